"""``fuzz.mavlink_oracles``' deaths (issue 39 item 4): the probe behind a case unanswered is a
crash (the vehicle gone: its process's end as evidence), a hang (no HEARTBEAT within
``heartbeat_gap_max_s``: MAV-HB-1) or unanswered (it beats on: MAV-PRM-4), named by the case's
rule; a probe answered late is no finding; a heartbeat that stops while the vehicle answers
is a hang; a replay's and the baseline's beat the same bound."""

from __future__ import annotations

import time
from dataclasses import dataclass

from mcp_conform.fuzz.mavlink_cases import Case
from mcp_conform.fuzz.mavlink_oracles import GAP_S, beats_on, lost, silent

CASE = Case("bad-crc", "MAV-HB-14", (b"\xfd",), messages=("COMMAND_LONG",), note="spoiled")


@dataclass
class Seen:
    """What a vehicle's link showed, as the oracles read it (``Observed``)."""

    running: bool = True
    beats: bool = True  # a HEARTBEAT comes within the gap
    late_answer: bool = False  # the probe's answer came after its bound
    last_beat: float = 0.0
    waits: int = 0

    @property
    def probe_name(self) -> str:
        return "SYSID_THISMAV"

    def alive(self) -> bool:
        return self.running

    def ending(self, grace: float = 0.0) -> tuple[str | None, tuple[str, ...]]:
        return "the vehicle process killed by signal SIGSEGV", ("vehicle command: x",)

    def wait_beat(self, since: float) -> bool:
        self.waits += 1
        return self.beats

    def probe_answered(self, timeout: float) -> bool:
        return self.late_answer


def test_an_unanswered_probe_is_a_crash_a_hang_or_unanswered_by_what_the_link_shows():
    crash = lost(Seen(running=False, beats=False), CASE)
    assert crash is not None and (crash.signature.oracle, crash.signature.rule, crash.signature.kind) == (
        "crash", "MAV-HB-14", "bad-crc")
    assert crash.actual.startswith("the vehicle process killed by signal SIGSEGV after bad-crc")
    assert crash.evidence == ("vehicle command: x",)
    seen = Seen(beats=False, last_beat=time.monotonic() - GAP_S - 1)
    hang = lost(seen, CASE)
    assert hang is not None and hang.signature.oracle == "hang" and hang.signature.rule == "MAV-HB-14"
    assert "(MAV-HB-1)" in hang.expected and hang.actual.startswith("no HEARTBEAT for ")
    deaf = lost(Seen(), CASE)
    assert deaf is not None and deaf.signature.oracle == "unanswered"
    assert "SYSID_THISMAV" in deaf.expected and "MAV-PRM-4" in deaf.expected
    assert lost(Seen(late_answer=True), CASE) is None  # late, not lost


def test_a_heartbeat_that_stops_while_the_vehicle_answers_is_a_hang():
    assert lost(Seen(), CASE, answered=True) is None
    hit = lost(Seen(beats=False), CASE, answered=True)
    assert hit is not None and hit.signature.oracle == "hang" and hit.actual.endswith("(it still answers)")


def test_a_replay_and_the_baseline_judge_the_heartbeat_alone():
    assert silent(Seen(), time.monotonic()) is None
    hit = silent(Seen(beats=False), time.monotonic())
    assert hit is not None and (hit.signature.oracle, hit.signature.rule) == ("hang", "MAV-HB-1")
    ok = Seen()
    assert beats_on(ok) is None and ok.waits == 2 and ok.last_beat > 0  # two beats, each timed afresh
    hit = beats_on(Seen(beats=False))
    assert hit is not None and "no first HEARTBEAT" in hit.actual

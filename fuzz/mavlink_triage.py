"""MAVLink's triage (issue 39 item 4: the protocol's part of the one campaign loop, ``fuzz.loop``,
as ``fuzz.nsqd_triage`` is Nsqd's): from a hit the engine saw to a confirmed, minimal finding.

The steps are every protocol's (``fuzz.triage_core``); this module declares MAVLink's: a hit
is counted, not triaged, when its group (rule and shape) is already a finding (a stopped
heartbeat: when a suspect like a hang finding's confirmed case is its culprit, two sends to one
fresh vehicle, ``fuzz.triage_core.known_lasting_hit``), when its signature did not reproduce
``UNCONFIRMED_TRIES`` times, once triage's share of the campaign is spent (``fuzz.budget``),
or when it is a stopped heartbeat one of whose suspects asked for it
(MAV_CMD_SET_MESSAGE_INTERVAL on the HEARTBEAT, ``fuzz.mavlink_cases.stops_heartbeat``: the
command's documented effect, ``STOP_ASKED``). Otherwise its suspects are replayed on a fresh
vehicle (spawn mode: a new process; attach mode: a new link): the case that showed it alone,
else every suspect (the cases since the last one proven harmless), those of one kind at a
time, then delta debugging (``fuzz.ddmin``) down to the fewest cases, then to the fewest
frames of a multi-frame case. A heartbeat that stopped stays stopped: its suspects (those since a period
before its last HEARTBEAT) are searched over their prefixes
(``fuzz.triage_core.earliest_prefix``: a vehicle that beats on after a prefix is sent the next
cases as it is), and the last case of the shortest prefix that stops it stands for the case
that showed it. The minimal input is confirmed N of N (``fuzz.confirm``), each on a fresh
vehicle, or counted unconfirmed (named environment-dependent: ``fuzz.environment``). The
finding is every protocol's (``fuzz.findings.Finding``): the rule of its signature, the cases
as ``finding.json`` holds them (``cases``, ``probe``), their frames as ``datagrams`` (hex),
the last confirming replay's traffic in ``repro.mcap`` (its ``/mavlink`` channel:
:func:`write_repro`).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from mcp_conform.fuzz.finding_files import write_packets_repro
from mcp_conform.fuzz.findings import Finding
from mcp_conform.fuzz.loop import count
from mcp_conform.fuzz.mavlink_cases import Case, asks_heartbeat_stop
from mcp_conform.fuzz.mavlink_vehicle import Hit, MavVehicle, Signature
from mcp_conform.fuzz.target_base import TargetLost
from mcp_conform.fuzz.triage_core import HitTriage, Parts
from mcp_conform.spec.profiles import MAVLINK_PROFILE

__all__ = ["MavTriage", "mavlink_finding", "replay_cases", "shape", "write_repro"]

DEATHS = ("crash", "hang", "unanswered")
#: A stopped heartbeat after a case that asked it stopped (``fuzz.mavlink_cases.stops_heartbeat``):
#: counted under this, not triaged, not a finding
STOP_ASKED = "hang: a suspect asked the HEARTBEAT stopped (MAV_CMD_SET_MESSAGE_INTERVAL)"
SPLIT = 1 / 3  # a stopped heartbeat's prefix search: the share of the suspects in doubt each replay adds


def _kind(c: Case) -> str:
    return c.kind


#: a case's frames, the fewest that show it (``fuzz.triage_core.fewest``: 8 replays)
FRAMES: Parts[Case, bytes] = Parts(lambda c: c.frames, lambda c, fs: replace(c, frames=tuple(fs)), 8)


def _like(c: Case) -> tuple[str, str, tuple[str, ...]]:
    """What makes cases alike for a known hang (``HitTriage.known_lasting``)."""
    return (c.kind, c.rule, c.messages)


def replay_cases(fresh: Any, cases: list[Case], sig: Signature, log: list[Any] | None = None) -> Hit | None:
    """``cases`` sent to a fresh vehicle (``fresh(log)``), each judged as in the campaign;
    the hit that shows ``sig`` (a stopped heartbeat: watched after the last case), else None."""
    v: MavVehicle = fresh(log)
    given = bool(cases)
    try:
        if sig.oracle == "hang" and len(cases) > 1:  # back to back, then watched
            if not v.run_all(cases):
                return None
            cases = []
        for c in cases:
            h = v.run(c)
            if h is not None and h.signature.same(sig):
                return h
            if h is not None and h.signature.oracle in ("crash", "hang"):
                return None
        if sig.oracle == "hang" and not given:  # a finding with no input blamed
            return v.beats_on()
        if sig.oracle == "hang":
            h = v.watch(time.monotonic())
            if h is not None:
                return Hit(replace(h.signature, rule=sig.rule, kind=sig.kind), h.expected, h.actual, h.evidence)
        return None
    finally:
        v.close()


def shape(sig: Signature, last: str | None) -> str:
    """A finding's shape, its group with its rule (``fuzz.findings.FindingStore``): an answer's
    signature; a death's or a hang's oracle after the ``last`` case's kind (None: no input)."""
    return (sig.describe() if sig.oracle == "answer" else f"{sig.oracle} after {last} ({sig.rule})"
            if last is not None else f"{sig.oracle} whatever it is sent ({sig.rule})")


def mavlink_finding(hit: Hit, cases: list[Case], replays: str, probe: bytes, *, seed: int = 0, worker: int = 0,
                    traffic: list[Any] | None = None, note: str = "") -> Finding:
    """A MAVLink finding as every protocol's is (``fuzz.findings.Finding``: its level its rule's;
    its seed and worker the triage's, ``HitTriage.add``)."""
    sig = hit.signature
    return Finding(sig.rule, hit.expected, hit.actual, [f.hex() for c in cases for f in c.frames],
                   shape(sig, cases[-1].kind if cases else None),
                   "stateless", seed, evidence=list(hit.evidence),
                   worker=worker, source=sig.oracle, protocol=MAVLINK_PROFILE.name, note=note, replays=replays,
                   no_input=not cases,
                   doc={"oracle": sig.oracle, "kind": sig.kind, "probe": probe.decode(errors="replace"),
                        "probe_hex": probe.hex(), "cases": [c.to_json() for c in cases]},
                   cases=list(cases), traffic=list(traffic or []))


@dataclass(kw_only=True, eq=False)
class MavTriage(HitTriage):
    """One worker's MAVLink triage (``fuzz.triage_core``'s steps; what it learnt carried to the
    next engine turn's: ``tries``, ``baselines``)."""

    DEATHS = DEATHS

    def consider(self, hit: Hit, suspects: list[Case]) -> MavVehicle:
        """A hit after ``suspects`` (the newest last), triaged and timed; the vehicle to go on with."""
        sig = hit.signature
        death = sig.oracle in DEATHS
        if death and self.target.attached and sig.oracle != "unanswered":
            raise TargetLost(f"the attached vehicle at {self.target.how.describe()}: {hit.actual}; "
                             "findings so far are kept")
        return self.triaged(sig.describe(), lambda: self._triage(hit, suspects),
                            (lambda: self.target.restart("after a hit")) if death else None)

    def _key(self, sig: Signature, kind: str) -> tuple[str, str, str]:
        return (sig.oracle, sig.rule, kind)

    def _known(self, sig: Signature) -> Finding | None:
        """The finding a hit already is: its group in the store (its rule and :func:`shape`,
        ``fuzz.findings.FindingStore``), a death's by the case it showed after (its signature's
        kind); a hang's is not: whatever case ran when the beat was missed, one of its suspects
        like a hang finding's case is its culprit (``HitTriage.known_lasting``)."""
        return None if sig.oracle == "hang" else self.store.groups.get((sig.rule, shape(sig, sig.kind)))

    def _triage(self, hit: Hit, suspects: list[Case]) -> None:
        sig = hit.signature
        kind = suspects[-1].kind if suspects else ""
        if sig.oracle == "hang" and any(asks_heartbeat_stop(c) for c in suspects):
            count(self.untriaged, STOP_ASKED)  # the command's documented effect: no defect, no triage
            return
        if self.counted(self._known(sig), self._key(sig, kind), sig.describe()):
            return
        if sig.oracle == "hang" and (self._hangs_anyway(sig) or self.known_lasting(
                suspects, "hang", _like, self._fresh, self._stops, MavVehicle.close)):
            return
        # the case that showed it (a hang's: the last of the shortest prefix of the suspects
        # that stops the heartbeat: it stays stopped) confirmed at once, then its fewest frames;
        # else the fewest cases of them that show it (fuzz.triage_core: HitTriage.minimal). A
        # replay that stops it costs heartbeat_gap_max_s (3 s) and a fresh vehicle, one that
        # beats on a period (1 s): each prefix adds a third of the range in doubt (SPLIT)
        lasting = (self._fresh, self._stops, MavVehicle.close, SPLIT) if sig.oracle == "hang" else None
        searched = self.minimal(suspects, self.shows(lambda cases: replay_cases(self._fresh, cases, sig), unstarted=True),
                                lambda cases, until_miss: self.confirm_logged(
                                    lambda log: replay_cases(self._fresh, cases, sig, log), until_miss=until_miss),
                                lasting=lasting, group=_kind, parts=FRAMES, budget=24, singles=2)
        if searched is None:
            self.not_confirmed(sig.rule, self._key(sig, kind))
            return
        minimal, conf = searched
        if sig.oracle in DEATHS:  # named by the case that makes it
            sig = replace(sig, rule=minimal[-1].rule, kind=minimal[-1].kind)
        if self.missed(sig.rule, self._key(sig, kind), conf, shape=sig.describe(), actual=hit.actual,
                       size=f"{len(minimal)} case(s)", where=" on a fresh vehicle"):
            return
        last, traffic = conf.hits[-1]
        found = Hit(sig, last.expected, last.actual, last.evidence or hit.evidence)
        self.add(mavlink_finding(found, minimal, conf.replays, self.target.info.probe, traffic=traffic,
                                 note=f"{len(minimal)} case(s) of {len(suspects)} suspect(s), replayed on a fresh vehicle"))

    def _hangs_anyway(self, sig: Signature) -> bool:
        """Whether the heartbeat stops with no case sent (``HitTriage.no_input``: a fresh
        vehicle watched for its next HEARTBEATs, ``replay_cases`` of none); then the stop is
        the vehicle's own (a finding with no input blamed, MAV-HB-1, one more occurrence of it)
        and no case is blamed for it."""
        if self.no_input("hang", lambda log, first: replay_cases(self._fresh, [], sig, log), lambda a, b: True, lambda first, last, log, replays: mavlink_finding(
                last, [], replays, self.target.info.probe, traffic=log, note="the vehicle's behaviour whatever it "
                "is sent: no input blamed (a fresh vehicle sent nothing)"),
                lambda h: (h.signature.rule, h.signature.describe(), h.actual)) is None:
            return False
        self.again(next((f for f in self.findings if f.no_input and f.source == "hang"), None))
        return True

    def _fresh(self, log: list[Any] | None = None) -> MavVehicle:
        return self.fresh(lambda: self.target.fresh(log))

    def _stops(self, v: MavVehicle, cases: Sequence[Case]) -> bool | None:
        """``cases`` sent to ``v`` back to back after what it was sent before (a hang's prefix
        search: ``fuzz.triage_core.earliest_prefix``): whether its heartbeat then stops (no
        HEARTBEAT after the probe's answer within ``heartbeat_gap_max_s`` of the last);
        None: the probe went unanswered (a death, not this hang)."""
        def send() -> bool | None:
            if not v.run_all(list(cases)):
                return None
            return v.watch(time.monotonic()) is not None
        return self.replay(send)


def write_repro(d: Path, f: Finding) -> None:
    """``repro.mcap``: the finding's last confirming replay (or its frames) on ``/mavlink``,
    from the vehicle's side (``rx``: the fuzzer's frames, ``tx``: the vehicle's), with the
    finding in the ``mcp-fuzz`` metadata record (``fuzz.finding_files.write_packets_repro``)."""
    from mcp_conform.traceio.recorder import mavlink_type

    write_packets_repro(d / "repro.mcap", f, MAVLINK_PROFILE.default_role.name, f.traffic, "rx", lambda rec, r: rec.mavlink(
        r[0], r[2], r[1], msg_type=mavlink_type(r[2])), protocol=MAVLINK_PROFILE.name, expected=f.expected, actual=f.actual)

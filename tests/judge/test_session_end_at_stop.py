"""A manager instance's session ends where the runner stopped that instance
(``judge.run_monitor.session_end``), in the run's monitor (``SessionMonitors``) and in
``mcp-capture check`` of its capture (``judge.judging``) alike: a judge-level trace of the
silent drone's scenario (tests/examples/test_go_manager.py's ``SILENT_SESSION_END``; the same
run end to end in tests/sim/test_manager_silent_stop_sim.py).

The manager's End_Mission to the silent drone has 2 copies at ``--rto 0.2`` when the instance is
stopped (its run delay read then, ``RUN_DELAY_METADATA``); the runner's case marks come 2.5 s
later. Before, the session ended at the last case mark, live and offline, and both failed
MCP-RTX-1 ("2 copies ... no ACK, none for 2.5 s"): time after the stop, when nothing could be
sent. Absences while the instance ran are still evidence: with no stop recorded (an attached
manager, still running) or a datagram after the stop (a node started again), the case marks
still end the session, and the same copies fail MCP-RTX-1 there.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from mcp_conform.judge.judging import Params, judge
from mcp_conform.judge.monitor import TESTER
from mcp_conform.judge.run_monitor import SessionMonitors
from mcp_conform.spec.codec import Action
from mcp_conform.traceio.recorder import (
    NODE_METADATA,
    RUN_DELAY_METADATA,
    McapRecorder,
    run_delay_metadata,
    run_metadata,
)
from tests.judge.monitor_scripts import Script

RUNNER, MANAGER = ("127.0.0.1", 41011), ("127.0.0.1", 41012)
S = 1_000_000_000
T0 = 1_700_000_000_000_000_000


def _silent_mission() -> Script:
    """Drones 1 and 2 ready, started, their lists ACKed; drone 2's End_Mission ACKed, drone 1's
    (the silent drone's) sent twice, unanswered."""
    s = Script((1, 2), vehicle=False, seed=3)
    for d in s.drones:
        s.exchange(d, 0, Action.MISSION_READY, origin=TESTER)
        s.tick(0.02)
    for d in s.drones:
        s.exchange(0, d, Action.START_MISSION, acker_origin=TESTER)
        s.tick(0.01)
    for d in s.drones:
        s.exchange(0, d, Action.WP_LIST, tuple(s.items), acker_origin=TESTER)
        s.tick(0.01)
    s.exchange(0, 2, Action.END_MISSION, acker_origin=TESTER)
    s.tick(0.01)
    _, data = s.send(0, 1, Action.END_MISSION)
    s.tick(0.2)
    s.raw(0, data, to=1)  # its second copy, the same seq
    return s


def _record(path: Path, *, stop: bool, after_stop: bool = False) -> tuple[SessionMonitors, int]:
    """The session as the manager role's runner records it and feeds its monitor: the mission's
    datagrams, the instance's stop 0.2 s after the last copy (``stop``), a datagram 0.1 s after
    it (``after_stop``), then the case's marks 2.5 s after the last copy. Returns the live
    monitor, finished, and the time of the last copy."""
    rec = McapRecorder(path, metadata=run_metadata("mcp-conform", role="manager",
                                                   parameters={"rto": 0.2, "ack_window": 0.25}), local=RUNNER)
    live = SessionMonitors(rto=0.2, ack_window=0.25, broadcast_id=0xFFFF, node_id=0, node_addr=MANAGER, complete=True)
    live.listen = RUNNER
    live.begin("silent")
    rec.begin_segment("silent", [(NODE_METADATA, {"id": 0, "address": f"{MANAGER[0]}:{MANAGER[1]}",
                                                  "complete": "true"})])
    s = _silent_mission()
    records = sorted(s.datagrams(), key=lambda r: r.t_ns)
    shift = T0 - records[0].t_ns

    def datagram(r, t_ns: int) -> None:
        direction = "rx" if r.src_addr == s.addr(0) else "tx"  # the manager's, or the drones'
        rec.datagram(direction, r.data, MANAGER, t_ns)
        live.observe(direction, r.data, MANAGER, t_ns)

    for r in records:
        datagram(r, r.t_ns + shift)
    last = records[-1].t_ns + shift
    if stop:
        rec.add_metadata(RUN_DELAY_METADATA, run_delay_metadata(0, 0, last + S // 5))
        live.run_delay(last + S // 5, 0, 0)
    if after_stop:
        datagram(records[0], last + 3 * S // 10)  # a drone's Mission_Ready again
    for t, event in ((last + 5 * S // 2, "start"), (last + 5 * S // 2 + 1000, "end")):
        rec.case_mark("FLOW/test_a_silent_drone_and_the_others", event, t, rules=("MCP-FLOW-7",),
                      outcome="info" if event == "end" else None)
        live.mark(t)
    live.finish()
    rec.close()
    return live, last


def _rtx1(violations: list[tuple[str, str]]) -> list[str]:
    return [actual for rule, actual in violations if rule == "MCP-RTX-1"]


def test_a_session_stopped_after_its_last_datagram_ends_at_the_stop(tmp_path: Path) -> None:
    cap = tmp_path / "stopped.mcap"
    live, _ = _record(cap, stop=True)
    got = [(v.rule, v.actual) for v in live.violations()]
    j = judge(cap, Params())
    assert _rtx1(got) == [] and _rtx1([(v.rule, v.actual) for v in j.violations]) == [], got
    assert live.verdict(0, "MCP-RTX-1") == j.verdicts[0].get("MCP-RTX-1", "not_observed") != "failed"
    assert sorted(got) == sorted((v.rule, v.actual) for v in j.violations)


@pytest.mark.parametrize("how", ["no stop recorded", "a datagram after the stop"])
def test_a_session_going_on_past_its_copies_still_fails_rtx1(tmp_path: Path, how: str) -> None:
    cap = tmp_path / "going-on.mcap"
    live, _ = _record(cap, stop=how != "no stop recorded", after_stop=how == "a datagram after the stop")
    got = _rtx1([(v.rule, v.actual) for v in live.violations()])
    j = judge(cap, Params())
    assert len(got) == 1 and got == _rtx1([(v.rule, v.actual) for v in j.violations]), got
    assert got[0].startswith("2 copies of End_Mission") and "to ID 1," in got[0], got
    assert live.verdict(0, "MCP-RTX-1") == j.verdicts[0]["MCP-RTX-1"] == "failed"


def test_session_end() -> None:
    from mcp_conform.judge.run_monitor import session_end

    assert session_end(10, 5, 7) == 7  # stopped after its last datagram: there
    assert session_end(10, 8, 7) == 10  # a datagram after the stop: its last record
    assert session_end(10, 5, None) == 10  # no stop known: its last record
    assert session_end(None, None, 7) == 7 and session_end(None, None, None) is None

"""The manager role's run monitor (``judge.run_monitor.SessionMonitors``) judges each datagram
by its stamp, not by when a runner thread told it (issue 38: a correct manager gets no verdict
under any schedule of the runner's own threads).

A runner thread taken off the CPU between a datagram's stamp (its send, or the kernel's
receive time) and telling its observers tells it late. Two false verdicts of the simulator's
preempted runner (``tests/sim/test_manager_preempt_seeds.py``) came from that alone:

- told more than the monitor's 100 ms hold late, the runner's ACK of a Start_Mission was fed
  behind the manager's next Start_Mission: MCP-BLK-1 (seed 118);
- told after the next scenario's session began, the previous manager's End_Mission copy and
  the runner's ACK of it were judged in that session, as a command to a drone after its
  End_Mission there: MCP-BLK-6 and MCP-SEQ-1 (seed 110).

Here the same two tellings on scripted missions (``tests.judge.monitor_scripts``), the
monitor's interface called as the manager session calls it.
"""

from __future__ import annotations

import pytest

from mcp_conform.judge.run_monitor import SessionMonitors
from mcp_conform.spec.codec import Action, peek_header
from tests.judge.monitor_scripts import MANAGER_ADDR, NS, TESTER, Record, Script

RUNNER = ("127.0.0.1", 41001)


def _monitors() -> SessionMonitors:
    live = SessionMonitors(rto=0.2, ack_window=0.25, broadcast_id=0xFFFF, node_id=0, node_addr=MANAGER_ADDR,
                           complete=True)
    live.listen = RUNNER
    return live


def _tell(observe, records: list[Record], shift: int = 0) -> None:
    """Each record to ``observe`` as the driver's observers get it: the manager's received
    ("rx"), the runner's drones' sent ("tx"), from and to the manager's address."""
    for r in records:
        observe("rx" if r.src_addr == MANAGER_ADDR else "tx", r.data, MANAGER_ADDR, r.t_ns + shift)


def _mission(seed: int, *, end_deaf: int = 0, pause: float = 0.0) -> Script:
    """A clean mission of drones 1 and 2 (the runner's, ``TESTER``); ``pause`` s between the
    Start_Missions and the lists; the last End_Mission's first ``end_deaf`` copies unanswered."""
    s = Script((1, 2), vehicle=False, seed=seed)
    for d in s.drones:
        s.exchange(d, 0, Action.MISSION_READY, origin=TESTER)
        s.tick(0.02)
    for d in s.drones:
        s.exchange(0, d, Action.START_MISSION, acker_origin=TESTER)
        s.tick(0.0001)
    s.tick(pause)
    for d in s.drones:
        s.exchange(0, d, Action.WP_LIST, tuple(s.items), acker_origin=TESTER)
        s.tick(0.01)
    for d in s.drones:
        s.exchange(0, d, Action.END_MISSION, acker_origin=TESTER, deaf=end_deaf if d == s.drones[-1] else 0)
    return s


def _bad(live: SessionMonitors) -> tuple[list, dict]:
    live.finish()
    out = live.to_json()
    return out["violations"], {r: v for r, v in out["rules"].get("0", {}).items() if v in ("failed", "warned")}


def test_an_ack_told_past_the_hold_is_judged_where_its_stamp_puts_it():
    """The runner's ACK of drone 1's Start_Mission, told after everything stamped up to 0.35 s
    after it (the manager's Start_Mission to drone 2 0.1 ms after it among them): no MCP-BLK-1.
    Told in stamp order, the same mission is judged clean (the control)."""
    s = _mission(1, pause=0.3)
    recs = sorted(s.datagrams(), key=lambda r: r.t_ns)
    ack = next(r for r in recs if r.origin is TESTER and peek_header(r.data)[3] == Action.ACK
               and peek_header(r.data)[1] == 1 and r.t_ns > recs[3].t_ns)
    starts = [r for r in recs if peek_header(r.data)[3] == Action.START_MISSION]
    assert starts[1].t_ns - ack.t_ns < 1_000_000  # the next unicast right after the ACK ...
    late = [r for r in recs if r is not ack and r.t_ns <= ack.t_ns + int(0.35 * NS)]
    assert late[-1].t_ns - ack.t_ns > 0.25 * NS  # ... and the ACK told after 0.25 s more of them
    control = _monitors()
    control.begin("main")
    _tell(control.observe, recs)
    assert _bad(control) == ([], {})
    live = _monitors()
    live.begin("main")
    _tell(live.observe, late)
    _tell(live.observe, [ack])
    _tell(live.observe, [r for r in recs if r.t_ns > ack.t_ns + int(0.35 * NS)])
    violations, bad = _bad(live)
    assert violations == [] and bad == {}, violations
    assert live.to_json()["rules"]["0"]["MCP-BLK-1"] == "passed"


@pytest.mark.parametrize("held", [True, False], ids=["side-by-side", "serial"])
def test_the_previous_managers_datagrams_told_late_stay_in_its_session(held):
    """The main manager's last End_Mission (to drone 2) has a copy before the runner's ACK;
    both stamped before the silent scenario's session began, told after it (and after that
    scenario's own End_Mission to drone 2): judged in the main session, where the copy is a
    retransmission -- not in the silent one, as a second End_Mission (MCP-BLK-6) numbered
    out of turn (MCP-SEQ-1). ``held``: the silent scenario ran beside on sockets of its own,
    its traffic told when its session begins (``observe_held``); else it ran after, on the
    same driver. Either way a datagram of the driver stamped after the boundary is told to
    the session its stamp names."""
    main = _mission(2, end_deaf=1)
    recs = sorted(main.datagrams(), key=lambda r: r.t_ns)
    copy, ack = recs[-2], recs[-1]
    assert peek_header(copy.data)[3] == Action.END_MISSION and peek_header(ack.data)[3] == Action.ACK
    assert copy.data == recs[-3].data  # the End_Mission's copy, then its ACK
    live = _monitors()
    live.begin("main", recs[0].t_ns)
    _tell(live.observe, recs[:-2])
    boundary = ack.t_ns + int(0.2 * NS)
    silent = _mission(3)
    srecs = sorted(silent.datagrams(), key=lambda r: r.t_ns)
    live.begin("silent", boundary, held=held)
    # the silent scenario: beside the main one (stamps of the same span) or after the boundary
    shift = recs[0].t_ns - srecs[0].t_ns if held else boundary + 1000 - srecs[0].t_ns
    _tell(live.observe_held if held else live.observe, srecs, shift)
    _tell(live.observe, [copy, ack])  # the main manager's, told after the silent scenario's
    violations, bad = _bad(live)
    assert violations == [] and bad == {}, violations
    assert live.parts["main"].monitor.count == len(recs)
    assert live.parts["silent"].monitor.count == len(srecs)

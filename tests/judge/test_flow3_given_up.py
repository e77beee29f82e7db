"""MCP-FLOW-3 (End_Mission to every drone started) does not fail a manager for a drone it gave
up at its retry limit before that drone's ACK came (issue 38: a rule fails only when every
explanation consistent with the trace breaks it).

The manager sends a drone's command until its retry limit (13 copies, the embedded manager's),
gets no ACK, and moves on to another drone; that drone's ACK comes seconds later (the
simulator's runner whose receiver thread fell behind: seed 26 of ``preempt=(0.3, 0.6)``,
``tests/sim/test_manager_preempt_seeds.py``). To the manager the drone never answered: it is
dropped from the mission, no End_Mission owed -- as for a drone given up short of MCP-RTX-1's
copies (that give-up fails MCP-RTX-1, not FLOW-3 too). A drone whose last command was ACKed
before the manager moved on and that never gets End_Mission still fails.
"""

from __future__ import annotations

from mcp_conform.spec.codec import Action
from tests.judge.monitor_scripts import TESTER, Script

COPIES = 13


def _mission(ack_late: bool) -> Script:
    """Drones 1 and 2 ready and started; drone 2's WP_List sent ``COPIES`` times unanswered,
    then End_Mission to drone 1 (ACKed). ``ack_late``: drone 2's ACK of the WP_List comes 2 s
    after the manager moved on; else it comes just before its last copy's timer (the manager
    had it) and drone 2 still gets no End_Mission."""
    s = Script((1, 2), vehicle=False, seed=5)
    for d in s.drones:
        s.exchange(d, 0, Action.MISSION_READY, origin=TESTER)
        s.tick(0.02)
    for d in s.drones:
        s.exchange(0, d, Action.START_MISSION, acker_origin=TESTER)
        s.tick(0.01)
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items), acker_origin=TESTER)
    s.tick(0.01)
    seq, data = s.send(0, 2, Action.WP_LIST, tuple(s.items))
    for _ in range(COPIES - 1):
        s.tick(s.rto)
        s.raw(0, data, to=2)
    if not ack_late:
        s.tick(s.rto / 2)
        s.ack(2, 0, seq, origin=TESTER)
        s.tick(s.rto / 2)
    else:
        s.tick(s.rto)
    s.exchange(0, 1, Action.END_MISSION, acker_origin=TESTER)
    if ack_late:
        s.tick(2.0)
        s.ack(2, 0, seq, origin=TESTER)
    return s


def _flow3(s: Script) -> list:
    return [v for v in s.judge(tail=5.0) if v.rule == "MCP-FLOW-3"]


def test_a_drone_given_up_at_the_retry_limit_before_its_ack_is_owed_no_end_mission():
    s = _mission(ack_late=True)
    assert _flow3(s) == []
    assert s.last_monitor.verdicts()[0]["MCP-FLOW-3"] == "passed"
    assert s.last_monitor.verdicts()[0]["MCP-RTX-1"] != "failed"  # 13 copies: the give-up is the rule's


def test_a_drone_whose_last_command_was_acked_in_time_still_needs_its_end_mission():
    flow3 = _flow3(_mission(ack_late=False))
    assert [v.actual for v in flow3] == ["drone 2 never got End_Mission (other drones did)"]

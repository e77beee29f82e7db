"""False or missing verdicts of the judge found under load or through an impaired link
(issue 38), each reproduced on a scripted trace (``tests.judge.monitor_scripts``)."""

from __future__ import annotations

from mcp_conform.judge.monitor import TESTER
from mcp_conform.spec.codec import Action
from mcp_conform.spec.mavframe import heartbeat_frame
from tests.judge.monitor_faults import _finish
from tests.judge.monitor_scripts import Script


def _interleaved_copies(answer_a: str) -> Script:
    """Two cases side by side on a loaded host (CI, test_mutants[ack-copies-wrong-seq]): the
    harness's Mav_Passthrough A and WP_Off B = A + 1 to drone 1, each ACKed right at once,
    then each retransmitted (the harness read the ACKs late): B's copy first, answered
    "B + 1" (no message of that number: an ACK naming nothing sent), then A's copy, answered
    ``answer_a`` ("B": the seq plus 1, as the ack-copies-wrong-seq node does; "none": never)."""
    s = Script((1,), challenge=1)
    s.ready(1)
    s.start(1)
    a, da = s.send(0, 1, Action.MAV_PASSTHROUGH, heartbeat_frame(), seq=1326, origin=TESTER)
    s.tick(0.004)
    s.ack(1, 0, a)
    s.tick(0.01)
    b, db = s.send(0, 1, Action.WP_OFF, seq=a + 1, origin=TESTER)
    s.tick(0.004)
    s.ack(1, 0, b)
    s.tick(0.2)
    s.raw(0, db, to=1, origin=TESTER)  # B's copy, answered "B + 1"
    s.tick(0.005)
    s.ack(1, 0, b + 1)
    s.tick(0.05)
    s.raw(0, da, to=1, origin=TESTER)  # A's copy
    if answer_a == "B":
        s.tick(0.005)
        s.ack(1, 0, b)
    s.tick(1.5)
    return _finish(s)


def test_a_copy_answered_by_an_ack_matched_to_another_copy_is_not_unacked():
    """CI (loaded, 10 workers on 2 cores): "copy of Mav_Passthrough seq 1326 from ID 0 to ID
    1 after its ACK was not ACKed" (MCP-ACK-1) beside the node's proven MCP-ACK-2. A's copy
    was answered "1327", B's number; B still had a copy owed an ACK, so the monitor counted
    that ACK as B's copy's and A's copy as never answered. An ACK did come for A's copy (a
    wrong one, or B's copy's second): MCP-ACK-1 is not proven there; and neither is
    MCP-ACK-2 (the ACK may be B's), which the node's other copies prove in a run."""
    rules = {v.rule for v in _interleaved_copies("B").judge()}
    assert "MCP-ACK-1" not in rules, rules


def test_a_copy_never_answered_is_still_unacked():
    """The same interleaving with A's copy never answered: MCP-ACK-1, as before (the fix
    above does not hide a missing ACK)."""
    found = _interleaved_copies("none").judge()
    assert [v.actual for v in found if v.rule == "MCP-ACK-1"] == [
        "copy of Mav_Passthrough seq 1326 from ID 0 to ID 1 after its ACK was not ACKed"], found


def _late_ready(payload: object) -> Script:
    """The manager's own view (seed monitor-blk2-manager-long-delays, shrunk): drone 2's
    Mission_Ready ACKed, the ACK lost, and of the drone's copies only one more reaches the
    manager, 70 s later (past the monitor's 60 s horizon at --rto 0.2), after the manager
    started drone 1; it is ACKed again. ``payload``: what that late datagram carries (None:
    the message's bytes, a copy; else the same number with other bytes)."""
    s = Script((1, 2), challenge=1)
    s.ready(1)
    seq = s.ready(2)
    s.start(1)
    s.tick(70.0)
    s.send(2, 0, Action.MISSION_READY, payload, seq=seq)
    s.tick(0.004)
    s.ack(0, 2, seq)
    s.tick(0.02)
    s.start(2)
    return _finish(s)


def test_a_copy_of_a_drones_last_message_however_late_is_no_new_mission_ready():
    """MCP-DUP-1: the same (src, seq) as the last message from that src is a duplicate, with
    no time limit. Taken for a restart, the late copy made the Start_Mission before it a false
    MCP-BLK-2 (the monitor's 100 s horizon at --rto 5; 1 in 600,000 correct schedules)."""
    s = _late_ready(None)
    mine = [v for v in s.judge(party=0) if v.node == 0]
    assert mine == [], mine
    assert s.last_monitor.verdicts()[0]["MCP-BLK-2"] == "passed"


def test_the_same_number_with_other_bytes_past_the_horizon_is_still_a_new_message():
    """Not a copy (MCP-SEQ-2: a copy repeats the bytes): a new Mission_Ready, after the
    manager's first command (MCP-BLK-2 fails, as before)."""
    s = _late_ready(2)
    assert "MCP-BLK-2" in {v.rule for v in s.judge(party=0) if v.node == 0}

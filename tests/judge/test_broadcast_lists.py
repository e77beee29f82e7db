"""D-11 in the trace monitor: the challenge's messages broadcast to every drone (delivery "any").

A broadcast is a command to each drone whose mission is on when it comes (its Start_Mission
answered, no End_Mission sent to it yet): one WP_List (Obstacles_List) broadcast
once after every Start_Mission was ACKed is each drone's one list (MCP-FLOW-4/6), broadcast
WP_On/WP_Off are each drone's (MCP-FLOW-5). A broadcast still goes to every drone: one while a
drone's Start_Mission awaits its ACK is a further command to it (MCP-BLK-3), one after its
End_Mission a command after it (MCP-BLK-6). What still fails is in tests/judge/monitor_faults.py
(``flow4-broadcast-*``, ``flow5-broadcast-*``, ``flow6-broadcast-*``: no list in a drone's
mission, two lists; ``blk3-broadcast-*``, ``blk6-broadcast-*``); the same judge serves
``mcp-capture check`` (tests/captures/test_check.py runs those scripts as pcaps). The judge
before D-11 failed the clean missions here ("End_Mission to drone 1 without any WP_List").
"""

from __future__ import annotations

import pytest

from mcp_conform.spec.codec import Action
from tests.judge.monitor_faults import FAULTY, flow6_broadcast_after_end
from tests.judge.monitor_scripts import Script

FLOW = {1: "MCP-FLOW-4", 2: "MCP-FLOW-5", 3: "MCP-FLOW-6"}


def _challenge_broadcast(s: Script) -> None:
    """The challenge's messages, each broadcast once (the C manager's ``VARIANT=BROADCAST``)."""
    if s.challenge == 2:
        for wp in s.items:
            s.broadcast(Action.WP_ON, wp)
            s.broadcast(Action.WP_OFF)
    else:
        s.broadcast(Action.WP_LIST if s.challenge == 1 else Action.OBSTACLES_LIST, tuple(s.items))


@pytest.mark.parametrize("complete", [True, False], ids=["complete", "lossy"])
@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_a_mission_broadcast_after_every_start_is_each_drones_mission(challenge, complete):
    s = Script((1, 2, 3), challenge=challenge, seed=challenge)
    for d in s.drones:
        s.ready(d)
    for d in s.drones:
        s.start(d, lost_acks=1)  # a lost ACK too: the Start_Mission is ACKed all the same
    _challenge_broadcast(s)
    for d in s.drones:
        s.end(d)
    assert [(v.rule, v.actual) for v in s.judge(complete=complete)] == []
    if complete:
        verdicts = s.last_monitor.verdicts()[0]
        assert verdicts[FLOW[challenge]] == "passed", verdicts


def test_a_broadcast_after_a_drones_end_mission_is_a_command_to_it_not_its_list():
    """Drone 1's whole mission (its list unicast) ends before drone 2's starts; the list then
    broadcast is drone 2's list, not a second list to drone 1 -- but a broadcast goes to every
    drone, drone 1 too, after its End_Mission ("it will send no further commands in the
    current mission"): MCP-BLK-6, once, and nothing else. The judge before session 34 let it
    pass (a broadcast a command to no drone whose mission is not on)."""
    s = Script((1, 2), challenge=1, seed=5)
    for d in s.drones:
        s.ready(d)
    s.start(1)
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items))
    s.tick(0.01)
    s.end(1)
    s.start(2)
    s.broadcast(Action.WP_LIST, tuple(s.items))
    s.end(2)
    violations = s.judge()
    assert [v.rule for v in violations] == ["MCP-BLK-6"], violations
    assert "to drone 1 too" in violations[0].actual, violations[0]
    assert s.last_monitor.verdicts()[0]["MCP-FLOW-4"] == "passed"


def test_a_list_broadcast_after_a_drones_end_is_not_its_list_and_a_command_after_its_end():
    """Drone 1 ended with no list; the Obstacles_List broadcast after that is not its list
    (MCP-FLOW-6, at its End_Mission) and a command after its End_Mission (MCP-BLK-6): two
    faults, each counted once under its rule."""
    s = flow6_broadcast_after_end()
    assert sorted(v.rule for v in s.judge()) == ["MCP-BLK-6", "MCP-FLOW-6"]


def test_a_list_broadcast_before_a_drones_start_is_acked_is_blk3s_and_its_list():
    """The list broadcast while drone 2's Start_Mission awaits its ACK: a further command to
    drone 2 before that ACK (a broadcast goes to every drone: "does not send any subsequent MCP
    commands until an acknowledgement is received"), MCP-BLK-3 once; and drone 2's list, so no
    MCP-FLOW-4 beside it (one fault, one rule). The broadcast is in the evidence. The judge
    before session 34 said MCP-FLOW-4 ("End_Mission to drone 2 without any WP_List")."""
    s = FAULTY["blk3-broadcast-before-start-acked"].build()
    violations = s.judge()
    assert [v.rule for v in violations] == ["MCP-BLK-3"], violations
    v = violations[0]
    assert "a broadcast: to drone 2 too" in v.actual, v
    sent = {r.t_ns for r in s.datagrams() if r.data[9:11] == b"\xff\xff"}  # the broadcast's dst
    assert len(sent) == 1 and sent <= {t for _, t in v.evidence}, (sent, v.evidence)
    assert s.last_monitor.verdicts()[0]["MCP-FLOW-4"] == "passed"


def test_a_wrong_ack_taken_for_the_start_is_rtx2s_not_also_a_missing_list():
    """A manager that took a wrong ACK for drone 1's Start_Mission and broadcast the list before
    the right one came: the broadcast is drone 1's list (its Start_Mission answered, as the
    manager took it): MCP-RTX-2 alone, one fault one rule."""
    s = FAULTY["rtx2-moves-on-then-broadcasts"].build()
    assert {v.rule for v in s.judge()} == {"MCP-RTX-2"}

"""``mcp-capture check --complete`` and MCP-RTX-1 on a lone copy (issue 38): a manager's
unicast End_Mission never ACKed and never sent again for six retransmission timeouts, the
capture going on after it, is the manager's MCP-RTX-1 (one copy, no ACK in a capture
declared complete, nothing more long after its next copy was due) -- judged the same from a
pcap and by the live run's monitor (``judge.run_monitor``: one judge)."""

from __future__ import annotations

from pathlib import Path

import pytest

from mcp_conform.judge.run_monitor import RunMonitor
from mcp_conform.spec.codec import Action
from tests.captures.test_check import check, mission_args
from tests.judge.monitor_scripts import MANAGER_ADDR, NS, T0_NS, Script

RTO, WINDOW = 5.0, 2.0  # the description's timeout and mcp-capture check's defaults


def _lone_end_mission(silence: float) -> Script:
    """A clean mission of drones 1 and 2 up to its end; the manager's End_Mission to drone 1
    sent once and never ACKed; ``silence`` s later its End_Mission to drone 2, ACKed, and
    the capture goes on a little."""
    s = Script((1, 2), challenge=1, rto=RTO, ack_window=WINDOW, seed=38)
    for d in s.drones:
        s.ready(d)
    for d in s.drones:
        s.start(d)
    s.challenge_steps()
    for d in s.drones:
        s.passthrough(d)
    s.tick(0.05)
    s.send(0, 1, Action.END_MISSION)  # once, never ACKed
    s.tick(silence)
    s.end(2)
    s.tick(0.5)
    # more traffic, the capture going on: drone 2's ACK of End_Mission again, as a link
    # duplicates it (an ACK naming a number nobody sent would be drone 2's MCP-ACK-2)
    s.raw(2, [r.data for r in s.records if r.src_addr == s.addr(2)][-1])
    return s


def _rtx1(doc: dict) -> list[dict]:
    return [v for v in doc["violations"] if v["rule"] == "MCP-RTX-1"]


def test_a_lone_unacked_copy_then_six_timeouts_of_nothing_is_rtx1_on_a_complete_capture(tmp_path: Path):
    s = _lone_end_mission(6 * RTO)
    rc, doc = check(tmp_path, s, *mission_args(s, tmp_path), "--complete")
    assert rc == 1 and [(v["rule"], v["node"]) for v in doc["violations"]] == [("MCP-RTX-1", 0)], doc["violations"]
    assert "1 copy of End_Mission" in _rtx1(doc)[0]["actual"]


def test_not_judged_on_a_capture_not_declared_complete(tmp_path: Path):
    s = _lone_end_mission(6 * RTO)
    rc, doc = check(tmp_path, s, *mission_args(s, tmp_path))
    assert rc == 0 and doc["violations"] == [], doc["violations"]


@pytest.mark.parametrize("silence", [0.9 * RTO, 1.5 * RTO])
def test_not_judged_before_the_next_copy_is_overdue(tmp_path: Path, silence: float):
    """Its next copy is due one timeout on, overdue at one and a half plus the ACK window
    (``_rtx_deadline``): a capture that goes on less than that after the copy proves
    nothing (a sender may still retransmit)."""
    s = _lone_end_mission(silence)
    rc, doc = check(tmp_path, s, *mission_args(s, tmp_path), "--complete")
    assert _rtx1(doc) == [], doc["violations"]


def test_the_live_monitor_gives_the_same_verdict():
    """The run's monitor (``judge.run_monitor.RunMonitor``, the manager under test at its
    address, the drones' datagrams the runner's) fed the same datagrams as they come."""
    s = _lone_end_mission(6 * RTO)
    live = RunMonitor(rto=RTO, ack_window=WINDOW, broadcast_id=0xFFFF, node_id=0, node_addr=MANAGER_ADDR,
                      drones=s.drones, challenge=s.challenge, waypoints=s.items)
    live.listen = MANAGER_ADDR
    for r in s.datagrams():
        if r.src_addr == MANAGER_ADDR:
            live.observe("rx", r.data, r.src_addr, r.t_ns)
        else:
            live.observe("tx", r.data, r.src_addr, r.t_ns)
    live.finish(int(T0_NS + s.t * NS))
    assert [(v.rule, v.node) for v in live.violations()] == [("MCP-RTX-1", 0)], live.violations()
    assert live.verdicts()[0]["MCP-RTX-1"] == "failed"

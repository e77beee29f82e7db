"""BLK — blocking and ordering of the manager's sends.

"Waits for 'Mission Ready' messages from all UAVs", then "Sends 'Start Mission' message to
each UAV". Unicast sends block until ACKed (stop-and-wait). After End_Mission a drone gets
nothing more.
"""

from __future__ import annotations

from mcp_conform.conformance.manager_case import (
    abandoned,
    awaiting_start,
    awaiting_until,
    gave_up,
    messages,
    runner_ack_time,
)
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec.codec import Action

_START = int(Action.START_MISSION)
_END = int(Action.END_MISSION)


def _name(action):
    return Action(action).name if 0 <= action <= 9 else str(action)


@rules("MCP-BLK-2")
def test_nothing_before_every_mission_ready(node):
    """One drone is held back while the others are ready, one of them announcing itself
    twice: no command may reach any drone before the last drone's Mission_Ready."""
    m = node.mission()
    if m.all_ready_t is None:
        raise Inconclusive("MCP-BLK-2: the last drone's Mission_Ready was never sent")
    early = [x for x in messages(m) if x.first.t < m.all_ready_t]
    x = early[0] if early else None
    how = (f"drone {m.duplicate.first.src} announced itself twice" if m.duplicate is not None
           else f"{m.ready_unacked}; the others announced themselves" if m.ready_unacked
           else "an ID outside the mission announced itself")
    node.expect_true(x is None, "MCP-BLK-2",
                     f"no command before drone {m.held_back}'s Mission_Ready (held back "
                     f"{m.all_ready_t - m.t0:.2f} s; {how})",
                     f"{_name(x.action)} to {x.dst} {m.all_ready_t - x.first.t:.3f} s before it" if x else "",
                     [y.first.describe() for y in early[:3]])


@rules("MCP-BLK-1")
def test_stop_and_wait(node):
    """No new unicast while one awaits its ACK (a command to the same drone while its
    Start_Mission is unACKed is MCP-BLK-3's; a copy with a new seq is MCP-SEQ-2's)."""
    m = node.mission()
    every = messages(m)
    msgs = [x for x in every if x.dst != node.broadcast_id]
    if not msgs:
        raise Inconclusive("MCP-BLK-1: the manager sent no unicast message")
    for x in msgs:
        until = awaiting_until(m, x, node.rto, every)
        for y in msgs:
            if y is x or not x.first.t < y.first.t < until:
                continue
            if x.action == _START and y.dst == x.dst:
                continue  # MCP-BLK-3's
            raise node.fail("MCP-BLK-1", f"nothing new while {_name(x.action)} (seq {x.seq}) to drone {x.dst} "
                            "awaits its ACK", f"{_name(y.action)} (seq {y.seq}) to drone {y.dst} "
                            f"{y.first.t - x.first.t:.3f} s after it, before its ACK",
                            [x.first.describe(), y.first.describe()])


@rules("MCP-BLK-3")
def test_nothing_to_a_drone_until_start_mission_is_acked(node):
    m = node.mission()
    msgs = messages(m)
    starts = [x for x in msgs if x.action == _START and x.dst in m.drones]
    if not starts:
        raise Inconclusive("MCP-BLK-3: the manager sent no Start_Mission (see MCP-FLOW-2)")
    for x in starts:
        acked = runner_ack_time(m, x)
        # given up before any answer (MCP-RTX-1's), it awaited until its last copy: a Start_Mission
        # sent again after it under a new number is a new message, not a command before its ACK
        until = x.last.t if gave_up(m, x, node.rto, msgs) else acked if acked is not None else m.t_end
        early = [y for y in msgs if y.dst == x.dst and y is not x and x.first.t < y.first.t < until]
        if x is next(y for y in msgs if y.dst == x.dst and y.action == _START):  # a broadcast goes to it too (D-11)
            early = sorted(early + awaiting_start(m, msgs, x.dst, node.broadcast_id, node.rto), key=lambda y: y.first.t)
        if early:
            y = early[0]
            raise node.fail("MCP-BLK-3", f"no command to drone {x.dst} until its Start_Mission (seq {x.seq}) is ACKed",
                            f"{_name(y.action)} (seq {y.seq}{', a broadcast: D-11' if y.dst != x.dst else ''}) "
                            f"{y.first.t - x.first.t:.3f} s after it"
                            + (", before any ACK" if acked is None else f", {acked - y.first.t:.3f} s before the ACK"),
                            [x.first.describe(), y.first.describe()])


@rules("MCP-BLK-6")
def test_nothing_after_end_mission(node):
    m = node.mission()
    msgs = messages(m)
    ends = {}
    for x in msgs:
        if x.action == _END and x.dst in m.drones:
            ends.setdefault(x.dst, x)
    if not ends:
        raise Inconclusive("MCP-BLK-6: the manager sent no End_Mission (see MCP-FLOW-3)")
    for d, end in ends.items():
        k = next(n for n, y in enumerate(msgs) if y is end)
        after = [y for n, y in enumerate(msgs) if (y.dst == d and y.first.t > end.first.t and y is not end)
                 or (y.dst == node.broadcast_id and n > k)]  # a broadcast after it goes to d too (D-11; in
        # arrival order: the two may bear one timestamp)
        node.expect_true(not after, "MCP-BLK-6", f"nothing to drone {d} after its End_Mission (seq {end.seq})",
                         f"{_name(after[0].action)} (seq {after[0].seq}{', a broadcast: D-11' if after[0].dst != d else ''}) "
                         f"{after[0].first.t - end.first.t:.3f} s "
                         "after it" if after else "", [end.first.describe()] + [y.first.describe() for y in after[:2]])
    gone = abandoned(m, node.rto)
    if gone:
        node.info(f"the manager gave up on drone(s) {sorted(gone)}")

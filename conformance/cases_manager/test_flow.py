"""FLOW — the mission as the manager runs it, compared with the waypoint file it was handed.

"1. Waits for 'Mission Ready' messages from all UAVs 2. Sends 'Start Mission' message to
each UAV 3. Executes the challenge based on the challenge number." Challenge 1: one
WP_List; challenge 2: WP_On, then WP_Off; challenge 3: one Obstacles_List; then End_Mission.
A drone the manager gave up on (its retry limit, MCP-RTX-1) is excused from the rest. The
challenge's messages may be broadcast (delivery "any"): a broadcast is a command to each drone
whose mission is on when it comes, and to one whose Start_Mission awaits its ACK (MCP-BLK-3's
fault, that drone's command: one fault, one rule), to no other (D-11, ``manager_case.to_mission``).
"""

from __future__ import annotations

from mcp_conform.conformance.manager_case import (
    abandoned,
    item_differences,
    messages,
    needs_scenario,
    to_mission,
)
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.judge.waypoints import waypoints_missed
from mcp_conform.spec.codec import Action

_START = int(Action.START_MISSION)
_END = int(Action.END_MISSION)
_WP_ON = int(Action.WP_ON)
_WP_OFF = int(Action.WP_OFF)


def _name(action):
    return Action(action).name if 0 <= action <= 9 else str(action)


@rules("MCP-FLOW-2")
def test_start_mission_to_each_drone_first(node):
    m = node.mission()
    msgs = messages(m)
    for d in m.drones:
        first = next((x for x in msgs if x.dst == d), None)
        node.expect_true(first is not None and first.action == _START, "MCP-FLOW-2",
                         f"Start_Mission unicast to drone {d} as its first command",
                         "nothing sent to it" if first is None else f"{_name(first.action)} first",
                         [first.first.describe()] if first is not None else [])


@rules("MCP-FLOW-3")
def test_end_mission_to_each_drone(node):
    m = node.mission()
    gone = abandoned(m, node.rto)
    ended = {x.dst for x in messages(m) if x.action == _END}
    missing = [d for d in m.drones if d not in ended and d not in gone]
    if gone:
        node.info(f"the manager gave up on drone(s) {sorted(gone)}: excused")
    node.expect_true(not missing, "MCP-FLOW-3", "End_Mission to every drone, as its last command",
                     f"no End_Mission to drone(s) {missing} (the mission record ended: {m.ended_by}, "
                     f"{m.t_end - m.t0:.1f} s)")


def _one_list(node, rule, action, want, what):
    """Exactly one new list of ``action`` per drone (unicast to it, or broadcast while its mission
    is on: D-11), equal to ``want`` (count, order, every field)."""
    m = node.mission()
    gone = abandoned(m, node.rto)
    msgs = messages(m)
    for d in m.drones:
        mine, outside = to_mission(m, msgs, d, node.broadcast_id, node.rto)
        lists = [x for x in mine if x.action == action]
        if not lists and d in gone:
            continue
        early = [x for x in outside if x.action == action]
        node.expect_true(len(lists) == 1, rule, f"one {_name(action)} to drone {d}", f"{len(lists)}"
                         + (f" ({len(early)} broadcast outside its mission: before its Start_Mission was ACKed "
                            "or after its End_Mission, D-11)" if early and not lists else ""),
                         [x.first.describe() for x in (lists or early)[:3]])
        got = lists[0].first
        if got.msg is None:
            raise Inconclusive(f"{rule}: the {_name(action)} to drone {d} cannot be decoded "
                               f"({got.error}; see MCP-PAY-3)")
        if want is None:
            raise Inconclusive(f"{rule}: the {what} the manager was handed is unknown "
                               "(attach mode without --waypoints)")
        items = got.msg.payload
        node.expect_true(len(items) == len(want), rule, f"{len(want)} {what} (the file's)",
                         f"{len(items)} items", [got.describe()])
        for n, (it, w) in enumerate(zip(items, want, strict=True)):
            diff = item_differences(it, w)
            node.expect_true(not diff, rule, f"item {n} of {_name(action)} to drone {d} = line {n + 1} of the file",
                             "; ".join(diff), [f"sent: {tuple(it)}", f"file: {tuple(w)}"])


@rules("MCP-FLOW-4")
def test_challenge_1_waypoints_as_one_wp_list(node):
    node.require_challenge("MCP-FLOW-4", 1)
    _one_list(node, "MCP-FLOW-4", int(Action.WP_LIST), node.mission().waypoints, "waypoints")


@rules("MCP-FLOW-5")
def test_challenge_2_wp_off_follows_wp_on(node):
    """Per drone: WP_On and WP_Off alternate, WP_On first; each WP_On carries one of the
    file's waypoints, and every waypoint of the file is sent (``judge.waypoints``: the trace
    monitor's judge too; not judged where a WP_On could not be decoded, MCP-PAY-5's)."""
    node.require_challenge("MCP-FLOW-5", 2)
    m = node.mission()
    gone = abandoned(m, node.rto)
    want = m.waypoints
    msgs = messages(m)
    for d in m.drones:
        mine = to_mission(m, msgs, d, node.broadcast_id, node.rto)[0]
        end = next((k for k, x in enumerate(mine) if x.action == _END), len(mine))  # in arrival order
        seq = [x for x in mine[:end] if x.action in (_WP_ON, _WP_OFF)]  # after End_Mission: MCP-BLK-6's
        if not seq and d in gone:
            continue
        on = False
        for x in seq:
            if x.action == _WP_OFF:
                node.expect_true(on, "MCP-FLOW-5", f"WP_Off to drone {d} only after a WP_On",
                                 f"WP_Off (seq {x.seq}) with no WP_On before it", [x.first.describe()])
            on = x.action == _WP_ON
        carried = [x.first.msg.payload if x.first.msg is not None else None for x in seq if x.action == _WP_ON]
        if want is None:
            continue
        for it in carried:
            node.expect_true(it is None or any(not item_differences(it, w) for w in want), "MCP-FLOW-5",
                             "each WP_On carries a waypoint of the file", f"an item not in the file: {tuple(it or ())}")
        missed = waypoints_missed(carried, want)  # the monitor's judge too (one judge)
        node.expect_true(not missed or d in gone, "MCP-FLOW-5", f"every waypoint of the file in a WP_On to drone {d}",
                         f"{len(missed or ())} of {len(want)} never sent", [f"file: {tuple(w)}" for w in (missed or ())[:2]])
    if want is None:
        raise Inconclusive("MCP-FLOW-5: the order was judged; the waypoints the manager was handed are unknown "
                           "(attach mode without --waypoints)")


@rules("MCP-FLOW-6")
def test_challenge_3_obstacles_as_one_list(node):
    node.require_challenge("MCP-FLOW-6", 3)
    _one_list(node, "MCP-FLOW-6", int(Action.OBSTACLES_LIST), node.mission().obstacles, "obstacles")


@rules("MCP-FLOW-7", phase="late")
@needs_scenario("silent")
def test_a_silent_drone_and_the_others(node):
    """One drone stops answering after its Start_Mission: what becomes of the others."""
    m = node.mission("silent")
    s = m.silent_drone
    msgs = messages(m)
    to_silent = [x for x in msgs if x.dst == s and m.silent_from is not None and x.first.t > m.silent_from]
    copies = sum(len(x.copies) for x in to_silent)
    gave_up = s in abandoned(m, node.rto)
    others = [d for d in m.drones if d != s]
    ended = {x.dst: x.first.t for x in msgs if x.action == _END}
    got_end = [d for d in others if d in ended]
    parts = [f"drone {s} went silent after its Start_Mission; the manager sent it "
             f"{len(to_silent)} message(s) in {copies} cop{'y' if copies == 1 else 'ies'}"
             + (" and then gave up" if gave_up else " and was still retransmitting" if to_silent else "")]
    if got_end:
        last = max(ended[d] for d in got_end)
        parts.append(f"drones {got_end} got End_Mission ({last - m.t0:.2f} s into the mission)")
    missing = [d for d in others if d not in ended]
    if missing:
        parts.append(f"drones {missing} got no End_Mission within the {m.t_end - m.t0:.1f} s watched "
                     f"(the record ended: {m.ended_by})")
    if m.exit_code is not None:
        parts.append(f"the manager exited with code {m.exit_code}")
    node.info("; ".join(parts))
    node.expect_true(not missing, "MCP-FLOW-7", "the other drones' missions go on to End_Mission",
                     "; ".join(parts))

"""PAY — the payloads of the manager's commands.

"WP_List: ... The first two bytes of the payload specify the number of waypoints that
follow." "WP_On: A single waypoint is embedded in the payload, in MAVLink format."
Mission items are MAVLink v1 MISSION_ITEM payloads, 37 bytes (E-1, E-2).
"""

from __future__ import annotations

import struct

from mcp_conform.conformance.manager_case import unpack_items
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec.codec import HEADER_SIZE, ITEM_SIZE, Action, DecodeError, decode
from mcp_conform.spec.mission import sane_item

_E1_ITEM = 33  # the description's struct string '<ffffffHHBBBBB' (erratum E-1)
_EMPTY = (int(Action.START_MISSION), int(Action.END_MISSION), int(Action.WP_OFF))
_LISTS = (int(Action.WP_LIST), int(Action.OBSTACLES_LIST))
_WP_ON = int(Action.WP_ON)
_BIG_ENDIAN_ITEM = struct.Struct(">fffffffHHBBBBB")


def _sent(m, actions):
    return [d for d in m.commands() if d.header[3] in actions]


def _item_region(d):
    return d.data[HEADER_SIZE + 2:] if d.header[3] in _LISTS else d.data[HEADER_SIZE:]


def _e1_layout(d) -> bool:
    """Items of 33 bytes (the description's struct string): MCP-PAY-4's, not a count error."""
    region = _item_region(d)
    return bool(region) and len(region) % _E1_ITEM == 0 and len(region) % ITEM_SIZE != 0


@rules("MCP-PAY-1")
def test_commands_without_payload_are_17_bytes(node):
    m = node.mission()
    node.expect_all(_sent(m, _EMPTY), lambda d: None if len(d.data) == HEADER_SIZE else f"{len(d.data)} bytes",
                    "MCP-PAY-1", "Start_Mission, End_Mission and WP_Off of exactly 17 bytes")
    node.expect_monitor_clean("MCP-PAY-1")


@rules("MCP-PAY-3")
def test_lists_carry_a_big_endian_count_and_that_many_items(node):
    m = node.mission()
    lists = [d for d in _sent(m, _LISTS) if not _e1_layout(d)]
    if not lists:
        raise Inconclusive("MCP-PAY-3: the manager sent no WP_List or Obstacles_List")

    def check(d):
        if len(d.data) < HEADER_SIZE + 2:
            return f"{len(d.data)} bytes: no count"
        count = int.from_bytes(d.data[HEADER_SIZE:HEADER_SIZE + 2], "big")
        want = HEADER_SIZE + 2 + ITEM_SIZE * count
        return None if len(d.data) == want else f"count {count} needs {want} bytes, datagram has {len(d.data)}"
    node.expect_all(lists, check, "MCP-PAY-3", "a u16 big-endian count, then exactly that many 37-byte items")


@rules("MCP-PAY-4")
def test_mission_items_are_mavlink_mission_item_payloads(node):
    """Items of 33 bytes (E-1) or items that read sanely only big-endian break the layout."""
    m = node.mission()
    carriers = _sent(m, _LISTS + (_WP_ON,))
    if not carriers:
        raise Inconclusive("MCP-PAY-4: the manager sent no mission item")

    def check(d):
        if _e1_layout(d):
            return f"items of {_E1_ITEM} bytes ({len(_item_region(d))}-byte item region)"
        region = _item_region(d)
        if len(region) % ITEM_SIZE:
            return None  # the list's length is MCP-PAY-3/5's business
        for le in unpack_items(region):
            be = _BIG_ENDIAN_ITEM.unpack(struct.pack("<fffffffHHBBBBB", *le))
            from mcp_conform.spec.codec import MissionItem

            if sane_item(le) and not sane_item(MissionItem._make(be)):
                return "items read sanely only big-endian"
        return None
    node.expect_all(carriers, check, "MCP-PAY-4", "37-byte items '<fffffffHHBBBBB' (MISSION_ITEM)")


@rules("MCP-PAY-5")
def test_wp_on_carries_one_item(node):
    m = node.mission()
    wp_on = [d for d in _sent(m, (_WP_ON,)) if not _e1_layout(d)]
    if not wp_on:
        raise Inconclusive("MCP-PAY-5: the manager sent no WP_On")
    node.expect_all(wp_on,
                    lambda d: None if len(d.data) == HEADER_SIZE + ITEM_SIZE else f"{len(d.data)} bytes",
                    "MCP-PAY-5", f"WP_On of exactly {HEADER_SIZE + ITEM_SIZE} bytes (one 37-byte item)")


@rules("MCP-PAY-6")
def test_passthrough_carries_one_valid_mavlink_frame(node):
    m = node.mission()
    frames = _sent(m, (int(Action.MAV_PASSTHROUGH),))
    if not frames:
        raise Inconclusive("MCP-PAY-6: the manager sent no Mav_Passthrough")

    def check(d):
        try:
            decode(d.data)
        except DecodeError as exc:
            return str(exc)
        return None
    node.expect_all(frames, check, "MCP-PAY-6", "one complete MAVLink frame with a valid checksum")
    node.expect_monitor_clean("MCP-PAY-6")


@rules("MCP-PAY-7")
def test_mission_items_are_sane(node):
    m = node.mission()
    carriers = [d for d in _sent(m, _LISTS + (_WP_ON,)) if d.msg is not None]
    if not carriers:
        raise Inconclusive("MCP-PAY-7: the manager sent no well-formed WP_List, WP_On or Obstacles_List")

    def check(d):
        items = (d.msg.payload,) if d.header[3] == _WP_ON else d.msg.payload
        for n, it in enumerate(items):
            problems = sane_item(it)
            if problems:
                return f"item {n}: {'; '.join(problems)}"
        return None
    node.expect_all(carriers, check, "MCP-PAY-7",
                    "finite floats, latitude in [-90, 90], longitude in [-180, 180], a known MAV_CMD and MAV_FRAME")

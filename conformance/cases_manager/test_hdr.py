"""HDR — framing of every datagram the manager sends.

"Each MCP message consists of a 17 bytes header ... base_format_string = "!7s2B4H"."
"By convention, the Mission Manager always has the ID 0." "ALL of the following messages
except ACK and Mission_Ready are always sent by the Mission Manager."
"""

from __future__ import annotations

import struct

from mcp_conform.conformance.marks import rules
from mcp_conform.spec.codec import HEADER_SIZE, MANAGER_ID, PREAMBLE, Action

_LE = struct.Struct("<HHHH")


@rules("MCP-HDR-1")
def test_every_datagram_starts_with_the_preamble(node):
    m = node.mission()
    node.expect_all(m.from_manager(), lambda d: None if d.data[:len(PREAMBLE)] == PREAMBLE
                    else f"starts {d.data[:len(PREAMBLE)].hex(' ')}", "MCP-HDR-1",
                    f"every datagram starts with {PREAMBLE.hex(' ')}")
    node.expect_monitor_clean("MCP-HDR-1")


@rules("MCP-HDR-2")
def test_header_is_17_bytes_in_network_order(node):
    """A datagram shorter than the header, or one whose header reads right only
    little-endian (dst a drone, action 0-8) and wrong big-endian, breaks the layout."""
    m = node.mission()
    ids = set(m.drones) | {node.broadcast_id}

    def check(d):
        if len(d.data) < HEADER_SIZE:
            return f"{len(d.data)} bytes"
        dst, src, seq, action = d.header
        ldst, _, _, laction = _LE.unpack_from(d.data, len(PREAMBLE))
        if (dst not in ids or action > 8) and ldst in ids and laction <= 8:
            return f"header reads dst={ldst} action={laction} only little-endian"
        return None
    node.expect_all(m.from_manager(), check, "MCP-HDR-2", "a 17-byte big-endian header (!7s2B4H)")
    node.expect_monitor_clean("MCP-HDR-2")


@rules("MCP-HDR-3")
def test_only_action_codes_0_to_8(node):
    m = node.mission()
    node.expect_all([d for d in m.from_manager() if d.header is not None],
                    lambda d: None if d.header[3] <= 8 else f"action {d.header[3]}", "MCP-HDR-3",
                    "action codes 0-8 only")
    node.expect_monitor_clean("MCP-HDR-3")


@rules("MCP-HDR-4")
def test_src_is_the_managers_id(node):
    m = node.mission()
    node.expect_all([d for d in m.from_manager() if d.header is not None],
                    lambda d: None if d.header[1] == MANAGER_ID else f"src {d.header[1]}", "MCP-HDR-4",
                    f"src {MANAGER_ID} (the Mission Manager) in every message")
    node.expect_monitor_clean("MCP-HDR-4")


@rules("MCP-HDR-5")
def test_manager_never_sends_mission_ready(node):
    m = node.mission()
    node.expect_all([d for d in m.from_manager() if d.header is not None],
                    lambda d: "a Mission_Ready" if d.header[3] == int(Action.MISSION_READY) else None,
                    "MCP-HDR-5", "no Mission_Ready from the manager (a drone's message)")
    node.expect_monitor_clean("MCP-HDR-5")

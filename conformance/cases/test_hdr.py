"""HDR — framing of everything the node sent during the run (judged late, passively).

Each case asks the trace monitor, which judged every datagram of the run as it came
(judge.run_monitor), then checks the datagrams the runner received itself.

"The Preamble is a 9-byte unique pattern. The first 7 bytes spell out “NCSU-CM” in ASCII,
the value of each of the last two bytes is 1."
"""

from __future__ import annotations

from mcp_conform.conformance.marks import rules
from mcp_conform.spec.codec import HEADER_SIZE, PREAMBLE, Action

_ON_WIRE = {int(a) for a in Action if a != Action.ANY}
_DRONE_SENDS = {int(Action.MISSION_READY), int(Action.ACK)}


@rules("MCP-HDR-1", phase="late")
def test_every_datagram_starts_with_the_preamble(node):
    node.expect_monitor_clean("MCP-HDR-1")
    node.expect_all(node.driver.received(), lambda d: None if d.preamble_ok else
                    f"starts {d.data[:9].hex(' ')}", "MCP-HDR-1", f"every datagram starts {PREAMBLE.hex(' ')}")


@rules("MCP-HDR-2", phase="late")
def test_every_datagram_has_the_17_byte_header(node):
    node.expect_monitor_clean("MCP-HDR-2")
    framed = [d for d in node.driver.received() if d.preamble_ok or len(d.data) < HEADER_SIZE]
    node.expect_all(framed, lambda d: None if len(d.data) >= HEADER_SIZE else f"{len(d.data)} bytes long",
                    "MCP-HDR-2", f"at least the {HEADER_SIZE}-byte header (!7s2B4H)")


@rules("MCP-HDR-3", phase="late")
def test_only_action_codes_0_to_8_are_sent(node):
    node.expect_monitor_clean("MCP-HDR-3")
    node.expect_all([d for d in node.driver.received() if d.header], lambda d: None if d.action in _ON_WIRE
                    else f"action code {d.action}", "MCP-HDR-3", "action codes 0-8 only (9 'Any' is API-only)")


@rules("MCP-HDR-4", phase="late")
def test_src_is_the_node_id(node):
    node.expect_monitor_clean("MCP-HDR-4")
    node.expect_all([d for d in node.driver.received() if d.header],
                    lambda d: None if d.header[1] == node.target_id else f"src {d.header[1]}",
                    "MCP-HDR-4", f"src = {node.target_id}, the node's configured ID")


@rules("MCP-HDR-5", phase="late")
def test_a_drone_sends_only_mission_ready_and_ack(node):
    node.require_observable("MCP-HDR-5")
    node.expect_monitor_clean("MCP-HDR-5")
    node.expect_all([d for d in node.driver.received() if d.header and d.action in _ON_WIRE],
                    lambda d: None if d.action in _DRONE_SENDS else f"sent {Action(d.action).name}",
                    "MCP-HDR-5", "only Mission_Ready and ACK from a drone")

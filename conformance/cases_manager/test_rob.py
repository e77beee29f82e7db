"""ROB — the manager's robustness to bad input from a drone.

Sent while the last drone is held back (the manager is surely receiving then), each
input followed by a liveness probe: a fresh Mission_Ready from the same drone, awaited
across retransmissions (MCP-ROB-5). "No ACK" is judged over the ACK window (D-6).
"""

from __future__ import annotations

from mcp_conform.conformance.manager_case import messages
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec.codec import Action


@rules("MCP-ROB-1", "MCP-ROB-5")
def test_short_datagrams_are_discarded(node):
    ins = node.inputs("MCP-ROB-1")
    node.expect_survived(ins, "MCP-ROB-1")
    node.expect_not_acked(ins, "MCP-ROB-1")


@rules("MCP-ROB-2", "MCP-ROB-5")
def test_bad_preamble_is_discarded(node):
    ins = node.inputs("MCP-ROB-2")
    node.expect_survived(ins, "MCP-ROB-2")
    node.expect_not_acked(ins, "MCP-ROB-2")


@rules("MCP-ROB-3", "MCP-ROB-5")
def test_unknown_action_code_is_discarded(node):
    ins = node.inputs("MCP-ROB-3")
    node.expect_survived(ins, "MCP-ROB-3")
    node.expect_not_acked(ins, "MCP-ROB-3")


@rules("MCP-ROB-4", "MCP-ROB-5")
def test_payload_that_does_not_fit_is_not_acked(node):
    ins = node.inputs("MCP-ROB-4")
    node.expect_survived(ins, "MCP-ROB-4")
    node.expect_not_acked(ins, "MCP-ROB-4")


@rules("MCP-ROB-5")
def test_unexpected_messages_are_survived_and_the_mission_goes_on(node):
    """A Start_Mission and a WP_List from a drone (messages a drone never sends), then the
    mission: the manager still ACKs, and still sends Start_Mission once every drone is ready."""
    m = node.mission()
    ins = node.inputs("MCP-ROB-5")
    node.expect_survived(ins, "MCP-ROB-5")
    if m.all_ready_t is None:
        raise Inconclusive("MCP-ROB-5: the last drone's Mission_Ready was never sent")
    later = [x for x in messages(m) if x.action == int(Action.START_MISSION) and x.first.t >= m.all_ready_t]
    early = [x for x in messages(m) if x.first.t < m.all_ready_t]
    node.expect_true(bool(later or early), "MCP-ROB-5",
                     "Start_Mission once every drone is ready, after the malformed and unexpected inputs",
                     f"no Start_Mission (the mission record ended: {m.ended_by})")


@rules("MCP-ROB-6")
def test_datagrams_of_65507_bytes_are_survived(node):
    node.expect_survived(node.inputs("MCP-ROB-6"), "MCP-ROB-6", live_rule="MCP-ROB-6")


@rules("MCP-ROB-7")
def test_flood_of_malformed_datagrams(node):
    ins = node.inputs("MCP-ROB-7")
    node.info(ins[0].label)
    node.expect_survived(ins, "MCP-ROB-7", live_rule="MCP-ROB-7")

"""DUP — duplicate discard. A manager's delivery of a message is not visible on the wire
(it acts on nothing a drone can see but its next commands), so these rules are SKIPPED with
the spec's reason; its ACK of every copy is MCP-ACK-1's (ACK/ cases)."""

from __future__ import annotations

from mcp_conform.conformance.marks import rules


@rules("MCP-DUP-1")
def test_duplicates_not_delivered_again(node):
    node.require_observable("MCP-DUP-1")


@rules("MCP-DUP-2")
def test_new_seq_is_delivered(node):
    node.require_observable("MCP-DUP-2")


@rules("MCP-DUP-3")
def test_duplicate_detection_is_per_source(node):
    node.require_observable("MCP-DUP-3")


@rules("MCP-DUP-4")
def test_late_copy_of_an_older_seq(node):
    node.require_observable("MCP-DUP-4")

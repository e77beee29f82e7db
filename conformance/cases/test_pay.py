"""PAY — payload formats.

"mcp_obj.send_unicast_message(mcp.Action_Codes.Mission_Ready, None, 0)" — and the manager
handler's "The buffer contains the ID of UAV that sent this message" (D-3).
"""

from __future__ import annotations

import pytest

from mcp_conform.conformance.marks import rules


@rules("MCP-PAY-2", phase="startup")
def test_mission_ready_payload(node):
    st = node.require_startup("MCP-PAY-2")
    d = st.copies[0]
    payload = d.data[17:]
    src = d.header[1] if d.header else None
    ok = payload == b"" or (len(payload) == 2 and int.from_bytes(payload, "big") == src)
    node.expect_true(ok, "MCP-PAY-2", f"no payload, or 2 bytes big-endian equal to src {src}",
                     f"payload {payload.hex(' ')} ({len(payload)} bytes)", [d.describe()])


@rules("MCP-PAY-8")
def test_passthrough_frame_reaches_the_autopilot_once(node):
    """MCP-PAY-8: "A drone linked to an autopilot forwards each delivered Mav_Passthrough
    frame to it exactly once." Written twice fails; so does a frame that reaches the
    autopilot altered (truncated, corrupted: the bytes that arrived are compared with the
    frame sent); SKIPPED only when nothing of it arrived."""
    node.require_passthrough("MCP-PAY-8", altered=True)
    d = node.deliver(node.probe())
    node.settle(d, expect_more=True)
    node.expect_delivered([(d, 1)], "MCP-PAY-8")


@pytest.mark.parametrize("rule", ["MCP-PAY-1", "MCP-PAY-4", "MCP-PAY-6"])
@rules("MCP-PAY-1", "MCP-PAY-4", "MCP-PAY-6")
def test_sender_payload_rules(node, rule):
    """What a drone never sends cannot be judged on it (the spec says why)."""
    node.require_observable(rule)

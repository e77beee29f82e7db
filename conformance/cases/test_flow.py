"""FLOW — mission flow.

"Send 'Mission_Ready' message to Mission Manager after (4) returns:
mcp_obj.send_unicast_message(mcp.Action_Codes.Mission_Ready, None, 0)"
"""

from __future__ import annotations

from mcp_conform.conformance.marks import rules
from mcp_conform.spec.codec import MANAGER_ID


@rules("MCP-FLOW-1", phase="startup")
def test_mission_ready_is_unicast_to_the_manager(node):
    st = node.require_startup("MCP-FLOW-1")
    bad = [d for d in st.copies if d.header is None or d.header[0] != MANAGER_ID]
    node.expect_true(not bad, "MCP-FLOW-1", f"Mission_Ready unicast to ID {MANAGER_ID}",
                     f"sent to ID {bad[0].header[0] if bad and bad[0].header else '?'}",
                     [d.describe() for d in bad[:2]])

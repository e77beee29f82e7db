"""TRN — transport.

"The Mission Manager and drone application communicate over UDP sockets, by convention on
ports 7889 and 7890. At the IP level, they are local subnet IP broadcasts."
"""

from __future__ import annotations

from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec import SPEC

_MANAGER_PORT = int(SPEC.protocol["ports"]["manager"])


@rules("MCP-TRN-1")
def test_ports_and_addresses_are_recorded(node):
    m = node.mission()
    sources = sorted({f"{d.addr[0]}:{d.addr[1]}" for d in m.from_manager()})
    if not sources:
        raise Inconclusive("MCP-TRN-1: the manager sent nothing")
    tgt = node.session.driver.target if node.session.driver else None
    node.info(f"the manager receives on {tgt[0]}:{tgt[1]} (convention: {_MANAGER_PORT}) and sent from "
              f"{', '.join(sources)}; the drones listen on port {node.session.driver.listen[1]}"
              if tgt else f"the manager sent from {', '.join(sources)}")


@rules("MCP-TRN-2")
def test_mission_ready_from_another_source_port_is_acked(node):
    ins = node.inputs("MCP-TRN-2")
    i = ins[0]
    node.expect_true(i.reply is not None, "MCP-TRN-2",
                     f"an ACK of Mission_Ready seq {i.sent.seq} sent from another source port",
                     f"none after {node.rto * 5:g} s (at either socket)", [i.sent.data.hex(" ")])

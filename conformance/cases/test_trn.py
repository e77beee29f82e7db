"""TRN — transport.

"The Mission Manager and drone application communicate over UDP sockets, by convention on
ports 7889 and 7890. At the IP level, they are local subnet IP broadcasts."
"""

from __future__ import annotations

import contextlib

from mcp_conform.conformance.marks import rules
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action


@rules("MCP-TRN-1", phase="late")
def test_ports_by_convention(node):
    got = node.driver.received()
    ports = sorted({d.addr[1] for d in got})
    node.info(f"the node sent from UDP port(s) {ports or 'none'} to the runner's port "
              f"{node.driver.listen[1]} and listens on {node.driver.target[1]} "
              f"(convention: drone {SPEC.protocol['ports']['drone']}, manager {SPEC.protocol['ports']['manager']})")


@rules("MCP-TRN-2")
def test_datagram_from_another_source_port_is_accepted(node):
    sock = node.driver.open_side_socket()
    with contextlib.closing(sock):
        port = sock.getsockname()[1]
        sent, ack = node.command_from(sock, Action.WP_OFF)
    if ack is None:  # one fault, one root: a node that ACKs nothing from the runner's own port either
        node.prove_live("node not live after the command from another port: its silence proves nothing")
    node.expect_true(ack is not None, "MCP-TRN-2",
                     f"an ACK of seq {sent.seq}, a command sent from source port {port} "
                     f"instead of the runner's {node.driver.listen[1]}",
                     "no ACK at either of the runner's sockets")

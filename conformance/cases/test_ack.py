"""ACK — acknowledgement.

"Unicast MCP messages should be replied to with an MCP acknowledgement message." —
"An ACK is sent by the drone application or Mission Manager for every unicast message
received." — "if the message is destined for itself, ACK, otherwise no ACKing."
"""

from __future__ import annotations

from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action, MissionItem
from mcp_conform.spec.mavframe import heartbeat_frame

_ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 1, 16, 1, 1, 3, 0, 1)
_COMMANDS = (
    ("WP_List", Action.WP_LIST, (_ITEM, _ITEM._replace(seq=2))),
    ("WP_On", Action.WP_ON, _ITEM),
    ("WP_Off", Action.WP_OFF, None),
    ("Obstacles_List", Action.OBSTACLES_LIST, (_ITEM,)),
    ("Mav_Passthrough", Action.MAV_PASSTHROUGH, heartbeat_frame()),
)


@rules("MCP-ACK-1")
def test_every_command_type_is_acked(node):
    """Commands of every type a manager sends, waited for by the application or not."""
    exchanges = [(label, node.command(action, payload)) for label, action, payload in _COMMANDS]
    node.expect_acked(exchanges)


@rules("MCP-ACK-1")
def test_every_retransmitted_copy_is_acked(node):
    """A copy with the same seq and bytes (a retransmission) is ACKed again."""
    first = node.command(Action.WP_OFF)
    copies = [node.await_ack(node.resend(first.first)) for _ in range(2)]
    node.expect_each_copy_acked(first, copies)


@rules("MCP-ACK-2")
def test_ack_payload_is_the_big_endian_seq(node):
    exchanges = [node.command(Action.WP_OFF) for _ in range(2)]
    node.expect_ack_format(exchanges, "MCP-ACK-2")


@rules("MCP-ACK-3")
def test_ack_is_addressed_back_to_the_sender(node):
    """From the manager's ID 0, then from another src: from 0 alone a node whose ACKs always
    go to ID 0 looks right. The other src's numbers are set as MCP-DUP-3's case sets them
    (below the manager's, once a run). A node that answers no message from the other src
    (D-10 lets it ignore them) shows nothing of where its ACKs go: skipped with that reason,
    never passed."""
    exchanges = [node.command(Action.WP_OFF) for _ in range(2)]
    node.expect_ack_format(exchanges, "MCP-ACK-3")
    other = node.other_id()
    drv = node.driver
    if node.session.other_src_accepted is not False:
        if not drv.sent_as(other):
            drv.set_seq(drv.peek_seq() // 2, src=other)
        first = node.command(Action.WP_OFF, src=other)
        if first.acked:
            node.session.other_src_accepted = True
            node.expect_ack_format([first, node.command(Action.WP_OFF, src=other)], "MCP-ACK-3")
            return
        node.prove_live("node lost during this case: it answers no liveness probe either")
        node.session.other_src_accepted = False
    raise Inconclusive(f"MCP-ACK-3: the node answers no message from src {other} (D-10: a drone may ignore "
                       "a command from a src other than the manager's 0), so whether its ACKs go back to "
                       "their sender, not always to ID 0, is unobservable; from ID 0 they were right")


@rules("MCP-ACK-4")
def test_broadcast_is_not_acked(node):
    sent = [node.send(Action.WP_OFF, dst=node.broadcast_id),
            node.send(Action.WP_ON, _ITEM, dst=node.broadcast_id)]
    node.expect_silence(sent, "MCP-ACK-4")


@rules("MCP-ACK-5")
def test_message_to_another_id_is_neither_acked_nor_acted_on(node):
    other = node.other_id()
    probes = []
    sent = [node.send(Action.WP_OFF, dst=other)]
    if node.vehicle is not None and node.vehicle.connections:
        p = node.probe()
        probes.append(p)
        sent.append(node.send(Action.MAV_PASSTHROUGH, p.frame, dst=other))
    node.expect_silence(sent, "MCP-ACK-5", also_not_delivered=probes)


@rules("MCP-ACK-6")
def test_an_ack_is_never_acked(node):
    unknown = (node.driver.peek_seq() + 0x4000) & 0xFFFF  # names nothing we sent
    node.expect_silence([node.send(Action.ACK, unknown)], "MCP-ACK-6")


@rules("MCP-ACK-7")
def test_ack_leaves_within_the_deadline(node):
    """Judged on the median of several samples, each a fresh command."""
    samples = []
    patience = max(node.rto, 1.0)  # no retransmission before a slow ACK can arrive
    for _ in range(max(5, int(SPEC.params["ack_latency_samples"]))):
        lat = node.driver.exchange(node.send(Action.WP_OFF), rto=patience, copies=2).latency()
        if lat is not None:
            samples.append(lat)
        else:
            node.info("one sample was ambiguous (retransmitted before its ACK) and is left out")
        node.session.clock.sleep(0.02)
    node.expect_median_latency(samples, float(SPEC.params["ack_deadline_s"]), "MCP-ACK-7")

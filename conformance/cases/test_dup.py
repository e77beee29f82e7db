"""DUP — duplicate discard, observed through the simulated vehicle: each delivered
Mav_Passthrough probe reaches the autopilot, so a duplicate delivery shows as a count.

"The receiver discards duplicates received for a message, if any."
"""

from __future__ import annotations

from mcp_conform.conformance.drone_case import DELIVERED, NOT_AGAIN
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive


@rules("MCP-DUP-1")
def test_same_seq_twice_is_delivered_once(node):
    """The copy is the copy of the message last delivered from the manager: nothing of
    another case's between the two (``in_a_row``, beside the schedule's batch), or a node that
    remembers only the last seq, as the rule words it, would see a late copy of an older
    message (MCP-DUP-4's open question) and be failed for delivering it."""
    node.require_passthrough("MCP-DUP-1")
    with node.in_a_row():  # until the copy is ACKed: the window after it holds nobody back
        first = node.deliver(node.probe())
        again = node.redeliver(first, first.exchange.first, watch=False)
    node.settle(again, expect_more=True)
    node.expect_delivered([(first, DELIVERED), (again, NOT_AGAIN)], "MCP-DUP-1")


@rules("MCP-DUP-2")
def test_new_seq_with_the_same_bytes_is_delivered(node):
    node.require_passthrough("MCP-DUP-2")
    probe = node.probe()
    first = node.deliver(probe)
    second = node.deliver(probe)  # same payload, next seq
    node.expect_delivered([(first, DELIVERED), (second, DELIVERED)], "MCP-DUP-2")


@rules("MCP-DUP-3")
def test_same_seq_from_another_src_is_not_a_duplicate(node):
    """The other src's numbers start below the manager's, so the manager's seq is new for that
    src even to a node that (wrongly, MCP-SEQ-3) compares numbers as plain integers; set once a
    run: a second attempt (``--impair`` retries a spoiled one) goes on from that src's last
    number, since repeating one of its own would be a duplicate for it (MCP-DUP-1), and a
    node that discards it is no node that "does not accept commands from" that src."""
    node.require_passthrough("MCP-DUP-3")
    other = node.other_id()
    if node.session.other_src_accepted is False:  # MCP-ACK-3's case found it so (alive)
        raise Inconclusive(f"MCP-DUP-3: the node answers no message from src {other} (D-10: a drone may "
                           "ignore a command from a src other than the manager's 0), so per-source "
                           "detection is unobservable")
    drv = node.driver
    if not drv.sent_as(other):
        drv.set_seq(drv.peek_seq() // 2, src=other)
    accepted = node.deliver(node.probe(), src=other)
    if not accepted.exchange.acked:
        node.prove_live("node lost during this case: it answers no liveness probe either")
    node.session.other_src_accepted = accepted.exchange.acked
    if not accepted.exchange.acked or accepted.delivered <= 0:
        raise Inconclusive(f"MCP-DUP-3: the node does not accept commands from src {other} "
                           f"({'not delivered' if accepted.exchange.acked else 'not ACKed'}; D-10: a drone "
                           "may ignore a command from a src other than the manager's 0), so per-source "
                           "detection is unobservable")
    from_manager = node.deliver(node.probe())
    same_seq = node.deliver(node.probe(), src=other, seq=from_manager.exchange.seq)
    node.expect_delivered([(from_manager, DELIVERED), (same_seq, DELIVERED)], "MCP-DUP-3")


@rules("MCP-DUP-4")
def test_late_copy_of_an_older_message(node):
    """Not specified: A (seq s), B (seq s+1), then A's copy again; report what happened."""
    node.require_passthrough("MCP-DUP-4")
    a = node.deliver(node.probe())
    node.deliver(node.probe())
    late = node.redeliver(a, a.exchange.first)
    node.info(f"a late copy of an older message (seq {a.exchange.seq}) was "
              f"{'ACKed' if late.exchange.acked else 'not ACKed'} and "
              f"{'delivered again' if late.delivered > 0 else 'not delivered again'}")

"""SEQ — sequence numbers.

"Each sender of MCP messages ... starts with an arbitrary initial sequence number value,
and then increments it for successive messages. Retransmissions of the same message are
identified by repeating sequence number."
"""

from __future__ import annotations

from mcp_conform.conformance.cases.ready_copies import by_number, renumbered
from mcp_conform.conformance.drone_case import DELIVERED
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive


@rules("MCP-SEQ-1", phase="late")
def test_successive_messages_take_successive_numbers(node):
    """The numbers of every new message the node sent in the whole run (D-5: its ACKs may take
    numbers), as the trace monitor judged them: not the observed startup's, so the verdict is
    the same on every node instance of ``--parallel`` (each on its own node's traffic, the
    worst kept; ``conformance.schedule``), whether it observed the startup or ran the quick
    one. A drone sends one new non-ACK message per mission: the spec's reason to skip."""
    node.require_observable("MCP-SEQ-1")
    node.expect_monitor_clean("MCP-SEQ-1")


@rules("MCP-SEQ-2", phase="startup")
def test_retransmission_repeats_seq_and_bytes(node):
    """Mission_Ready copies sent while the runner withholds the ACK. Those that repeat its
    number are its copies ("Retransmissions of the same message are identified by repeating
    sequence number"): a new Mission_Ready after them, once the node gave them up, is a new
    message (MCP-RTX-1 counts the copies). Sent once, then again under new numbers while the
    ACK is withheld: a retransmission renumbered (``cases.ready_copies``)."""
    st = node.require_startup("MCP-SEQ-2")
    copies = st.copies if renumbered(st) else by_number(st)
    if len(copies) < 2:
        raise Inconclusive("MCP-SEQ-2: the node did not retransmit Mission_Ready (see MCP-RTX-1)")
    first = copies[0]
    bad = [d for d in copies[1:] if d.data != first.data]
    node.expect_true(not bad, "MCP-SEQ-2",
                     f"every copy of Mission_Ready repeats seq {first.header[2] if first.header else '?'} "
                     "and its bytes exactly",
                     f"{len(bad)} of {len(copies) - 1} copies differ",
                     [f"first: {first.data.hex(' ')}"] + [f"copy:  {d.data.hex(' ')}" for d in bad[:3]])


@rules("MCP-SEQ-3", phase="late")
def test_zero_after_65535_is_new(node):
    """Hop the runner's seq up to 65535 in steps under half the space (so a node using
    serial-number arithmetic sees each as newer), then send 0: it must be delivered.
    A node that got this wrong would take every later message for a duplicate, so in
    spawn mode the next case gets a fresh node."""
    node.require_passthrough("MCP-SEQ-3")
    node.fresh_node_after()
    drv = node.driver
    seq = drv.peek_seq()
    while (65535 - seq) & 0xFFFF > 16000:
        seq = (seq + 16000) & 0xFFFF
        drv.set_seq(seq)
        node.deliver(node.probe(), wait_delivery=False)
        seq = drv.peek_seq()
    drv.set_seq(65535)
    top = node.deliver(node.probe())
    zero = node.deliver(node.probe())  # the driver's counter wrapped: seq 0
    assert zero.exchange.seq == 0
    node.expect_delivered([(top, DELIVERED), (zero, DELIVERED)], "MCP-SEQ-3")


@rules("MCP-SEQ-4", phase="startup")
def test_initial_sequence_number_is_recorded(node):
    st = node.require_startup("MCP-SEQ-4")
    d = st.copies[0]
    node.info(f"initial sequence number of the node (its Mission_Ready): {d.header[2] if d.header else '?'}")

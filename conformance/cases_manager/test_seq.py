"""SEQ — the manager's sequence numbers.

"Sequence number is incremented during every send." "The retransmitted message carries
the same sequence number as the original."
"""

from __future__ import annotations

from mcp_conform.conformance.manager_case import messages, withheld_copies
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action


class _New:
    def __init__(self, d):
        self.first, self.seq = d, d.header[2]


@rules("MCP-SEQ-1")
def test_each_new_message_takes_the_next_seq(node):
    """Between two successive new messages the seq advances by 1, or further by the numbers
    the manager's ACKs took in between (D-5: an ACK may or may not take a number): every
    number skipped must be one an ACK of the manager carried. Judged on the numbers, not on
    arrival order: the manager's datagrams to different drones reach the runner's sockets
    in an order of the host's choosing, so an ACK that took the number before a message
    may be read just after it."""
    m = node.mission()
    msgs, seen = [], set()
    for d in m.commands():  # each seq once: a copy with the same seq is not a new message
        if d.header[2] not in seen:
            seen.add(d.header[2])
            msgs.append(_New(d))
    if len(msgs) < 2:
        raise Inconclusive("MCP-SEQ-1: fewer than two messages from the manager")
    acks = [(d.t, d.header[2]) for d in m.from_manager() if d.is_ack_like and d.header is not None]
    for a, b in zip(msgs, msgs[1:], strict=False):
        step = (b.seq - a.seq) & 0xFFFF
        near = {seq for t, seq in acks if a.first.t - _NEAR_S < t < b.first.t + _NEAR_S}
        skipped = [(a.seq + k) & 0xFFFF for k in range(1, step)] if step <= 1 + len(near) else None
        node.expect_true(step >= 1 and skipped is not None and all(s in near for s in skipped), "MCP-SEQ-1",
                         f"seq {(a.seq + 1) & 0xFFFF} after seq {a.seq}, or later by the numbers its ACKs "
                         f"took in between ({len(near)} ACKs of the manager around them)", f"seq {b.seq}",
                         [a.first.describe(), b.first.describe()])


#: how far from a pair of messages an ACK's number still counts for the gap between them
_NEAR_S = float(SPEC.params["seq_reorder_grace_s"])


@rules("MCP-SEQ-2")
def test_retransmission_repeats_seq_and_bytes(node):
    m = node.mission()
    w = m.withheld
    copies = withheld_copies(w)  # by number; all of them where it was sent once, then renumbered
    if len(copies) < 2:
        raise Inconclusive("MCP-SEQ-2: the manager did not retransmit Start_Mission (see MCP-RTX-1)")
    first = copies[0]
    bad = [d for d in copies[1:] if d.data != first.data]
    node.expect_true(not bad, "MCP-SEQ-2", f"every copy of Start_Mission to drone {w.drone} repeats seq "
                     f"{first.header[2]} and its bytes", f"{len(bad)} of {len(copies) - 1} copies differ"
                     + (f" (seq {bad[0].header[2]})" if bad and bad[0].header else ""),
                     [first.describe()] + [d.describe() for d in bad[:2]])


@rules("MCP-SEQ-3")
def test_wrap_as_receiver(node):
    node.require_observable("MCP-SEQ-3")


@rules("MCP-SEQ-4")
def test_initial_seq_is_recorded(node):
    m = node.mission()
    msgs = [d for d in m.from_manager() if d.header is not None]
    if not msgs:
        raise Inconclusive("MCP-SEQ-4: the manager sent nothing")
    first_cmd = next((x for x in messages(m)), None)
    node.info(f"the manager's first datagram carries seq {msgs[0].header[2]} "
              f"({Action(msgs[0].header[3]).name if msgs[0].header[3] <= 9 else msgs[0].header[3]})"
              + (f"; its first command seq {first_cmd.seq}" if first_cmd else ""))

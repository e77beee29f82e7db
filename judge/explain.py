"""Attribution as one algorithm: which ACK answered which copy, decided over every explanation
of a trace consistent with stated bounds (issue 38, item 1).

The model is one direction of MCP unicast, a sender ``S`` and a receiver ``R``: the copies
``S`` sent (:class:`Copy`: a message's sequence number, its identity, the time the observer
saw it), the ACKs ``R`` or anyone else sent ``S`` (:class:`Ack`: the time seen, the number its
payload names, ``None`` for a payload that is not 2 bytes), and :class:`Bounds`: how far an
observed time may lie from the datagram's true time (the runner's receive backlog, the run
delay ``harness/run_delay.py`` measures, a link's delay), how soon a node answers (the ACK
window, ``--ack-window``, D-6) and when a sender retransmits (``--rto`` and RTX-3's
tolerance).

An *explanation* assigns each ACK to at most one copy it could answer -- with a latency of
at least zero and within the bounds -- each copy drawing any number of ACKs (D-9: every copy
is ACKed, and nothing forbids answering one more than once, so a count of ACKs above the
copies proves nothing), or, for the sender's
retransmission, assigns the end of a message's retransmission a cause: an ACK that reached
the sender before it, or a give-up at a timer's expiry. A rule is:

- ``proven`` when every consistent explanation violates it; the evidence is one explanation
  (the one that comes nearest to keeping the rule: a maximum matching) and the set of
  copies or ACKs that no explanation can satisfy together (Hall's condition, read off the
  matching), written for a person;
- ``consistent`` when some explanation keeps it (that explanation is the evidence);
- ``unobservable`` when the trace holds nothing the rule speaks about, or cannot be
  explained at all within the bounds (then another rule, or the bounds, are wrong).

Which ACK answered which copy is a bipartite matching problem (Kuhn's augmenting paths,
polynomial; :mod:`judge.explain_model`), with a small search where D-6 leaves a choice. The
time bounds are checked per (ACK, copy) pair, a relaxation of the joint constraint that one
datagram has one delay, and each rule is decided over its own explanations: both admit more
explanations than the exact model, so a rule proven here is proven there too (sound; it may
leave undecided what a joint check would prove).

Rules decided (docs/spec.md, spec/mcp.yaml):

- MCP-ACK-1 (receiver, :mod:`judge.explain_ack1`): the rule as observed (D-6): a node may
  miss the first copies of a message, at most ``max_ack_copies - 1``, and answers every copy
  after one it answered, by an ACK of any payload within the ACK window; every ACK of ``R``'s
  to ``S`` answers something. Only on a complete trace.
- MCP-ACK-2 (receiver): every ACK from ``R`` to ``S`` answers a copy whose number it names (or
  a datagram ``S`` sent that a node must not ACK, :attr:`Copy.ackable` false: MCP-ACK-4/6's
  business, not ACK-2's): proven where an ACK names a number no copy before it carried
  (D-9). Only on a complete trace, where an ACK cannot answer a copy the
  capture missed. ``MCP-ACK-1 or MCP-ACK-2`` is reported too: a message never answered
  except, perhaps, by ACKs naming other numbers violates one of them in every explanation.
- MCP-RTX-1 (sender): a sender that stops retransmitting with no ACK reaching it has sent
  at least ``min_copies`` copies of its own (copies the link made, :attr:`Copy.link_copy`,
  are not retransmissions). A silence after its last copy shows a stop only when it is past
  the timeout in the time the sender could run: less the run delay (D-7) its readings
  (:attr:`Trace.run_delay`) allow over it, since a copy due while it was off the CPU goes late.
- MCP-RTX-2 (sender): what ended a message's retransmission is an ACK from ``R`` naming its
  number. ``MCP-RTX-1 or MCP-RTX-2`` is reported too: where a stop could be either a give-up
  too early or a wrong ACK taken, every explanation violates one of them.

Sans-I/O: no clock, socket, file or thread; times are seconds on the observer's clock.
"""

from __future__ import annotations

from mcp_conform.judge.explain_model import (
    CONSISTENT,
    EITHER_ACK,
    EITHER_RTX,
    PROVEN,
    UNOBSERVABLE,
    Ack,
    Bounds,
    Copy,
    Trace,
    Verdict,
)
from mcp_conform.judge.explain_receiver import decide_receiver
from mcp_conform.judge.explain_sender import decide_message, decide_sender

__all__ = [
    "CONSISTENT",
    "EITHER_ACK",
    "EITHER_RTX",
    "PROVEN",
    "UNOBSERVABLE",
    "Ack",
    "Bounds",
    "Copy",
    "Trace",
    "Verdict",
    "decide",
    "decide_message",
    "decide_receiver",
    "decide_sender",
]


def decide(trace: Trace, b: Bounds, side: str) -> dict[str, Verdict]:
    """The verdicts of the node on ``side`` ("receiver": ACK-1/2; "sender": RTX-1/2)."""
    if side == "receiver":
        return decide_receiver(trace, b)
    if side == "sender":
        return decide_sender(trace, b)
    raise ValueError(f"side is 'receiver' or 'sender', not {side!r}")

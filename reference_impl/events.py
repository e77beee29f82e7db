"""Typed events emitted by the sans-I/O :class:`~reference_impl.endpoint.Endpoint`.

Every event is a frozen dataclass. Events that report a peer's mistake or an input the
transition table does not allow carry the ID of the rule involved (``rule``), so logs,
reports and fuzz findings speak the catalogue's language (STYLE.md §6). Nothing a peer
sends ever raises: it becomes one of these events.

The events, by what the endpoint saw or did:

- :class:`MessageDelivered` — a new message for the application (unicast to our ID or a
  broadcast), already ACKed where MCP-ACK-1 says so;
- :class:`DuplicateDiscarded` — a copy of the last message delivered from that source
  (MCP-DUP-1: "ACKed again but not delivered to the application again");
- :class:`AckSent` — we acknowledged a unicast copy (MCP-ACK-1/2/3);
- :class:`AckReceived` — the ACK that ends the in-flight message's retransmission (MCP-RTX-2);
- :class:`DeliveryConfirmed` / :class:`DeliveryFailed` — the outcome of one of our unicasts
  (MCP-RTX-1: retransmitted "until it is ACKed or its retry limit is reached");
- :class:`Retransmitted` — one more copy of the in-flight message left (MCP-SEQ-2);
- :class:`Malformed` — a datagram the codec rejected (MCP-ROB-1..4, MCP-PAY-6), dropped;
- :class:`Unexpected` — a well-formed input that the state table does not allow or that
  is not for us (e.g. MCP-ACK-5, MCP-RTX-2), survived and reported.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mcp_conform.spec.codec import Message

__all__ = [
    "AckReceived",
    "AckSent",
    "Address",
    "DeliveryConfirmed",
    "DeliveryFailed",
    "DuplicateDiscarded",
    "Event",
    "Malformed",
    "MessageDelivered",
    "Retransmitted",
    "Unexpected",
]

#: A transport address as the transport gives it (``(host, port)`` for UDP); opaque here.
Address = Any


@dataclass(frozen=True, slots=True)
class Event:
    """Base class of every endpoint event."""


@dataclass(frozen=True, slots=True)
class MessageDelivered(Event):
    """A new message for the application: unicast to our ID (already ACKed) or broadcast."""

    msg: Message
    addr: Address


@dataclass(frozen=True, slots=True)
class DuplicateDiscarded(Event):
    """A copy of a message already delivered from ``msg.src``: ACKed again if unicast, not delivered.

    ``rule`` MCP-DUP-1: "A message with the same (src, seq) as the one last delivered from
    that src is a duplicate: ACKed again (MCP-ACK-1) but not delivered to the application
    again." ``rule`` MCP-DUP-4: a late copy of an older seq, one of the endpoint's
    ``dup_window`` most recent from that src and not ahead of the highest delivered (the
    catalogue leaves this case open; the endpoint discards it).
    """

    msg: Message
    addr: Address
    rule: str = "MCP-DUP-1"


@dataclass(frozen=True, slots=True)
class AckSent(Event):
    """We acknowledged ``acked_seq`` from ``dst`` (MCP-ACK-1/2/3); ``seq`` is the ACK's own (D-5)."""

    acked_seq: int
    dst: int
    seq: int
    addr: Address


@dataclass(frozen=True, slots=True)
class AckReceived(Event):
    """An ACK from the in-flight message's destination carrying its sequence number (MCP-RTX-2)."""

    seq: int
    src: int
    handle: int
    addr: Address


@dataclass(frozen=True, slots=True)
class DeliveryConfirmed(Event):
    """Our unicast ``handle`` (sent with ``seq``) was ACKed by ``dst`` after ``copies`` copies."""

    handle: int
    seq: int
    dst: int
    copies: int


@dataclass(frozen=True, slots=True)
class DeliveryFailed(Event):
    """Our unicast ``handle`` was never ACKed: the retry limit ran out (MCP-RTX-1)."""

    handle: int
    seq: int
    dst: int
    copies: int
    reason: str
    rule: str = "MCP-RTX-1"


@dataclass(frozen=True, slots=True)
class Retransmitted(Event):
    """Copy number ``copy`` (2, 3, ...) of the in-flight message left, same seq and bytes (MCP-SEQ-2)."""

    handle: int
    seq: int
    dst: int
    copy: int


@dataclass(frozen=True, slots=True)
class Malformed(Event):
    """A datagram the codec rejected; dropped without ACK or delivery (``rule`` from DecodeError)."""

    data: bytes
    addr: Address
    rule: str
    reason: str


@dataclass(frozen=True, slots=True)
class Unexpected(Event):
    """A well-formed input not for us or not allowed in the current state; survived, not acted on."""

    msg: Message | None
    addr: Address
    rule: str
    reason: str

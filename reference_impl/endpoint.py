"""The sans-I/O MCP endpoint: bytes and ``now`` in, events and datagrams out.

In the style of h11 and aioquic, :class:`Endpoint` never touches a socket, a clock or a
sleep. Its caller (an asyncio transport, a test's in-memory link, a simulator) feeds it
datagrams with the time they arrived, asks for the datagrams to send, and wakes it at
:meth:`Endpoint.get_timer`::

    ep = Endpoint(node_id=1)
    ep.receive_datagram(data, addr, now=t)          # queues events and ACKs
    for ev in ep.events(): ...                      # MessageDelivered, Malformed(rule=...), ...
    for data, addr in ep.datagrams_to_send(now=t): ...
    ep.handle_timer(now=ep.get_timer())            # retransmits, or gives up: DeliveryFailed

Receiving (identical whatever we are sending):

- MCP-ACK-1: "a node ACKs every well-formed unicast message addressed to its own ID other
  than an ACK — every copy, retransmissions included"; the ACK's payload is the acked
  sequence number, big-endian (ACK-2, D-2); its dst is the message's src, its src our ID
  (ACK-3); it takes the next sequence number of its own (D-5).
- No ACK for a broadcast (ACK-4), a message to another ID (ACK-5, not acted on either), an
  ACK (ACK-6) or a malformed datagram (ROB-1..4, D-4: "discarded without ACK and without
  delivery").
- MCP-DUP-1: "A message with the same (src, seq) as the one last delivered from that src
  is a duplicate: ACKed again but not delivered to the application again"; a late copy of
  one of the last ``dup_window`` seqs delivered from that src is discarded too when it is
  not ahead of the *highest* seq delivered from it (our answer to the open MCP-DUP-4, so a
  reordering link never delivers twice); any seq ahead of the highest is new (DUP-2), per
  source (DUP-3), so 0 after 65535 is new (SEQ-3).

Sending:

- MCP-SEQ-1: each new message (ACKs included, D-5) takes the previous number plus one,
  modulo 65536; a unicast takes its number when it goes on the wire, not when queued.
- MCP-BLK-1 (stop-and-wait): one unicast in flight, later ones queued in order.
- MCP-RTX-1/3: the in-flight message is repeated every ``timeout`` until ACKed or
  ``retries`` retransmissions have gone unanswered; MCP-SEQ-2: "A retransmission repeats
  the original's sequence number and bytes exactly."
- MCP-RTX-2: "Only an ACK from the message's destination whose payload equals the
  message's sequence number ends its retransmission."
- MCP-RTX-4: broadcasts go out at once, once.

The transitions are the table in :mod:`reference_impl._transitions`; an input the table
does not allow becomes an :class:`~reference_impl.events.Unexpected` event. Only misuse by
our own caller raises (:class:`~spec.codec.LocalProtocolError`).
"""

from __future__ import annotations

import random
import struct
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from mcp_conform.reference_impl._transitions import FALLBACK_RULE, TRANSITIONS, Input, State
from mcp_conform.reference_impl.events import (
    AckReceived,
    AckSent,
    Address,
    DeliveryConfirmed,
    DeliveryFailed,
    DuplicateDiscarded,
    Event,
    Malformed,
    MessageDelivered,
    Retransmitted,
    Unexpected,
)
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import (
    BROADCAST_ID,
    PREAMBLE,
    Action,
    LocalProtocolError,
    Message,
    encode_payload,
    try_decode,
)

__all__ = ["Endpoint", "State"]

_ACK = int(Action.ACK)
_IDLE, _MALFORMED = State.IDLE, Input.MALFORMED
#: one state's transitions: input kind -> (handler, next state, the next state's row)
_Row = dict[Input, tuple[Callable[..., None], State, Any]]
_SEQ_MOD = 0x10000
_SERIAL_HALF = 0x8000  # serial-number arithmetic: "behind" means less than half the space back
#: The header after the preamble (dst, src, seq, action), from the spec's header table.
_HEAD = struct.Struct(SPEC.header["struct"][0] + "".join(
    f["code"] for f in SPEC.header["fields"] if "const" not in f))
#: The same, followed by an ACK's payload: the acknowledged seq (MCP-ACK-2, D-2).
_ACK_HEAD = struct.Struct(_HEAD.format + SPEC.payloads["ack"]["struct"].lstrip("!<>=@"))


@dataclass(slots=True)
class _Unicast:
    """One unicast of ours: queued, then in flight (seq and bytes fixed at first copy)."""

    handle: int
    action: int
    payload: bytes
    dst: int
    timeout: float
    retries: int
    seq: int = -1
    data: bytes = b""
    copies: int = 0
    deadline: float = 0.0


def _u16(name: str, value: Any) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value < _SEQ_MOD:
        raise LocalProtocolError(f"{name} must be an integer 0-65535, got {value!r}")
    return value


class Endpoint:
    """One MCP node's protocol state: no I/O, no clock; see the module docstring.

    ``timeout`` (seconds between copies) and ``retries`` (retransmissions after the first
    copy) default to the spec's parameters and may be overridden per :meth:`send`.
    ``initial_seq`` is the sequence number of the first message (arbitrary by default,
    MCP-SEQ-4), drawn from ``rng`` (a ``random.Random``) when not given. ``dup_window``:
    how many recently delivered seqs per source are remembered for duplicate discard
    (1 = only the last, exactly MCP-DUP-1; see ``_deliver``).
    """

    def __init__(self, node_id: int, *, timeout: float = SPEC.params["timeout_s"],
                 retries: int = int(SPEC.params["retries"]), broadcast_id: int = BROADCAST_ID,
                 initial_seq: int | None = None, rng: random.Random | None = None,
                 dup_window: int = 64) -> None:
        self.node_id = _u16("node_id", node_id)
        self.broadcast_id = _u16("broadcast_id", broadcast_id)
        if node_id == broadcast_id:
            raise LocalProtocolError(f"node ID {node_id} is the broadcast ID (D-1)")
        self.timeout = self._check_timeout(timeout)
        self.retries = self._check_retries(retries)
        if initial_seq is None:
            initial_seq = (rng or random.Random()).randrange(_SEQ_MOD)
        self._seq = _u16("initial_seq", initial_seq)
        self._state = State.IDLE
        self._in_flight: _Unicast | None = None
        self._queue: deque[_Unicast] = deque()
        self._next_handle = 1
        self.dup_window = max(1, int(dup_window))
        # src -> the last ``dup_window`` seqs delivered from it, the last one last (MCP-DUP-1)
        self._recent: dict[int, deque[int]] = {}
        # src -> the highest seq delivered from it, in serial arithmetic (see ``_deliver``)
        self._highest: dict[int, int] = {}
        # src -> a bound on how far (serial) its remembered seqs lie behind its highest (never
        # less than the farthest): ``_deliver`` looks for seqs to forget only once it reaches half the space
        self._far: dict[int, int] = {}
        self._events: deque[Event] = deque()
        self._outgoing: list[tuple[bytes, Address | None]] = []
        # TRANSITIONS as one row per state: kind -> (handler, next state, the next state's row)
        rows: dict[State, _Row] = {s: {} for s in State}
        for (state, kind), t in TRANSITIONS.items():
            rows[state][kind] = (getattr(self, "_on_" + t.handler), t.next_state, rows[t.next_state])
        self._row = rows[self._state]  # the current state's

    # ------------------------------------------------------------------ inspection
    @property
    def state(self) -> State:
        """``State.IDLE`` or ``State.AWAITING_ACK`` (one unicast in flight)."""
        return self._state

    @property
    def next_seq(self) -> int:
        """The sequence number the next new message will carry."""
        return self._seq

    @property
    def in_flight(self) -> tuple[int, int, int] | None:
        """``(handle, seq, dst)`` of the unicast awaiting its ACK, or None."""
        u = self._in_flight
        return None if u is None else (u.handle, u.seq, u.dst)

    @property
    def queued(self) -> int:
        """How many unicasts wait behind the in-flight one (MCP-BLK-1)."""
        return len(self._queue)

    # ------------------------------------------------------------------ caller's API
    def send(self, action: int, payload: Any, dst: int, *, now: float,
             timeout: float | None = None, retries: int | None = None) -> int:
        """Send a message; returns its handle (an int, not the seq, which is fixed on the wire).

        ``dst == broadcast_id``: a broadcast, on the wire at once, once (MCP-RTX-4), no
        outcome event. Otherwise a unicast: in flight at once if nothing else is, else
        queued (MCP-BLK-1); its outcome is a ``DeliveryConfirmed`` or ``DeliveryFailed``
        event with this handle. Raises ``LocalProtocolError`` on a message the spec forbids
        (an ACK, action ``ANY``, a bad payload or ID).
        """
        action = int(action)
        if action == _ACK:
            raise LocalProtocolError("ACKs are sent by the endpoint itself (MCP-ACK-1), not by send()")
        body = encode_payload(action, payload)  # raises LocalProtocolError (MCP-HDR-3, PAY-*)
        dst = _u16("dst", dst)
        if dst == self.node_id:
            raise LocalProtocolError(f"cannot send to our own ID {dst}")
        u = _Unicast(self._next_handle, action, body, dst,
                     self.timeout if timeout is None else self._check_timeout(timeout),
                     self.retries if retries is None else self._check_retries(retries))
        self._next_handle += 1
        kind = Input.SEND_BROADCAST if dst == self.broadcast_id else Input.SEND_UNICAST
        self._step(kind, None, None, now, u)
        return u.handle

    def receive_datagram(self, data: bytes, addr: Address, now: float) -> None:
        """Take one datagram that arrived at ``now`` from ``addr``. Never raises."""
        try:
            msg, bad = try_decode(data)
        except Exception as exc:  # noqa: BLE001 - a codec bug must not stop the node (ROB-5)
            self._step(_MALFORMED, None, addr, now, (data, (FALLBACK_RULE, f"codec error: {exc!r}")))
            return
        if msg is None:  # MCP-ROB-1..4, PAY-6: bad is (rule, reason)
            self._step(_MALFORMED, None, addr, now, (data, bad))
            return
        if msg.src == self.node_id:
            kind = Input.FROM_SELF
        elif msg.src == self.broadcast_id:
            kind = Input.FROM_BROADCAST_ID
        elif msg.action == _ACK:
            if msg.dst != self.node_id:
                kind = Input.NOT_FOR_ME
            else:
                u = self._in_flight
                kind = (Input.ACK_MATCHING if u is not None and msg.src == u.dst and msg.payload == u.seq
                        else Input.ACK_OTHER)
        elif msg.dst == self.node_id:
            kind = Input.UNICAST
        elif msg.dst == self.broadcast_id:
            kind = Input.BROADCAST
        else:
            kind = Input.NOT_FOR_ME
        self._step(kind, msg, addr, now, None)

    def get_timer(self) -> float | None:
        """When :meth:`handle_timer` must next be called (the retransmit deadline), or None."""
        u = self._in_flight
        return None if u is None else u.deadline

    def handle_timer(self, now: float) -> None:
        """Retransmit the in-flight unicast, or give it up, if its deadline has come."""
        u = self._in_flight
        if u is None or now < u.deadline:
            return
        kind = Input.RTO_RETRANSMIT if u.copies <= u.retries else Input.RTO_EXHAUSTED
        self._step(kind, None, None, now, u)

    def datagrams_to_send(self, now: float | None = None) -> list[tuple[bytes, Address | None]]:
        """Drain what must go on the wire, in order, as ``(bytes, addr)``.

        ``addr`` is None for our own messages (send them to the configured remote); for an
        ACK it is the source address of the datagram acknowledged, so a transport may
        reply to the source instead of the remote (its ``reply_to_source`` option).
        """
        out, self._outgoing = self._outgoing, []
        return out

    def next_event(self) -> Event | None:
        """The oldest pending event, or None."""
        return self._events.popleft() if self._events else None

    def events(self) -> list[Event]:
        """Drain every pending event, oldest first."""
        out = list(self._events)
        self._events.clear()
        return out

    # ------------------------------------------------------------------ machinery
    @staticmethod
    def _check_timeout(timeout: float) -> float:
        if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not timeout > 0:
            raise LocalProtocolError(f"timeout must be a positive number of seconds, got {timeout!r}")
        return float(timeout)

    @staticmethod
    def _check_retries(retries: int) -> int:
        if isinstance(retries, bool) or not isinstance(retries, int) or retries < 0:
            raise LocalProtocolError(f"retries must be an integer >= 0, got {retries!r}")
        return retries

    def _take_seq(self) -> int:
        seq = self._seq
        self._seq = (seq + 1) & 0xFFFF  # MCP-SEQ-1/3: modulo 65536
        return seq

    def _step(self, kind: Input, msg: Message | None, addr: Address, now: float, arg: Any) -> None:
        entry = self._row.get(kind)
        if entry is None:
            self._events.append(Unexpected(
                msg, addr, FALLBACK_RULE,
                f"input {kind.value} is not allowed in state {self._state.value}; ignored"))
            return
        handler, next_state, row = entry
        handler(msg, addr, now, arg)
        self._state, self._row = next_state, row
        if next_state is _IDLE and self._queue:
            self._step(Input.DEQUEUE, None, None, now, None)

    # ------------------------------------------------------------------ handlers (table)
    def _on_ack_and_deliver(self, msg: Message, addr: Address, now: float, arg: Any) -> None:
        """MCP-ACK-1: ACK every copy; then deliver unless a duplicate (MCP-DUP-1)."""
        seq = self._take_seq()
        data = PREAMBLE + _ACK_HEAD.pack(msg.src, self.node_id, seq, _ACK, msg.seq)
        self._outgoing.append((data, addr))
        self._events.append(AckSent(msg.seq, msg.src, seq, addr))
        self._deliver(msg, addr)

    def _on_deliver_broadcast(self, msg: Message, addr: Address, now: float, arg: Any) -> None:
        """MCP-ACK-4: "A node does not ACK a broadcast message"; delivered once (DUP-1)."""
        self._deliver(msg, addr)

    def _deliver(self, msg: Message, addr: Address) -> None:
        """Deliver ``msg`` unless it is a copy of one recently delivered from its src.

        MCP-DUP-1: the seq last delivered from that src is a duplicate. MCP-DUP-4 leaves a
        late copy of an older seq open; we also discard a copy of any of the last
        ``dup_window`` seqs delivered from that src unless it lies *ahead of the highest*
        seq delivered from it (serial arithmetic): a delayed retransmission overtaken by a
        newer message, or a copy interleaved with broadcasts (same seq space).

        The reference is the highest seq, not the last delivered one: on a reordering link
        the last delivered may be a *late* message (3 after 4), and a copy of 4 arriving
        next is "ahead of the last" yet already delivered. A seq ahead of the highest is
        always new, so 0 after 65535 is new (MCP-SEQ-3), and so is any seq never delivered
        (DUP-2, per src: DUP-3). When the highest moves, remembered seqs half the space or
        more behind it are forgotten, so an old 0 can never shadow the 0 after 65535. (Looking
        for them is a scan of the window; ``_far`` bounds how far behind the remembered seqs
        lie, so the scan runs only when the bound reaches half the space: once in ~32,000
        messages of a sequential peer, instead of each time the highest moves.)
        """
        src, seq = msg.src, msg.seq
        recent = self._recent.get(src)
        if recent is None:
            recent = self._recent[src] = deque(maxlen=self.dup_window)
        highest = self._highest.get(src)
        if recent:
            if seq == recent[-1]:
                self._events.append(DuplicateDiscarded(msg, addr))
                return
            assert highest is not None
            if ((highest - seq) & 0xFFFF) < _SERIAL_HALF and seq in recent:
                self._events.append(DuplicateDiscarded(msg, addr, "MCP-DUP-4"))
                return
        if highest is None:
            self._highest[src] = seq
            far = 0
        elif 0 < (ahead := (seq - highest) & 0xFFFF) < _SERIAL_HALF:
            self._highest[src] = seq
            # every remembered seq is now ``ahead`` further behind; none can be half the space
            # behind unless the bound says so (then it is checked, and made exact again)
            far = self._far[src] + ahead
            if far >= _SERIAL_HALF:
                if any(((seq - s) & 0xFFFF) >= _SERIAL_HALF for s in recent):
                    kept = [s for s in recent if ((seq - s) & 0xFFFF) < _SERIAL_HALF]
                    recent.clear()
                    recent.extend(kept)
                far = max([(seq - s) & 0xFFFF for s in recent], default=0)
        else:  # a late seq, remembered behind the highest
            far = max(self._far[src], (highest - seq) & 0xFFFF)
        self._far[src] = far
        recent.append(seq)
        self._events.append(MessageDelivered(msg, addr))

    def _on_ignore_other_id(self, msg: Message, addr: Address, now: float, arg: Any) -> None:
        self._events.append(Unexpected(
            msg, addr, "MCP-ACK-5",
            f"addressed to ID {msg.dst}, not ours ({self.node_id}): neither ACKed nor acted on"))

    def _on_ignore_own_echo(self, msg: Message, addr: Address, now: float, arg: Any) -> None:
        self._events.append(Unexpected(
            msg, addr, "MCP-HDR-4", f"src is our own ID {self.node_id} (our broadcast looped back?); ignored"))

    def _on_ignore_broadcast_src(self, msg: Message, addr: Address, now: float, arg: Any) -> None:
        # its ACK would go to the broadcast ID, which MCP-ACK-3 ("an ACK's dst is the src of
        # the acknowledged message") cannot mean: no node has that ID (D-1, MCP-HDR-4)
        self._events.append(Unexpected(
            msg, addr, "MCP-ACK-3", f"src is the broadcast ID {self.broadcast_id}: an ACK would be a "
                                    "broadcast; neither ACKed nor acted on"))

    def _on_drop_malformed(self, msg: None, addr: Address, now: float, arg: Any) -> None:
        data, (rule, reason) = arg
        self._events.append(Malformed(bytes(data), addr, rule, reason))

    def _on_confirm(self, msg: Message, addr: Address, now: float, arg: Any) -> None:
        u = self._in_flight
        assert u is not None
        self._in_flight = None
        self._events.append(AckReceived(u.seq, msg.src, u.handle, addr))
        self._events.append(DeliveryConfirmed(u.handle, u.seq, u.dst, u.copies))

    def _on_stray_ack(self, msg: Message, addr: Address, now: float, arg: Any) -> None:
        """MCP-RTX-2 / MCP-ACK-6: an ACK that acknowledges nothing of ours is ignored."""
        u = self._in_flight
        if u is None:
            why = "no unicast of ours is in flight"
        elif msg.src != u.dst:
            why = f"in-flight seq {u.seq} went to ID {u.dst}, not {msg.src}"
        else:
            why = f"in-flight seq is {u.seq}"
        self._events.append(Unexpected(msg, addr, "MCP-RTX-2", f"ACK of seq {msg.payload} from {msg.src}: {why}"))

    def _on_transmit(self, msg: None, addr: None, now: float, u: _Unicast) -> None:
        """First copy of a unicast: it takes its sequence number now (MCP-SEQ-1)."""
        u.seq = self._take_seq()
        u.data = PREAMBLE + _HEAD.pack(u.dst, self.node_id, u.seq, u.action) + u.payload
        u.copies = 1
        u.deadline = now + u.timeout
        self._in_flight = u
        self._outgoing.append((u.data, None))

    def _on_enqueue(self, msg: None, addr: None, now: float, u: _Unicast) -> None:
        """MCP-BLK-1: another unicast is in flight; this one waits its turn."""
        self._queue.append(u)

    def _on_transmit_next(self, msg: None, addr: None, now: float, arg: None) -> None:
        self._on_transmit(None, None, now, self._queue.popleft())

    def _on_broadcast(self, msg: None, addr: None, now: float, u: _Unicast) -> None:
        """MCP-RTX-4: "Broadcast messages are sent once and not retransmitted"."""
        seq = self._take_seq()
        self._outgoing.append((PREAMBLE + _HEAD.pack(u.dst, self.node_id, seq, u.action) + u.payload, None))

    def _on_retransmit(self, msg: None, addr: None, now: float, u: _Unicast) -> None:
        """MCP-SEQ-2: the same sequence number and the same bytes, every ``timeout``."""
        u.copies += 1
        u.deadline = now + u.timeout
        self._outgoing.append((u.data, None))
        self._events.append(Retransmitted(u.handle, u.seq, u.dst, u.copies))

    def _on_fail(self, msg: None, addr: None, now: float, u: _Unicast) -> None:
        """MCP-RTX-1: the retry limit is reached; the message is given up."""
        self._in_flight = None
        self._events.append(DeliveryFailed(
            u.handle, u.seq, u.dst, u.copies,
            f"no ACK from ID {u.dst} for seq {u.seq} after {u.copies} copies "
            f"{u.timeout:g} s apart ({u.retries} retries)"))

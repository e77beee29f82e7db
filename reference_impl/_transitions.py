"""The endpoint's transition table: every allowed (state, input kind) pair, as data.

In the manner of h11's ``_state.py`` the whole behaviour of the endpoint's sender state
machine is this one dict. :class:`~reference_impl.endpoint.Endpoint` classifies each input
(a datagram, an expired retransmit timer, a call of ``send``) into an :class:`Input` kind,
looks up ``(state, kind)`` here and runs the named handler, then moves to the next state.

A pair missing from :data:`TRANSITIONS` is *not* an exception (MCP-ROB-5: "After any
malformed or unexpected input the node stays live"): the endpoint survives it and emits an
``Unexpected`` event naming :data:`FALLBACK_RULE`.

The states are those of stop-and-wait (MCP-BLK-1: "a node sends no new unicast message
other than an ACK while one of its unicast messages awaits its ACK"): ``IDLE`` with no
unicast in flight, ``AWAITING_ACK`` with exactly one. Receiving is the same in both
states: every well-formed unicast copy to our ID is ACKed (MCP-ACK-1) whatever we are
waiting for.
"""

from __future__ import annotations

from enum import Enum
from typing import NamedTuple

__all__ = ["FALLBACK_RULE", "Input", "State", "TRANSITIONS", "Transition", "lookup"]


class State(Enum):
    """Sender state of one endpoint (MCP-BLK-1 stop-and-wait)."""

    # members compare by identity (Enum has no __eq__), so they may hash by it too: the
    # endpoint looks one up per datagram, and Enum.__hash__ (hash of the name) is Python code
    __hash__ = object.__hash__

    IDLE = "idle"                  # no unicast of ours awaits an ACK
    AWAITING_ACK = "awaiting_ack"  # one unicast in flight; others wait in the queue


class Input(Enum):
    """What happened, as the endpoint classifies it before looking up the table."""

    __hash__ = object.__hash__  # as State's

    UNICAST = "unicast"                  # well-formed, dst = our ID, not an ACK
    BROADCAST = "broadcast"              # well-formed, dst = broadcast ID, not an ACK
    ACK_MATCHING = "ack_matching"        # ACK to us, from the in-flight dst, payload = its seq
    ACK_OTHER = "ack_other"              # any other ACK to our ID (MCP-RTX-2: does not count)
    NOT_FOR_ME = "not_for_me"            # dst is another ID (MCP-ACK-5)
    FROM_SELF = "from_self"              # src is our own ID: our broadcast looped back
    FROM_BROADCAST_ID = "from_broadcast_id"  # src is the broadcast ID: no node has it (MCP-ACK-3)
    MALFORMED = "malformed"              # the codec raised DecodeError (MCP-ROB-1..4, PAY-6)
    RTO_RETRANSMIT = "rto_retransmit"    # retransmit timer expired, retries left (MCP-RTX-1)
    RTO_EXHAUSTED = "rto_exhausted"      # retransmit timer expired, retry limit reached
    SEND_UNICAST = "send_unicast"        # the application asked to send a unicast
    SEND_BROADCAST = "send_broadcast"    # the application asked to send a broadcast
    DEQUEUE = "dequeue"                  # internal: idle again and a unicast is queued


class Transition(NamedTuple):
    """The endpoint method to run (``_on_<handler>``) and the state to move to."""

    handler: str
    next_state: State


_I, _A = State.IDLE, State.AWAITING_ACK

#: Every allowed (state, input) pair. Anything missing is survived and reported.
TRANSITIONS: dict[tuple[State, Input], Transition] = {
    # receiving: identical in both states (MCP-ACK-1, DUP-1..3, ACK-4/5/6, ROB-1..4)
    (_I, Input.UNICAST): Transition("ack_and_deliver", _I),
    (_A, Input.UNICAST): Transition("ack_and_deliver", _A),
    (_I, Input.BROADCAST): Transition("deliver_broadcast", _I),
    (_A, Input.BROADCAST): Transition("deliver_broadcast", _A),
    (_I, Input.NOT_FOR_ME): Transition("ignore_other_id", _I),
    (_A, Input.NOT_FOR_ME): Transition("ignore_other_id", _A),
    (_I, Input.FROM_SELF): Transition("ignore_own_echo", _I),
    (_A, Input.FROM_SELF): Transition("ignore_own_echo", _A),
    (_I, Input.FROM_BROADCAST_ID): Transition("ignore_broadcast_src", _I),
    (_A, Input.FROM_BROADCAST_ID): Transition("ignore_broadcast_src", _A),
    (_I, Input.MALFORMED): Transition("drop_malformed", _I),
    (_A, Input.MALFORMED): Transition("drop_malformed", _A),
    # ACKs: only the matching one ends the wait (MCP-RTX-2); others are reported
    (_A, Input.ACK_MATCHING): Transition("confirm", _I),
    (_I, Input.ACK_OTHER): Transition("stray_ack", _I),
    (_A, Input.ACK_OTHER): Transition("stray_ack", _A),
    # retransmission (MCP-RTX-1, SEQ-2)
    (_A, Input.RTO_RETRANSMIT): Transition("retransmit", _A),
    (_A, Input.RTO_EXHAUSTED): Transition("fail", _I),
    # sending (MCP-BLK-1 stop-and-wait, MCP-RTX-4 broadcasts once)
    (_I, Input.SEND_UNICAST): Transition("transmit", _A),
    (_A, Input.SEND_UNICAST): Transition("enqueue", _A),
    (_I, Input.SEND_BROADCAST): Transition("broadcast", _I),
    (_A, Input.SEND_BROADCAST): Transition("broadcast", _A),
    (_I, Input.DEQUEUE): Transition("transmit_next", _A),
}

#: The rule an input missing from the table is reported under.
FALLBACK_RULE = "MCP-ROB-5"


def lookup(state: State, kind: Input) -> Transition | None:
    """The transition for ``(state, kind)``, or None when the table does not allow it."""
    return TRANSITIONS.get((state, kind))

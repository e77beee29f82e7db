"""Fault models: the reference endpoint with one behaviour changed each, after the sample
node's and sample manager's ``--fault`` list (``tests/conformance/nodes/sample_node.py``,
``sample_manager.py``), each with the rule it breaks (docs/spec.md) and a record of every time
it did something the correct endpoint would not have done (:attr:`FaultMixin.deviations`),
which is what the search asks the judges to find.

Each fault is a subclass of :class:`~reference_impl.endpoint.Endpoint` overriding one handler of
its transition table (``reference_impl._transitions``):

- ``no-ack`` (drone) / ``no-ready-ack`` (manager), MCP-ACK-1 "a node ACKs every well-formed
  unicast message addressed to its own ID other than an ACK -- every copy";
- ``ack-first-copy-only`` (drone), MCP-ACK-1: a duplicate copy is not ACKed;
- ``ack-previous-seq`` (drone), MCP-ACK-2 "An ACK's payload is exactly 2 bytes: the
  acknowledged message's sequence number": it names the number ACKed before (0 at first);
- ``ack-copies-wrong-seq`` (drone), MCP-ACK-2: a duplicate copy is ACKed with its seq plus 1;
- ``rtx-none`` (drone) / ``manager-rtx-none``, MCP-RTX-1 "The sender of a unicast message
  retransmits it until it is ACKed or its retry limit is reached": each unicast is sent once
  (the issue's capture: a manager's End_Mission never ACKed and never sent again);
- ``wrong-seq-ack`` (manager) / ``rtx-stop-on-any-ack`` (drone), MCP-RTX-2 "Only an ACK from
  the message's destination whose payload equals the message's sequence number ends its
  retransmission": any ACK from the destination (any ACK at all) ends it;
- ``give-up-after-two`` (manager), MCP-RTX-1: each unicast is sent twice at most (the rule is
  observed as "at least 3 copies while the ACK is withheld");
- ``give-up-never`` (manager): retries without limit -- the rule's "retry limit" is
  configurable, so this breaks no rule: a control that must get no MUST verdict;
- ``ack-twice`` (drone): ACKs each duplicate copy twice, and the message before each new one
  (from the same sender) once more -- every copy ACKed, nothing forbids answering one more
  than once (D-9), so it breaks no rule: a control for a judge that counts ACKs;
- ``no-dup-discard`` (drone), MCP-DUP-1 "ACKed again ... but not delivered to the application
  again": duplicates are delivered (not on the wire: docs/spec.md observes it on the vehicle
  link, which the simulator models since the vehicle runs on its clock: sim.vehicle).
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass
from typing import Any

from mcp_conform.reference_impl._transitions import Input
from mcp_conform.reference_impl.endpoint import _ACK_HEAD, Endpoint
from mcp_conform.reference_impl.events import AckSent, DuplicateDiscarded, MessageDelivered
from mcp_conform.spec.codec import PREAMBLE, Action, DecodeError, decode, peek_header

__all__ = ["FAULTS", "Fault", "FaultMixin", "fault_endpoint"]

#: retries of the never-giving-up sender (MCP-RTX-1's limit is configurable)
NEVER = 10**9


class FaultMixin(Endpoint):
    """Records ``(now, what)`` each time the fault changed what the endpoint did."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.deviations: list[tuple[float, str]] = []
        self.now = 0.0

    def receive_datagram(self, data: bytes, addr: Any, now: float) -> None:
        self.now = now
        super().receive_datagram(data, addr, now)

    def _ack(self, msg: Any, addr: Any, named: int) -> None:
        seq = self._take_seq()
        self._outgoing.append((PREAMBLE + _ACK_HEAD.pack(msg.src, self.node_id, seq, int(Action.ACK), named),
                               addr))
        self._events.append(AckSent(msg.seq, msg.src, seq, addr))

    def _is_dup(self, msg: Any) -> bool:
        """Whether the correct endpoint would discard ``msg`` as a duplicate (MCP-DUP-1)."""
        recent = self._recent.get(msg.src)
        if not recent:
            return False
        if msg.seq == recent[-1]:
            return True
        highest = self._highest.get(msg.src)
        return highest is not None and ((highest - msg.seq) & 0xFFFF) < 0x8000 and msg.seq in recent


class NoAck(FaultMixin):
    def _on_ack_and_deliver(self, msg: Any, addr: Any, now: float, arg: Any) -> None:
        self.deviations.append((now, f"no ACK of seq {msg.seq}"))
        self._deliver(msg, addr)


class NoReadyAck(FaultMixin):
    def _on_ack_and_deliver(self, msg: Any, addr: Any, now: float, arg: Any) -> None:
        if msg.action == Action.MISSION_READY:
            self.deviations.append((now, f"no ACK of Mission_Ready seq {msg.seq} from {msg.src}"))
            self._deliver(msg, addr)
            return
        super()._on_ack_and_deliver(msg, addr, now, arg)


class AckFirstCopyOnly(FaultMixin):
    def _on_ack_and_deliver(self, msg: Any, addr: Any, now: float, arg: Any) -> None:
        if self._is_dup(msg):
            self.deviations.append((now, f"duplicate seq {msg.seq} {Action(msg.action).name} not ACKed"))
            self._deliver(msg, addr)
            return
        super()._on_ack_and_deliver(msg, addr, now, arg)


class AckPreviousSeq(FaultMixin):
    _prev = 0

    def _on_ack_and_deliver(self, msg: Any, addr: Any, now: float, arg: Any) -> None:
        named, self._prev = self._prev, msg.seq
        if named != msg.seq:
            self.deviations.append((now, f"ACK of seq {msg.seq} names {named}"))
        self._ack(msg, addr, named)
        self._deliver(msg, addr)


class AckCopiesWrongSeq(FaultMixin):
    def _on_ack_and_deliver(self, msg: Any, addr: Any, now: float, arg: Any) -> None:
        if not self._is_dup(msg):
            super()._on_ack_and_deliver(msg, addr, now, arg)
            return
        named = (msg.seq + 1) & 0xFFFF
        self.deviations.append((now, f"ACK of copy of seq {msg.seq} names {named}"))
        self._ack(msg, addr, named)
        self._deliver(msg, addr)


class AckTwice(FaultMixin):
    """Correct (D-9): every copy ACKed; some answered twice, some again later."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._last: dict[int, int] = {}  # sender -> the number of its last message read

    def _on_ack_and_deliver(self, msg: Any, addr: Any, now: float, arg: Any) -> None:
        dup = self._is_dup(msg)
        prev = self._last.get(msg.src)
        super()._on_ack_and_deliver(msg, addr, now, arg)
        if dup:
            self.deviations.append((now, f"copy of seq {msg.seq} ACKed twice"))
            self._ack(msg, addr, msg.seq)
        elif prev is not None and prev != msg.seq:
            self.deviations.append((now, f"seq {prev} ACKed again on reading seq {msg.seq}"))
            self._ack(msg, addr, prev)
        self._last[msg.src] = msg.seq


class RtxNone(FaultMixin):
    def _on_retransmit(self, msg: Any, addr: Any, now: float, u: Any) -> None:
        self.deviations.append((now, f"seq {u.seq} not retransmitted"))
        u.deadline = math.inf  # in flight for ever: no copy, no give-up


class _TakesWrongAcks(FaultMixin):
    any_src = False

    def receive_datagram(self, data: bytes, addr: Any, now: float) -> None:
        self.now = now
        u = self._in_flight
        head = peek_header(data) if u is not None else None
        if u is not None and head is not None and head[3] == Action.ACK:
            try:
                msg = decode(data)
            except DecodeError:
                msg = None
            if (msg is not None and msg.dst == self.node_id and msg.action == Action.ACK
                    and (self.any_src or msg.src == u.dst) and not (msg.src == u.dst and msg.payload == u.seq)):
                self.deviations.append((now, f"seq {u.seq} ended by an ACK of {msg.payload} from {msg.src}"))
                self._step(Input.ACK_MATCHING, msg, addr, now, None)
                return
        Endpoint.receive_datagram(self, data, addr, now)


class WrongSeqAck(_TakesWrongAcks):
    pass


class RtxStopOnAnyAck(_TakesWrongAcks):
    any_src = True


class GiveUpAfterTwo(FaultMixin):
    def _on_fail(self, msg: Any, addr: Any, now: float, u: Any) -> None:
        self.deviations.append((now, f"seq {u.seq} given up after {u.copies} copies"))
        super()._on_fail(msg, addr, now, u)


class NoDupDiscard(FaultMixin):
    def _deliver(self, msg: Any, addr: Any) -> None:
        before = len(self._events)
        super()._deliver(msg, addr)
        if len(self._events) > before and isinstance(self._events[-1], DuplicateDiscarded):
            self._events.pop()
            self._events.append(MessageDelivered(msg, addr))
            self.deviations.append((self.now, f"duplicate seq {msg.seq} delivered again"))


@dataclass(frozen=True)
class Fault:
    """A fault model: its role, the rule it breaks (None: none), its endpoint class, and the
    retry limit it uses (None: the model's)."""

    name: str
    role: str
    rule: str | None
    cls: type[FaultMixin]
    retries: int | None = None
    what: str = ""


FAULTS: dict[str, Fault] = {f.name: f for f in (
    Fault("no-ack", "drone", "MCP-ACK-1", NoAck, what="never ACKs"),
    Fault("ack-first-copy-only", "drone", "MCP-ACK-1", AckFirstCopyOnly,
          what="a duplicate copy is neither delivered nor ACKed"),
    Fault("ack-previous-seq", "drone", "MCP-ACK-2", AckPreviousSeq,
          what="ACK payload is the seq of the message it ACKed before (0 at first)"),
    Fault("ack-copies-wrong-seq", "drone", "MCP-ACK-2", AckCopiesWrongSeq,
          what="a retransmitted copy is ACKed with the seq plus 1"),
    Fault("rtx-none", "drone", "MCP-RTX-1", RtxNone, what="Mission_Ready is sent once"),
    Fault("rtx-stop-on-any-ack", "drone", "MCP-RTX-2", RtxStopOnAnyAck,
          what="any ACK addressed to it stops the retransmission"),
    Fault("no-dup-discard", "drone", "MCP-DUP-1", NoDupDiscard, what="duplicates are delivered again"),
    Fault("manager-rtx-none", "manager", "MCP-RTX-1", RtxNone,
          what="each command is sent once, never retransmitted (nor given up)"),
    Fault("no-ready-ack", "manager", "MCP-ACK-1", NoReadyAck, what="never ACKs a Mission_Ready"),
    Fault("wrong-seq-ack", "manager", "MCP-RTX-2", WrongSeqAck,
          what="any ACK from the destination ends the retransmission, whatever its seq"),
    Fault("give-up-after-two", "manager", "MCP-RTX-1", GiveUpAfterTwo, retries=1,
          what="sends each unicast twice at most, then drops the drone"),
    Fault("give-up-never", "manager", None, GiveUpAfterTwo, retries=NEVER,
          what="retransmits without limit (a configurable retry limit: no rule broken)"),
    Fault("ack-twice", "drone", None, AckTwice,
          what="ACKs duplicates twice and the message before each new one again (D-9: no rule broken)"),
)}


def fault_endpoint(fault: Fault, retries: int) -> Any:
    """The endpoint factory of the models (:data:`sim.models.EndpointFactory`) for ``fault``."""
    limit = fault.retries if fault.retries is not None else retries

    def make(node_id: int, rto: float, _retries: int, rng: random.Random) -> Endpoint:
        return fault.cls(node_id, timeout=rto, retries=limit, rng=rng)

    return make

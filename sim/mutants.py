"""The sample node's mutants as drone models (issue 38, item 4): the ``--fault`` list of
``tests/conformance/nodes/sample_node.py`` that ``tests/conformance/test_mutants.py`` runs the
runner against, each one fault breaking one rule, for the runner's cases in the simulator
(:mod:`sim.runner`).

A mutant is the reference drone model (:class:`sim.models.DroneModel`) with its wire changed as
the sample node's fault changes it -- what it sends rewritten (:meth:`MutantDrone.drain`: a
preamble, a header's byte order, an ACK's payload or destination, Mission_Ready's source,
destination or payload, an ACK held back 300 ms, a retransmission under a new seq), what it
reads filtered or answered beyond the rule (:meth:`MutantDrone.receive`: a datagram from another
source port dropped, an ACK of a broadcast, of another ID's message, of an ACK, of a malformed
datagram; an exit on a short or a huge datagram; deafness after a flood), or its timer changed
(``rtx-storm``). The faults the sim already models on the endpoint (:mod:`sim.faults`) are
taken from there. The mutants observed on the vehicle's link (DUP, BLK-4/5/7, PAY-8, SEQ-3) are
not here: the simulator has no vehicle model yet (:data:`NEEDS_VEHICLE`).
"""

from __future__ import annotations

import random
import struct
from collections.abc import Callable
from typing import Any

from mcp_conform.sim.faults import FAULTS, fault_endpoint
from mcp_conform.sim.models import DroneModel
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import (
    BROADCAST_ID,
    HEADER_SIZE,
    MANAGER_ID,
    PREAMBLE,
    Action,
    DecodeError,
    decode,
    peek_header,
)

__all__ = ["MUTANTS", "NEEDS_VEHICLE", "MutantDrone", "mutant_factory"]

_ACK = int(Action.ACK)
_READY = int(Action.MISSION_READY)
BAD_PREAMBLE = PREAMBLE[:-1] + b"\x02"
SLOW_ACK_DELAY = 0.3
STORM_INTERVAL = 0.01
FLOOD_HANG_AFTER = 5000
FLOOD_HANG_FOR = 30.0
CRASH_BIG_ABOVE = 8192
_HDR = struct.Struct("!4H")
_HDR_LE = struct.Struct("<4H")

#: mutant -> the rule it breaks (test_mutants' MUTANTS, the ones without a vehicle)
MUTANTS: dict[str, str] = {
    "bad-preamble": "MCP-HDR-1", "header-little-endian": "MCP-HDR-2", "send-action-9": "MCP-HDR-3",
    "mission-ready-wrong-src": "MCP-HDR-4", "send-wp-list": "MCP-HDR-5",
    "ack-first-copy-only": "MCP-ACK-1", "ack-copies-wrong-seq": "MCP-ACK-2", "ack-little-endian": "MCP-ACK-2",
    "ack-own-seq": "MCP-ACK-2", "ack-previous-seq": "MCP-ACK-2", "ack-zero": "MCP-ACK-2",
    "ack-wrong-dst": "MCP-ACK-3", "ack-broadcast": "MCP-ACK-4", "ack-other-id": "MCP-ACK-5",
    "ack-ack": "MCP-ACK-6", "slow-ack": "MCP-ACK-7", "rtx-new-seq": "MCP-SEQ-2", "rtx-none": "MCP-RTX-1",
    "rtx-stop-on-any-ack": "MCP-RTX-2", "rtx-storm": "MCP-RTX-3", "ready-bad-payload": "MCP-PAY-2",
    "crash-on-short": "MCP-ROB-1", "ack-bad-preamble": "MCP-ROB-2", "ack-unknown-action": "MCP-ROB-3",
    "ack-bad-length": "MCP-ROB-4", "crash-on-big": "MCP-ROB-6", "flood-hang": "MCP-ROB-7",
    "ready-to-wrong-id": "MCP-FLOW-1", "source-port-filter": "MCP-TRN-2",
}
#: test_mutants' mutants observed on the vehicle's link: not simulated yet
NEEDS_VEHICLE = ("seq-no-wrap", "no-dup-discard", "dup-by-content", "dup-ignores-src", "arm-early",
                 "arm-before-fix", "arm-before-start", "ready-without-fix", "no-rtl", "passthrough-twice",
                 "passthrough-truncated", "passthrough-corrupt")


class MutantDrone(DroneModel):
    """The reference drone with one of the sample node's faults on its wire (module docstring)."""

    def __init__(self, fault: str, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.fault = fault
        self.send_to: Any = None  # the runner's address (the transport sets it: source-port-filter)
        self._extra: list[tuple[bytes, Any, float]] = []
        self._malformed = 0
        self._deaf_until = -1.0
        self._acked_before = False
        self._ready_seq: int | None = None
        self._new_seqs: set[int] = set()
        self.exit_code: int | None = None

    # ------------------------------------------------------------------ reading
    def receive(self, data: bytes, addr: Any, now: float) -> None:
        f, n = self.fault, len(data)
        if f == "source-port-filter" and self.send_to is not None and tuple(addr[:2]) != tuple(self.send_to):
            return
        if (f == "crash-on-short" and n < HEADER_SIZE) or (f == "crash-on-big" and n > CRASH_BIG_ABOVE):
            self.exit_code = 3 if f == "crash-on-short" else 4
            self.close(now, f"exit:{self.exit_code}")
            return
        if now < self._deaf_until:
            return
        try:
            msg = decode(data)
        except DecodeError as exc:
            self._malformed_in(data, addr, now, exc)
            super().receive(data, addr, now)
            return
        if msg.action == _ACK:
            if f == "ack-ack" and msg.dst == self.node_id:
                self._ack(msg.src, msg.seq, addr)
            if f == "mission-ready-wrong-src" and msg.dst == self.node_id + 1:
                data = PREAMBLE + _HDR.pack(self.node_id, msg.src, msg.seq, _ACK) + data[HEADER_SIZE:]
            if f == "rtx-new-seq" and self._ready_seq is not None and msg.payload in self._new_seqs:
                data = data[:HEADER_SIZE] + struct.pack("!H", self._ready_seq)
        elif msg.dst == BROADCAST_ID and f == "ack-broadcast":
            self._ack(msg.src, msg.seq, addr)
        elif msg.dst not in (self.node_id, BROADCAST_ID) and f == "ack-other-id":
            self._ack(msg.src, msg.seq, addr)
        started = self.started
        super().receive(data, addr, now)
        if self.started and not started:
            self._started(now)

    def _malformed_in(self, data: bytes, addr: Any, now: float, exc: DecodeError) -> None:
        self._malformed += 1
        f = self.fault
        if f == "flood-hang" and self._malformed == FLOOD_HANG_AFTER:
            self._deaf_until = now + FLOOD_HANG_FOR
        header = None
        if exc.rule == "MCP-ROB-2" and f == "ack-bad-preamble":
            try:
                fixed = decode(PREAMBLE + bytes(data[len(PREAMBLE):]))
                header = (fixed.dst, fixed.src, fixed.seq, int(fixed.action))
            except DecodeError:
                header = None
        elif (exc.rule == "MCP-ROB-3" and f == "ack-unknown-action") or (exc.rule == "MCP-ROB-4" and f == "ack-bad-length"):
            header = peek_header(data)
        if header is not None and header[0] == self.node_id and header[3] != _ACK:
            self._ack(header[1], header[2], addr)

    def _started(self, now: float) -> None:
        """Start_Mission delivered: the faults that speak then (after the reference's ACK)."""
        if self.fault == "send-action-9":
            self._extra.append((PREAMBLE + _HDR.pack(MANAGER_ID, self.node_id, self.ep._take_seq(), 9), None, 0.0))
        elif self.fault == "send-wp-list":
            self.ep.send(Action.WP_LIST, (), MANAGER_ID, now=now)

    def _ack(self, dst: int, seq: int, addr: Any) -> None:
        """An ACK the correct drone would not send (its own seq taken, as every ACK takes one)."""
        self._extra.append((PREAMBLE + _HDR.pack(dst, self.node_id, self.ep._take_seq(), _ACK)
                            + struct.pack("!H", seq), None, 0.0))

    # ------------------------------------------------------------------ sending
    def drain(self, now: float) -> list[tuple[bytes, Any, float]]:
        """What goes on the wire now: ``(bytes, addr or None, delay s)``, the fault applied."""
        out = [(d, a, 0.0) for d, a in self.ep.datagrams_to_send(now)]
        out, self._extra = [*self._extra, *out], []
        return [self._rewrite(d, a, delay) for d, a, delay in out]

    def _rewrite(self, data: bytes, addr: Any, delay: float) -> tuple[bytes, Any, float]:
        f = self.fault
        head = peek_header(data)
        if head is None:
            return data, addr, delay
        dst, src, seq, action = head
        payload = data[HEADER_SIZE:]
        if action == _ACK and len(payload) == 2:
            named = struct.unpack("!H", payload)[0]
            if f == "ack-zero":
                named = 0
            elif f == "ack-own-seq":
                named = seq
            payload = struct.pack("<H" if f == "ack-little-endian" else "!H", named)
            if f == "ack-wrong-dst":
                dst = 0x0FFF
            if f == "slow-ack":
                delay = SLOW_ACK_DELAY
        elif action == _READY:
            if f == "ready-bad-payload":
                payload = struct.pack("!HH", self.node_id, 0)
            elif f == "mission-ready-wrong-src":
                src = self.node_id + 1
            elif f == "ready-to-wrong-id":
                dst = 5 if self.node_id != 5 else 6
            elif f == "rtx-new-seq":
                if self._ready_seq is None:
                    self._ready_seq = seq
                else:  # a retransmission: a new seq of its own
                    seq = self.ep._take_seq()
                    self._new_seqs.add(seq)
        pre = BAD_PREAMBLE if f == "bad-preamble" else PREAMBLE
        hdr = (_HDR_LE if f == "header-little-endian" else _HDR).pack(dst, src, seq, action)
        return pre + hdr + payload, addr, delay


def mutant_factory(mutant: str, *, rto: float = 0.2, seed: int = 0, ready_after: float = 0.05) -> Callable[[float], DroneModel]:
    """A fresh model of ``mutant`` (:data:`MUTANTS`) for each spawn (``sim.runner``'s factory)."""
    if mutant not in MUTANTS:
        why = "observed on the vehicle link (not simulated yet)" if mutant in NEEDS_VEHICLE else "unknown"
        raise ValueError(f"mutant {mutant!r}: {why}")
    retries = int(SPEC.params["retries"])
    endpoint = fault_endpoint(FAULTS[mutant], retries) if mutant in FAULTS else None
    node_rto = STORM_INTERVAL if mutant == "rtx-storm" else rto
    spawns = random.Random(seed)

    def make(now: float) -> DroneModel:
        return MutantDrone(mutant, 1, node_rto, retries, random.Random(spawns.getrandbits(64)),
                           ready_at=now + ready_after, endpoint=endpoint)

    make.__name__ = mutant
    return make

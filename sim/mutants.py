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
taken from there.

The mutants observed on the vehicle's link (:data:`NEEDS_VEHICLE`: DUP, BLK-4/5/7, PAY-8,
SEQ-3) are caught in a run with the vehicle (``sim.runner.run_cases(..., mavlink=True)``). Their
faults are the sample node's: its duplicate test (``Node.is_duplicate``: ``seq-no-wrap`` takes a
seq at or below the last delivered from that src, as plain integers, for a duplicate;
``dup-by-content`` a message equal in action and payload to that src's last; ``dup-ignores-src``
keeps one last seq for every src; ``no-dup-discard`` delivers every copy, :mod:`sim.faults`), and
what its ``Node.run`` and handlers ask of the autopilot (``arm-before-fix``: an arm request on
connecting; ``arm-early``: after the fix, before Mission_Ready; ``arm-before-start``: once
Mission_Ready is ACKed; ``ready-without-fix``: Mission_Ready without waiting for the fix;
``no-rtl``: no RTL on End_Mission; ``passthrough-twice``, ``-truncated`` (its last 3 bytes cut),
``-corrupt`` (bit 0 of its byte 11, a payload byte, flipped; the CRC unchanged): the frame written
so), on the reference drone's autopilot client (:mod:`sim.autopilot`) without its HEARTBEATs, as the
sample node's link sends none.
"""

from __future__ import annotations

import math
import random
import struct
from collections.abc import Callable
from typing import Any

from mcp_conform.reference_impl.endpoint import Endpoint
from mcp_conform.reference_impl.events import DuplicateDiscarded, MessageDelivered
from mcp_conform.sim.autopilot import AutopilotClient, Flow
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
DUP_WINDOW = 64  # sample_node.DUP_WINDOW
ARM_WAIT = 5.0  # how long sample_node's run waits for its arm job
_HDR = struct.Struct("!4H")
_HDR_LE = struct.Struct("<4H")

#: mutant -> the rule it breaks (test_mutants' MUTANTS)
MUTANTS: dict[str, str] = {
    "bad-preamble": "MCP-HDR-1", "header-little-endian": "MCP-HDR-2", "send-action-9": "MCP-HDR-3",
    "mission-ready-wrong-src": "MCP-HDR-4", "send-wp-list": "MCP-HDR-5",
    "ack-first-copy-only": "MCP-ACK-1", "ack-copies-wrong-seq": "MCP-ACK-2", "ack-little-endian": "MCP-ACK-2",
    "ack-own-seq": "MCP-ACK-2", "ack-previous-seq": "MCP-ACK-2", "ack-zero": "MCP-ACK-2",
    "ack-wrong-dst": "MCP-ACK-3", "ack-to-manager": "MCP-ACK-3", "ack-broadcast": "MCP-ACK-4", "ack-other-id": "MCP-ACK-5",
    "ack-ack": "MCP-ACK-6", "slow-ack": "MCP-ACK-7", "rtx-new-seq": "MCP-SEQ-2", "rtx-none": "MCP-RTX-1",
    "rtx-stop-on-any-ack": "MCP-RTX-2", "rtx-storm": "MCP-RTX-3", "ready-bad-payload": "MCP-PAY-2",
    "crash-on-short": "MCP-ROB-1", "ack-bad-preamble": "MCP-ROB-2", "ack-unknown-action": "MCP-ROB-3",
    "ack-bad-length": "MCP-ROB-4", "crash-on-big": "MCP-ROB-6", "flood-hang": "MCP-ROB-7",
    "ready-to-wrong-id": "MCP-FLOW-1", "source-port-filter": "MCP-TRN-2",
    "seq-no-wrap": "MCP-SEQ-3", "no-dup-discard": "MCP-DUP-1", "dup-by-content": "MCP-DUP-2",
    "dup-ignores-src": "MCP-DUP-3", "arm-early": "MCP-BLK-4", "arm-before-fix": "MCP-BLK-4",
    "arm-before-start": "MCP-BLK-4", "ready-without-fix": "MCP-BLK-5", "no-rtl": "MCP-BLK-7",
    "passthrough-twice": "MCP-PAY-8", "passthrough-truncated": "MCP-PAY-8", "passthrough-corrupt": "MCP-PAY-8",
}
#: test_mutants' mutants observed on the vehicle's link: caught in a run with the vehicle
NEEDS_VEHICLE = ("seq-no-wrap", "no-dup-discard", "dup-by-content", "dup-ignores-src", "arm-early",
                 "arm-before-fix", "arm-before-start", "ready-without-fix", "no-rtl", "passthrough-twice",
                 "passthrough-truncated", "passthrough-corrupt")
_SAMPLE_DUP = ("seq-no-wrap", "dup-by-content", "dup-ignores-src")


class SampleDup(Endpoint):
    """The reference endpoint with the sample node's duplicate test (module docstring) in
    place of its own; the ACK of every copy is the reference's (the sample node's too)."""

    fault = ""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._raw = b""
        self._last: dict[Any, int] = {}
        self._seen: dict[Any, list[int]] = {}
        self._content: dict[int, tuple[int, bytes]] = {}

    def receive_datagram(self, data: bytes, addr: Any, now: float) -> None:
        self._raw = bytes(data)
        super().receive_datagram(data, addr, now)

    def _deliver(self, msg: Any, addr: Any) -> None:
        f = self.fault
        key = "all" if f == "dup-ignores-src" else msg.src
        content = (int(msg.action), self._raw[HEADER_SIZE:])
        last = self._last.get(key)
        dup = last is not None and (msg.seq <= last if f == "seq-no-wrap" else msg.seq == last)
        if not dup and f != "seq-no-wrap" and msg.seq in self._seen.get(key, ()):
            dup = True
        if not dup and f == "dup-by-content":
            dup = self._content.get(msg.src) == content
        if dup:
            self._events.append(DuplicateDiscarded(msg, addr))
            return
        self._last[key] = msg.seq
        self._seen[key] = [*self._seen.get(key, ()), msg.seq][-DUP_WINDOW:]
        self._content[msg.src] = content
        self._events.append(MessageDelivered(msg, addr))


def _sample_dup(fault: str) -> Callable[[int, float, int, random.Random], Endpoint]:
    cls = type(f"SampleDup[{fault}]", (SampleDup,), {"fault": fault})

    def make(node_id: int, rto: float, retries: int, rng: random.Random) -> Endpoint:
        return cls(node_id, timeout=rto, retries=retries, rng=rng)

    return make


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

    # ------------------------------------------------------------------ the autopilot
    def make_autopilot(self, addr: tuple[str, int]) -> AutopilotClient:
        """The sample node's link: no HEARTBEAT of its own (``sample_node.Autopilot`` writes
        only its jobs' frames), so over TCP an altered frame is followed by nothing for a while,
        and a UDP vehicle that waits to hear from it never does (test_mutants runs it over TCP)."""
        return AutopilotClient(addr, heartbeat_period=None)

    def main(self) -> Flow:
        """``sample_node.Node.run``'s order where its fault changes it (else the reference's)."""
        f, ap = self.fault, self.autopilot
        if f not in ("arm-before-fix", "arm-early", "arm-before-start", "ready-without-fix"):
            return (yield from super().main())
        assert ap is not None
        if f == "arm-before-fix":
            self.submit("arm")
            yield from self._until(ap.idle, ARM_WAIT)
        if f != "ready-without-fix":
            yield from self._until(lambda: ap.fix, math.inf)
        if f == "arm-early":
            self.submit("arm")
            yield from self._until(ap.idle, ARM_WAIT)
        self.send_ready(self.now)
        if f == "arm-before-start":
            yield from self._until(lambda: self.ready_acked, math.inf)
            if not self.started:
                self.submit("arm")
        yield from self._until(lambda: self.ended, math.inf)
        yield from self._until(ap.idle, self.drain_timeout)
        self.close_at = self.now + self.linger

    def forward(self, frame: bytes) -> None:
        f = self.fault
        if f == "passthrough-truncated":
            frame = frame[:-3]
        elif f == "passthrough-corrupt" and len(frame) > 12:
            frame = frame[:11] + bytes([frame[11] ^ 0x01]) + frame[12:]
        for _ in range(2 if f == "passthrough-twice" else 1):
            super().forward(frame)

    def end_mission(self, now: float) -> None:
        if self.fault == "no-rtl" and self.autopilot is not None:
            return  # no RTL; main() still waits for the work queued before, then lingers
        super().end_mission(now)

    def _ack(self, dst: int, seq: int, addr: Any) -> None:
        """An ACK the correct drone would not send (its own seq taken, as every ACK takes one)."""
        self._extra.append((PREAMBLE + _HDR.pack(dst, self.node_id, self.ep._take_seq(), _ACK)
                            + struct.pack("!H", seq), None, 0.0))

    # ------------------------------------------------------------------ sending
    def drain(self, now: float) -> list[tuple[bytes, Any, float]]:
        """What goes on the wire now: ``(bytes, addr or None, delay s)``, the fault applied."""
        sends = self.ep.datagrams_to_send(now)
        if not sends and not self._extra:
            return []  # the common case (a flood's datagram dropped): no lists made
        out = [(d, a, 0.0) for d, a in sends]
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
            elif f == "ack-to-manager":  # sample_node's: right only for the manager's messages
                dst = MANAGER_ID
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
        raise ValueError(f"mutant {mutant!r}: unknown")
    retries = int(SPEC.params["retries"])
    endpoint = fault_endpoint(FAULTS[mutant], retries) if mutant in FAULTS else None
    if mutant in _SAMPLE_DUP:
        endpoint = _sample_dup(mutant)
    node_rto = STORM_INTERVAL if mutant == "rtx-storm" else rto
    spawns = random.Random(seed)

    def make(now: float) -> DroneModel:
        return MutantDrone(mutant, 1, node_rto, retries, random.Random(spawns.getrandbits(64)),
                           ready_at=now + ready_after, endpoint=endpoint)

    make.__name__ = mutant
    return make

"""The trace monitor: the protocol's rules as one incremental judge of MCP traffic.

Sans-I/O and deterministic (no sockets, no clocks): fed every datagram seen on the wire,
optionally the drones' autopilot-link events and the passing of time, it returns
violations as soon as the trace *proves* them. Shared by every consumer: the runner (both
roles), the fuzzer, ``mcp-capture check`` and golden replay.

>>> m = Monitor(rto=5.0, ack_window=2.0)
>>> for t_ns, src, dst, data in trace:                    # doctest: +SKIP
...     for v in m.datagram(t_ns, src, dst, data):
...         print(v.rule, v.node, v.actual)
>>> m.finish(end_ns)                                      # doctest: +SKIP
>>> m.verdicts()[1]["MCP-ACK-1"]                          # doctest: +SKIP
'passed'

Nodes are MCP IDs (the manager is 0), never addresses: the sender of a datagram is the
header's src when the header parses. A malformed datagram (short, bad preamble) is tied
to a node only through its source address, when that address has been seen with exactly
one ID (the evidence says so), or through ``origin`` when the observer knows who sent it.
Datagrams fed with ``origin=TESTER`` are the test harness's own (often faulty on purpose):
they are input to the other nodes and never blamed.

What the trace proves and nothing more. A capture point misses datagrams, so by default
(``complete=False``) the monitor judges only what was *seen*: a datagram that breaks a
sender rule, an ACK that must not exist, copies that interleave with a newer message, a
retransmission storm. The absence of something (an ACK, a retransmission, a delivery) is
evidence only when the trace holds every datagram the nodes exchanged (``complete=True``:
the runner's own socket, a capture on the one host where every node runs), and even then
a deadline that falls after the end of the trace judges nothing. Autopilot-link events are
taken as complete for a drone once any was fed for it.

Its MCP-RTX-1/2 failures stand only where ``judge.explain`` cannot explain the trace without
them (``judge.veto``, applied at :meth:`Monitor.finish`; what it dropped is in
:attr:`Monitor.vetoed` with the explanation), so a failure returned before ``finish`` may
still be withdrawn: :meth:`Monitor.verdicts` and :attr:`Monitor.violations` after it are the
judgement.

Rules judged (spec/mcp.yaml): HDR-1..5, ACK-1..7, SEQ-1..4, RTX-1..4, BLK-1..7, PAY-1..8,
ROB-2..4, FLOW-1..6, DUP-1..4 and TRN-2 (a node that ACKs a sender from one address but not
from another). ROB-1/5/6/7 (liveness after bad input) need a live node and are the runner's;
they stay ``not_observed`` here.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any, Literal

from mcp_conform.judge._monitor_base import (
    ACK,
    HDR,
    JITTER_NS,
    LEVEL,
    MIN_COPIES,
    N_ACTIONS,
    NS,
    PASSTHROUGH,
    PRE,
    PRE_LEN,
    RTX_TOLERANCE,
    TESTER,
    VEHICLE_KINDS,
    VERDICT_OF_LEVEL,
    NodeFacts,
    VehicleEvent,
    Violation,
    _Node,
    _Timers,
    action_name,
    byte_order_fault,
    late_ack_wait_s,
    role_of,
    unpack_header,
)
from mcp_conform.judge._monitor_receiver import ReceiverRules
from mcp_conform.judge._monitor_rtx import DESCRIPTION_TIMEOUT_NS
from mcp_conform.judge._monitor_sender import SenderRules
from mcp_conform.judge._monitor_vehicle import (
    VehicleRules,
    alteration,
    events_from_mavlink,
    events_from_vehicle,
    frame_hex,
)
from mcp_conform.judge.veto import Recorder, Vetoed, veto
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import BROADCAST_ID, DecodeError, decode
from mcp_conform.spec.mission import sane_item

__all__ = [
    "MONITORED_RULES",
    "byte_order_fault",
    "Monitor",
    "NodeFacts",
    "TESTER",
    "VEHICLE_KINDS",
    "VehicleEvent",
    "Violation",
    "alteration",
    "events_from_mavlink",
    "events_from_vehicle",
    "frame_hex",
    "late_ack_wait_s",
]

#: Rules the monitor can judge from traffic (and the autopilot link); every other rule of a
#: node's role is reported ``not_observed``.
MONITORED_RULES: frozenset[str] = frozenset(
    f"MCP-{r}" for r in (
        "HDR-1 HDR-2 HDR-3 HDR-4 HDR-5 ACK-1 ACK-2 ACK-3 ACK-4 ACK-5 ACK-6 ACK-7 SEQ-1 SEQ-2 SEQ-3 "
        "SEQ-4 RTX-1 RTX-2 RTX-3 RTX-4 BLK-1 BLK-2 BLK-3 BLK-4 BLK-5 BLK-6 BLK-7 PAY-1 PAY-2 PAY-3 "
        "PAY-4 PAY-5 PAY-6 PAY-7 PAY-8 ROB-2 ROB-3 ROB-4 FLOW-1 FLOW-2 FLOW-3 FLOW-4 FLOW-5 FLOW-6 "
        "DUP-1 DUP-2 DUP-3 DUP-4 TRN-2").split())

_ACK_LEN = HDR + 2
#: where a header's seq field ends: the preamble, dst and src before it (``spec.codec.HEADER``)
_SEQ_END = PRE_LEN + 6
#: (rule, role) -> whether the rule binds a node of that role (``Monitor._judged``)
_BINDS: dict[tuple[str, str], bool] = {}
_KINDS = tuple(SPEC.actions[a].payload_kind for a in range(N_ACTIONS))
_EMPTY = frozenset(a for a in range(N_ACTIONS) if _KINDS[a] == "empty")
_ITEMS = frozenset(a for a in range(N_ACTIONS) if _KINDS[a] in ("counted_items", "single_item"))


class Monitor(SenderRules, ReceiverRules, VehicleRules):
    """Judge MCP traffic incrementally (see the module docstring).

    ``rto``: the nodes' retransmission timeout as assumed (s); ``ack_window``: how long "no
    reply" is watched (D-6); ``broadcast_id`` (D-1); ``drones``: the mission's drone IDs when
    known (MCP-BLK-2, MCP-HDR-4); ``challenge`` (1-3) and ``waypoints`` (the mission items
    the manager should send: waypoints for challenges 1-2, obstacles for 3) for MCP-FLOW-4..6;
    ``complete``: the trace holds every datagram the nodes exchanged (absences are evidence);
    with ``party`` (a node's own capture, ``mcp-node --capture``) only every datagram that
    node sent or received: what it overheard between others (a manager's commands to the
    other drones on a shared port, without their ACKs) is judged as a lossy trace would be.
    ``rto_declared``: ``rto`` is the nodes' own retransmission timeout, as the run that set
    them up knows it (the runner's embedded reference node, the simulator's models), not only
    assumed: a lone copy's next one is overdue one and a half ``rto`` after it, where an
    assumed ``rto`` waits for the description's timeout (MCP-RTX-1, ``_rtx_deadline``).
    """

    def __init__(self, rto: float = 5.0, ack_window: float = 2.0, broadcast_id: int = BROADCAST_ID,
                 drones: Iterable[int] | None = None, challenge: int | None = None,
                 waypoints: Iterable[Any] | None = None, *, complete: bool = False,
                 party: int | None = None, rto_declared: bool = False) -> None:
        self.rto_ns = int(rto * NS)
        self.rto_declared = rto_declared
        #: a lone copy's next one is due this long after it, at the latest (``_rtx_deadline``):
        #: the declared timeout, else the assumed one but never before the description's
        self.lone_rto_ns = self.rto_ns if rto_declared else max(self.rto_ns, DESCRIPTION_TIMEOUT_NS)
        self.window_ns = int(ack_window * NS)
        self.broadcast_id = broadcast_id
        self.drones = tuple(drones) if drones is not None else None
        self._declared = frozenset((0, *self.drones)) if self.drones is not None else None
        self.challenge = challenge
        self.waypoints = tuple(waypoints) if waypoints is not None else None
        self.complete = complete
        self.party = party
        self._packed_waypoints: list[bytes] | None = None
        self._insane: dict[bytes, str] = {}  # MCP-PAY-7: the first problem, by payload bytes
        #: MCP-RTX-1's first look at an unACKed unicast (``_rtx_expire``; one delay for all,
        #: a FIFO): when its MIN_COPIES copies at --rto's pace were all due, or sooner when a
        #: lone copy's next one is overdue by then (``_rtx_deadline``: one and a half timeouts,
        #: the description's when --rto is shorter, plus the ACK window), which waits on from
        #: there while copies come. At --rto 5 the first look came 32 s after the copy, so a
        #: complete capture of a manager's End_Mission sent once, with nothing more for six
        #: timeouts (30 s), ended unjudged though its next copy was overdue at 9.5 s (issue 38)
        self._rtx_delay = min(MIN_COPIES * 3 * self.rto_ns // 2, 3 * self.lone_rto_ns // 2) + self.window_ns
        #: a declared timeout: a lone copy's third was due this long after it at the latest
        #: (MIN_COPIES - 1 gaps of rto and MCP-RTX-3's tolerance, and the timestamp jitter), the
        #: first look at every unicast then (``_rtx_deadline`` waits on from there for the others)
        self.lone_due_ns = (MIN_COPIES - 1) * int(self.rto_ns * (1 + RTX_TOLERANCE)) + 3 * JITTER_NS
        if rto_declared:
            self._rtx_delay = self.lone_due_ns
        #: how late an ACK is still taken to answer something other than the message it
        #: names exactly (a broadcast, a malformed datagram: numbers do not repeat that soon)
        self._ack_horizon = max(10 * NS, 2 * (self.window_ns + self.rto_ns))
        self._waypoint_set: frozenset[bytes] = frozenset()
        #: How long a (src, dst, seq) stays the same message: copies closer than this are
        #: retransmissions, a later one is a new message after the numbers wrapped -- unless it
        #: repeats its sender's latest message to that receiver (``_late_copy``: a copy).
        self.horizon_ns = max(60 * NS, 20 * self.rto_ns)
        self._next_prune = 0  # trace time of the next pruning of old messages
        self.count = 0  # datagrams fed
        self._rd: int | None = None  # the run delay of the datagram being judged
        self.last_t = 0
        self.violations: list[Violation] = []
        self._out: list[Violation] = []
        self._nodes: dict[int, _Node] = {}
        self._tester_ids: set[int] = set()
        self._addr_ids: dict[Any, set[int]] = {}
        self._orphans: list[tuple[int, int, Any, str, str]] = []  # malformed, sender unknown yet
        self._ex: dict[int, Any] = {}  # src << 32 | dst << 16 | seq -> the message
        self._by_seq: dict[int, Any] = {}  # src << 16 | seq -> what src last sent with it
        self._ack_seq: dict[int, Any] = {}  # src << 16 | own seq -> [dst, i, t, copies, answers] of its ACK
        self._to_seq: dict[int, Any] = {}  # dst << 16 | seq -> the latest message to dst
        self._timers = _Timers()
        self._violated: set[tuple[int, str]] = set()
        self._frame_ok: dict[bytes, str | None] = {}
        self._items: dict[tuple[int, bytes], Any] = {}  # decoded item payloads by bytes
        self._on_real: dict[int, list[Any]] = {}  # judgements waiting for a node to show itself
        self._malformed_seen: set[tuple[int, int, int, int]] = set()
        self._malformed_lists: set[tuple[int, int]] = set()  # (drone, action): a list sent malformed
        self._acked_addrs: dict[tuple[int, int], set[Any]] = {}  # (src, dst) -> addresses ACKed from
        self._acks_to: set[int] = set()  # IDs an ACK was addressed to (MCP-ACK-6 observed)
        #: (acker, dst) -> (index, t, named) of the acker's last ACK to dst that named nothing
        #: it was sent: a copy whose ACK-1 deadline finds one after it was ACKed wrongly (ACK-2)
        self._stray_acks: dict[tuple[int, int], tuple[int, int, int]] = {}
        #: (acker, dst) -> (index, t) of the acker's last re-ACK to dst: an ACK naming a message
        #: every copy of which had drawn one (D-9: legal; a waiting copy's wrong ACK, or not)
        self._reacks: dict[tuple[int, int], tuple[int, int]] = {}
        #: (acker, sender) -> the latest arrival a right ACK of the acker's answered (MCP-ACK-1)
        self._answered_to: dict[tuple[int, int], int] = {}
        #: (receiver, sender) -> the latest message a copy of which came after its ACK, and
        #: the ACKs naming what the receiver must not ACK (a broadcast ...) while that copy
        #: waited: the copy's wrong ACKs or what they name, decided at its ACK-1 deadline
        self._waiting_copy: dict[tuple[int, int], Any] = {}
        self._ambiguous: dict[int, tuple[Any, list[tuple[Any, int, int, int]]]] = {}
        #: indexes of re-ACKs naming a message while a later copy of another one waited for
        #: its ACK: that copy's wrong ACK as well as the re-ACK (``_acked``)
        self._doubtful: set[int] = set()
        #: src << 16 | dst -> when src last sent dst a (non-ACK) message, any copy
        self._last_to: dict[int, int] = {}
        #: src << 16 | dst -> src's latest new message to dst (not the harness's), kept past the
        #: horizon: a copy of it is one however late (``_late_copy``); one per pair, as
        #: ``_acked_addrs``
        self._latest_to: dict[int, Any] = {}
        #: (acker, dst) -> (index, t) of the acker's latest ACK to dst naming nothing dst sent it
        #: (the harness's too: MCP-RTX-2's deliberate wrong ACKs), for ``stale_ack``
        self._unmatched_acks: dict[tuple[int, int], tuple[int, int]] = {}
        #: the sequence numbers any datagram fed so far carried (a flag per number): an ACK
        #: naming none of them acknowledges no message (MCP-ACK-2, ``_ack_of_nothing``)
        self._carried = bytearray(0x10000)
        self._nothing: dict[int, tuple[int, int, int, int]] = {}  # index -> (src, dst, named, t)
        self._bcast_srcs: set[int] = set()  # senders of broadcasts (MCP-ACK-4 observed)
        self._unicast_dsts: set[int] = set()  # unicast destinations (MCP-ACK-5 observed)
        self._rob_dsts: dict[str, set[int]] = {r: set() for r in ("MCP-ROB-2", "MCP-ROB-3", "MCP-ROB-4")}
        self._latency: dict[int, list[Any]] = {}  # MCP-ACK-7 samples per ACKing node
        self._pt: dict[Any, list[Any]] = {}  # Mav_Passthrough messages by frame key
        self._pt_to: dict[int, list[Any]] = {}  # ... by destination
        self._node_delivers: set[int] = set()  # drones seen forwarding passthrough frames
        self.inferred_challenge: int | None = None
        self.finished = False
        #: what the monitor was fed, for judge.explain's veto at ``finish`` (``judge.veto``)
        self.recorder = Recorder()
        #: the MCP-RTX-1/2 violations judge.explain explained away, with the explanation
        self.vetoed: list[Vetoed] = []
        for d in self.drones or ():
            self._node(d)

    # ------------------------------------------------------------------ input
    def datagram(self, t_ns: int, src_addr: Any, dst_addr: Any, data: bytes,
                 origin: Any = None, run_delay: int | None = None) -> list[Violation]:
        """Judge one datagram seen on the wire (any direction). ``src_addr``/``dst_addr`` are
        ``(host, port)`` or None; ``origin`` is :data:`TESTER` for the harness's own
        datagrams, an MCP ID when the observer knows the sender, else None; ``run_delay``:
        its sender's run delay (ns) as it came, when known (MCP-RTX-3, ``judge.spacing``)."""
        i = self.count
        self.count = i + 1
        self._rd = run_delay
        self.last_t = t_ns
        if t_ns > self._next_prune:
            self._prune(t_ns)
            self._next_prune = t_ns + self.horizon_ns
        out: list[Violation] = []
        self._out = out
        tm = self._timers
        if (tm.heap and tm.heap[0][0] <= t_ns) or (tm.fifo and tm.fifo[0][0] <= t_ns):
            self._run_timers(t_ns)
        n = len(data)
        tester = origin is TESTER
        self.recorder.add(t_ns, data, tester, run_delay)
        if n >= _SEQ_END:  # its number, framed or not: what an ACK may name (``_carried``)
            self._carried[data[_SEQ_END - 2] << 8 | data[_SEQ_END - 1]] = 1
        if n < HDR or not data.startswith(PRE):
            self._unframed(i, t_ns, src_addr, data, n, tester, origin)
            return out
        dst, src, seq, action = unpack_header(data)[3:]
        nodes = self._nodes
        swapped = byte_order_fault(origin, src, action) if isinstance(origin, int) and not tester else None
        if swapped is not None:
            self._byte_order(i, t_ns, origin, action, swapped)
            tester = True  # its fields are misread in network order: judged as input only
        elif origin is not None and not tester and origin != src:
            self._wrong_src(i, t_ns, origin, src, action)
            tester = True  # its src is not its sender's: judged as input only
        elif self._declared is not None and not tester and src not in self._declared:
            # MCP-HDR-4: an ID outside the mission; its sender is named by address at the end
            self._orphans.append((i, t_ns, src_addr, "MCP-HDR-4", f"has src {src}"))
            tester = True
        if tester:
            if origin is not TESTER:
                self.recorder.mark_tester(i)
            self._tester_ids.add(src)
            node = None
        else:
            node = nodes.get(src) or self._node(src)
            node.sent += 1
            if not node.real:
                node.real = True
                for fn, args in self._on_real.pop(src, ()):
                    fn(t_ns, *args)
            if origin is not None and "MCP-HDR-4" not in node.seen:
                node.seen.add("MCP-HDR-4")  # the observer knows the sender: its src is checked
            if src_addr is not None and action < N_ACTIONS:
                if src_addr not in node.addresses:
                    node.addresses[src_addr] = None
                    self._addr_ids.setdefault(src_addr, set()).add(src)
        receiver = nodes.get(dst)
        if receiver is not None:
            receiver.received += 1
        if action == ACK:
            if n == _ACK_LEN:
                self._ack(i, t_ns, src, dst, seq, (data[HDR] << 8) | data[HDR + 1], tester, node)
            else:
                self._malformed(i, t_ns, src, dst, seq, action, "MCP-ROB-4", tester,
                                f"ACK payload of {n - HDR} bytes (exactly 2 required)")
            return out
        if action >= N_ACTIONS:
            self._malformed(i, t_ns, src, dst, seq, action, "MCP-ROB-3", tester,
                            f"action code {action} is not 0-{N_ACTIONS - 1}")
            return out
        if action in _EMPTY:
            if n != HDR:
                self._malformed(i, t_ns, src, dst, seq, action, "MCP-ROB-4", tester,
                                f"payload of {n - HDR} bytes where {action_name(action)} has none")
                return out
            payload = None
        elif action == PASSTHROUGH:
            frame = data[HDR:]
            why: str | None | Literal[False] = self._frame_ok.get(frame, False)
            if why is False:
                try:
                    decode(data)
                    why = None
                except DecodeError as exc:
                    why = exc.reason
                if len(self._frame_ok) < 4096:
                    self._frame_ok[frame] = why
            if why is not None:
                self._malformed(i, t_ns, src, dst, seq, action, "MCP-ROB-4", tester, why)
                return out
            payload = frame
        elif action in _ITEMS:  # mission items repeat (retransmissions, WP_On cycles): cached
            key = (action, data[HDR:])
            payload = self._items.get(key)
            if payload is None:
                payload = self._decode_items(data)
                if len(self._items) < 4096:
                    self._items[key] = payload
            if isinstance(payload, DecodeError):
                self._malformed(i, t_ns, src, dst, seq, action, "MCP-ROB-4", tester, payload.reason)
                return out
        else:
            try:
                payload = decode(data).payload
            except DecodeError as exc:
                self._malformed(i, t_ns, src, dst, seq, action, "MCP-ROB-4", tester, exc.reason)
                return out
        self._message(i, t_ns, src, dst, seq, action, data, payload, tester, src_addr)
        return out

    def vehicle(self, t_ns: int, drone_id: int, event: VehicleEvent) -> list[Violation]:
        """An observation on drone ``drone_id``'s autopilot link (see :class:`VehicleEvent`)."""
        out: list[Violation] = []
        self._out = out
        self.last_t = max(self.last_t, t_ns)
        if self._timers.pending(t_ns):
            self._run_timers(t_ns)
        self._vehicle_event(t_ns, drone_id, event)
        return out

    def run_delay(self, t_ns: int, node: int, run_delay_ns: int) -> None:
        """Node ``node`` (its MCP ID) had ``run_delay_ns`` of run delay (D-7) at ``t_ns``, known
        without a datagram -- read as its view ends, so a stall after its last datagram is
        known. Judges nothing by itself: the veto (``judge.veto``) counts it as a datagram's."""
        self.recorder.sample(t_ns, node, run_delay_ns)

    def advance(self, t_ns: int) -> list[Violation]:
        """Time has passed: deadlines up to ``t_ns`` fall due."""
        out: list[Violation] = []
        self._out = out
        self.last_t = max(self.last_t, t_ns)
        self._run_timers(t_ns)
        return out

    def finish(self, t_ns: int | None = None) -> list[Violation]:
        """The trace ends at ``t_ns`` (default: the last time seen). Deadlines after it judge
        nothing; what needs the whole trace (medians, the mission's end) is judged now."""
        out: list[Violation] = []
        self._out = out
        if self.finished:
            return out
        end = self.last_t if t_ns is None else max(t_ns, self.last_t)
        self.last_t = end
        self._run_timers(end)
        self._finish_sender(end)
        self._finish_receiver(end)
        self._finish_orphans()
        self._veto(end, out)
        self.finished = True
        return out

    def _veto(self, end: int, out: list[Violation]) -> None:
        """MCP-RTX-1/2 failures judge.explain explains away are dropped (``judge.veto``)."""
        vetoed = veto(self.violations, self.recorder, rto=self.rto_ns / NS,
                      ack_window=self.window_ns / NS, end_ns=end, broadcast_id=self.broadcast_id,
                      complete_for=self._complete_for)
        self.recorder.records = []
        if not vetoed:
            return
        gone = {id(x.violation) for x in vetoed}
        self.violations[:] = [v for v in self.violations if id(v) not in gone]
        out[:] = [v for v in out if id(v) not in gone]
        self.vetoed += vetoed
        for x in vetoed:
            key = (x.violation.node, x.violation.rule)
            if not any((v.node, v.rule) == key for v in self.violations):
                self._violated.discard(key)

    # ------------------------------------------------------------------ output
    def verdicts(self) -> dict[int, dict[str, str]]:
        """``{node_id: {rule_id: verdict}}`` for every node seen, over the rules of its role:
        failed / warned / info where a MUST / SHOULD / INFO rule was violated, passed where
        the rule was observed and never violated, info for an observed INFO rule, else
        not_observed."""
        out: dict[int, dict[str, str]] = {}
        for node in sorted(self._nodes.values(), key=lambda n: n.id):
            if not self._reported(node):
                continue
            role = node.role
            table = {}
            for rule in SPEC.rules:
                if rule.status != "active" or not rule.applies_to(role):
                    continue
                key = (node.id, rule.id)
                if key in self._violated:
                    table[rule.id] = VERDICT_OF_LEVEL[rule.level]
                elif rule.id in node.seen:
                    table[rule.id] = "info" if rule.level == "INFO" else "passed"
                else:
                    table[rule.id] = "not_observed"
            out[node.id] = table
        return out

    def nodes(self) -> list[NodeFacts]:
        """The nodes the trace showed (not the harness's own IDs), by ID."""
        return [NodeFacts(n.id, n.role, tuple(n.addresses), n.sent, n.received)
                for n in sorted(self._nodes.values(), key=lambda n: n.id) if self._reported(n)]

    def _reported(self, node: _Node) -> bool:
        return node.real or (self.drones is not None and node.id in self.drones)

    def _decode_items(self, data: bytes) -> Any:
        """The mission items of a datagram (or its DecodeError); MCP-PAY-7's problems noted
        by payload bytes in ``_insane``."""
        try:
            payload = decode(data).payload
        except DecodeError as exc:
            return exc
        for item in (payload if isinstance(payload, tuple) and not hasattr(payload, "_fields") else (payload,)):
            problems = sane_item(item)
            if problems:
                self._insane[data[HDR:]] = f"item {item.seq}: {'; '.join(problems)}"
                break
        return payload

    # ------------------------------------------------------------------ shared helpers
    def _node(self, node_id: int) -> _Node:
        node = self._nodes.get(node_id)
        if node is None:
            node = self._nodes[node_id] = _Node(node_id)
        return node

    def _run_timers(self, now: int) -> None:
        for fn, args in self._timers.due(now):
            fn(now, *args)

    def _rtx_expire(self, now: int, ex: Any) -> None:
        """MCP-RTX-1's deadline of one unicast (``_timers.after``): ACKed, or judged."""
        if ex.acks:
            self._nodes[ex.src].seen.add("MCP-RTX-1")
        else:
            self._rtx_deadline(now, ex)

    def _complete_for(self, *ids: int) -> bool:
        """Absences are evidence about what passes between ``ids``: the trace is complete,
        and (a node's own capture) its node is one of them."""
        return self.complete and (self.party is None or self.party in ids)

    def _judged(self, node: int, rule: str) -> bool:
        """Whether ``rule`` binds ``node`` (its role) and ``node`` is not the harness."""
        n = self._nodes.get(node)
        if n is None or not n.real:
            return False
        role = role_of(node)
        binds = _BINDS.get((rule, role))
        if binds is None:  # the spec's answer, asked once per rule and role (issue 17)
            binds = _BINDS[rule, role] = SPEC.rule(rule).applies_to(role)
        return binds

    def _observe(self, node: int, rule: str) -> None:
        (self._nodes.get(node) or self._node(node)).seen.add(rule)

    def _emit(self, rule: str, node: int, t_ns: int, expected: str, actual: str,
              evidence: Iterable[tuple[int, int]]) -> None:
        n = self._nodes.get(node)
        if (n is None or not n.real) and node not in self._tester_ids:
            # a node not seen sending yet (a drone arming before its Mission_Ready): blamed
            # once it shows itself as a node rather than the harness
            self._on_real.setdefault(node, []).append(
                (lambda now, *a: self._emit(*a), (rule, node, t_ns, expected, actual, tuple(evidence))))
            return
        if not self._judged(node, rule):
            return
        v = Violation(rule, LEVEL[rule], node, t_ns, expected, actual, tuple(evidence))
        self._violated.add((node, rule))
        self._nodes[node].seen.add(rule)
        self.violations.append(v)
        self._out.append(v)

    # ------------------------------------------------------------------ unframed datagrams
    def _unframed(self, i: int, t: int, src_addr: Any, data: bytes, n: int, tester: bool,
                  origin: Any) -> None:
        """Short (< 17 bytes) or bad preamble: MCP-HDR-2 / MCP-HDR-1 on its sender when it can
        be named; as input to others, a bad preamble with a whole header is MCP-ROB-2's."""
        k = min(n, PRE_LEN)
        rule = "MCP-HDR-1" if data[:k] != PRE[:k] else "MCP-HDR-2"
        what = (f"starts {bytes(data[:PRE_LEN]).hex(' ')}" if rule == "MCP-HDR-1"
                else f"{n} bytes long")
        if n >= HDR:
            dst, src, seq, action = unpack_header(data)[3:]
            self._remember(src, seq, ("MCP-ROB-2", dst, i, t, action))
            self._rob_dsts["MCP-ROB-2"].add(dst)
        if tester:
            return
        if isinstance(origin, int):
            node = self._node(origin)
            node.real = True
            node.sent += 1
            self._blame_unframed(origin, i, t, rule, what, "")
        else:
            self._orphans.append((i, t, src_addr, rule, what))

    def _blame_unframed(self, node: int, i: int, t: int, rule: str, what: str, how: str) -> None:
        expected = ("every datagram starts with the preamble " + PRE.hex(" ") if rule == "MCP-HDR-1"
                    else f"at least the {HDR}-byte header")
        self._emit(rule, node, t, expected, f"datagram #{i} {what}{how}", [(i, t)])

    def _finish_orphans(self) -> None:
        """Datagrams whose sender the header cannot name (malformed, or an ID outside the
        declared mission): blamed on the one ID their source address was seen with, if
        exactly one (a mission ID for MCP-HDR-4); otherwise on nobody."""
        for i, t, addr, rule, what in self._orphans:
            ids = self._addr_ids.get(addr) if addr is not None else None
            if ids is not None and rule == "MCP-HDR-4":
                ids = ids & self._declared  # type: ignore[operator]  # HDR-4 orphans: only when declared
            if ids is not None and len(ids) == 1:
                (node,) = ids
                host, port = addr
                how = f" (sender by source address {host}:{port}, seen only with ID {node})"
                if rule == "MCP-HDR-4":
                    self._observe(node, rule)
                    self._emit(rule, node, t, f"src = {node}, the node's configured ID",
                               f"datagram #{i} {what}{how}", [(i, t)])
                else:
                    self._blame_unframed(node, i, t, rule, what, how)
        self._orphans.clear()

    def _byte_order(self, i: int, t: int, origin: int, action: int, why: str) -> None:
        """MCP-HDR-2: the node's header fields read right only byte-swapped (little-endian)."""
        node = self._node(origin)
        node.real = True
        node.sent += 1
        self._observe(origin, "MCP-HDR-2")
        self._emit("MCP-HDR-2", origin, t, "header fields dst, src, seq, action in network byte order (!7s2B4H)",
                   f"datagram #{i}: {why}", [(i, t)])

    def _wrong_src(self, i: int, t: int, origin: int, src: int, action: int) -> None:
        """MCP-HDR-4: the observer knows the sender is ``origin`` but the header says ``src``."""
        node = self._node(origin)
        node.real = True
        node.sent += 1
        self._observe(origin, "MCP-HDR-4")
        self._emit("MCP-HDR-4", origin, t, f"src = {origin}, the node's configured ID",
                   f"{action_name(action)} with src {src}", [(i, t)])

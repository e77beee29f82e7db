"""Manager fault models for the manager role's suite in the simulator (:mod:`sim.manager_runner`):
the independent sample manager's ``--fault`` list (``tests/conformance/nodes/sample_manager.py``)
as :class:`sim.models.ManagerModel` variants, each breaking the one rule the sample's does
(docs/spec.md), so that the real-time matrix of ``tests/conformance/test_manager_role.py`` keeps
only what the simulator cannot check.

Where the sample's fault is in how a message is sent, it is an endpoint fault
(:class:`sim.faults.FaultMixin`, one handler of ``reference_impl._transitions`` changed); where
it is in what the mission sends, a ``ManagerModel`` whose plan or readiness differs:

- ``start-early``, MCP-BLK-2 "The manager sends Start_Mission (or any command) to no drone
  before it has received Mission_Ready from every drone": starts once every drone but one is
  ready;
- ``count-duplicates``, MCP-BLK-2: counts delivered Mission_Ready messages, not drones (the
  runner's second Mission_Ready with a new seq starts it early);
- ``rtx-new-seq``, MCP-SEQ-2 "A retransmission repeats the original's sequence number and
  bytes exactly": each copy takes a new seq, and an ACK of any of them ends it;
- ``wrong-count`` / ``le-count``, MCP-PAY-3 "a u16 big-endian count, then exactly that many
  37-byte mission items": the count one more than the items / packed little-endian;
- ``out-of-order`` / ``field-changed``, MCP-FLOW-4 "the mission's waypoints as one WP_List":
  reversed / the second waypoint 1 m higher than the file's;
- ``wp-off-first``, MCP-FLOW-5 "WP_Off follows a WP_On" (challenge 2): a WP_Off to each drone
  before the first WP_On;
- ``after-end``, MCP-BLK-6 "no command to a drone after that drone's End_Mission": a WP_Off
  to the first drone after its End_Mission;
- ``ack-ack``, MCP-ACK-6 "A node never ACKs an ACK": every ACK addressed to it is ACKed;
- ``broadcast-early``, MCP-BLK-3 "After Start_Mission the manager sends no further command to
  that drone until Start_Mission is ACKed": the WP_List broadcast once, as the last drone's
  Start_Mission goes out, before its ACK (a broadcast goes to every drone, D-11; that drone's
  list, so not also MCP-FLOW-4: one fault, one rule);
- ``broadcast-after-end``, MCP-BLK-6: a WP_Off broadcast after every drone's End_Mission;
- ``skips-a-waypoint`` / ``broadcast-skips-a-waypoint``, MCP-FLOW-5 "WP_On messages carry the
  mission's waypoints" (every one of them: the case's and the monitor's one judge,
  ``judge.waypoints``): the third waypoint's WP_On carries the second again, unicast / broadcast;
- ``reissues-after-two``, MCP-RTX-1 (not in the sample manager's list): each unicast sent twice
  at most, a Start_Mission given up sent once more under a new number (a new message:
  retransmissions are identified by repeating sequence number), then the drone dropped;

and, breaking no rule (controls: no verdict may fall on them), ``acks-copies-late`` (a copy
ACKed again 0.3 s late, past a 0.2 s --rto: "ACKed again, however late", MCP-ACK-1),
``broadcasts-mission`` (the challenge's messages broadcast once to every drone once each
Start_Mission is ACKed, D-11: the C manager's ``VARIANT=BROADCAST``), and the manager faults
of :data:`sim.faults.FAULTS` (``manager-rtx-none``, ``no-ready-ack``, ``wrong-seq-ack``,
``give-up-after-two``, the ``give-up-never`` control). Not modelled:
``no-wait-start-ack`` (MCP-BLK-3: two unicasts in flight at once, which the reference
endpoint's one in-flight slot cannot hold) and ``dup-seq-only`` (no rule a clean link shows).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass
from typing import Any

from mcp_conform.reference_impl._transitions import Input
from mcp_conform.reference_impl.endpoint import _HEAD
from mcp_conform.reference_impl.events import DeliveryConfirmed, DeliveryFailed
from mcp_conform.sim.faults import FAULTS, FaultMixin, GiveUpAfterTwo
from mcp_conform.sim.models import ManagerModel
from mcp_conform.spec.codec import BROADCAST_ID, PREAMBLE, Action, DecodeError, decode, peek_header

__all__ = ["MANAGER_FAULTS", "ManagerFault"]

_U16BE, _U16LE = struct.Struct("!H"), struct.Struct("<H")
_LISTS = (int(Action.WP_LIST), int(Action.OBSTACLES_LIST))


# ---------------------------------------------------------------------- endpoint faults
class RtxNewSeq(FaultMixin):
    """Each copy a new seq; an ACK of any of the message's seqs ends it."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._old_seqs: set[int] = set()  # the in-flight message's earlier seqs

    def _on_retransmit(self, msg: Any, addr: Any, now: float, u: Any) -> None:
        old = u.seq
        self._old_seqs.add(old)
        u.seq = self._take_seq()
        u.data = PREAMBLE + _HEAD.pack(u.dst, self.node_id, u.seq, u.action) + u.payload
        self.deviations.append((now, f"copy of seq {old} sent as seq {u.seq}"))
        super()._on_retransmit(msg, addr, now, u)

    def _on_transmit(self, msg: Any, addr: Any, now: float, u: Any) -> None:
        self._old_seqs = set()
        super()._on_transmit(msg, addr, now, u)

    def receive_datagram(self, data: bytes, addr: Any, now: float) -> None:
        self.now = now
        u = self._in_flight
        head = peek_header(data)
        if u is not None and head is not None and head[3] == Action.ACK and self._old_seqs:
            try:
                m = decode(data)
            except DecodeError:
                m = None
            if m is not None and m.dst == self.node_id and m.src == u.dst and m.payload in self._old_seqs:
                self._step(Input.ACK_MATCHING, m, addr, now, None)
                return
        super().receive_datagram(data, addr, now)


class _ListPayload(FaultMixin):
    """A WP_List's or Obstacles_List's payload changed as it first goes on the wire."""

    def change(self, body: bytes) -> bytes:
        raise NotImplementedError

    def _on_transmit(self, msg: Any, addr: Any, now: float, u: Any) -> None:
        if u.action in _LISTS and len(u.payload) >= 2:
            u.payload = self.change(u.payload)
            self.deviations.append((now, f"{Action(u.action).name} to {u.dst}: payload changed"))
        super()._on_transmit(msg, addr, now, u)


class WrongCount(_ListPayload):
    def change(self, body: bytes) -> bytes:
        return _U16BE.pack((_U16BE.unpack(body[:2])[0] + 1) & 0xFFFF) + body[2:]


class LeCount(_ListPayload):
    def change(self, body: bytes) -> bytes:
        return _U16LE.pack(_U16BE.unpack(body[:2])[0]) + body[2:]


class AckAck(FaultMixin):
    """Every ACK addressed to it is ACKed too (then taken as an ACK)."""

    def receive_datagram(self, data: bytes, addr: Any, now: float) -> None:
        self.now = now
        head = peek_header(data)
        if head is not None and head[3] == Action.ACK and head[0] == self.node_id:
            try:
                m = decode(data)
            except DecodeError:
                m = None
            if m is not None and m.src != self.node_id:
                self._ack(m, addr, m.seq)
                self.deviations.append((now, f"ACK of ACK seq {m.seq} from {m.src}"))
        super().receive_datagram(data, addr, now)


# ---------------------------------------------------------------------- mission faults
class StartEarly(ManagerModel):
    """Starts once every drone but one is ready."""

    def _delivered(self, action: int, src: int, now: float) -> None:
        if action != Action.MISSION_READY or src not in self.drones or src in self.ready:
            return
        self.ready.append(src)
        if len(self.ready) >= max(1, len(self.drones) - 1) and not self._plan and self._handle is None \
                and not self.sent:
            self._plan = self.plan()
            self._next(now)


class CountDuplicates(ManagerModel):
    """Counts delivered Mission_Ready messages, not drones."""

    def _delivered(self, action: int, src: int, now: float) -> None:
        if action != Action.MISSION_READY:
            return
        self.ready.append(src)
        if len(self.ready) >= len(self.drones) and not self._plan and self._handle is None and not self.sent:
            self._plan = self.plan()
            self._next(now)


class _ChangedItems(ManagerModel):
    """The WP_List carries other items than the file's."""

    def items_sent(self) -> tuple[Any, ...]:
        raise NotImplementedError

    def plan(self) -> list[tuple[int, int, Any]]:
        out = super().plan()
        return [(d, a, self.items_sent() if a == Action.WP_LIST else p) for d, a, p in out]


class OutOfOrder(_ChangedItems):
    def items_sent(self) -> tuple[Any, ...]:
        return tuple(reversed(self.items))


class FieldChanged(_ChangedItems):
    def items_sent(self) -> tuple[Any, ...]:
        items = list(self.items)
        if len(items) > 1:
            items[1] = items[1]._replace(z=items[1].z + 1.0)
        return tuple(items)


class WpOffFirst(ManagerModel):
    """Challenge 2: a WP_Off to each drone before its first WP_On."""

    def plan(self) -> list[tuple[int, int, Any]]:
        out = super().plan()
        first = next((i for i, (_, a, _) in enumerate(out) if a == Action.WP_ON), None)
        if first is None:
            return out
        return out[:first] + [(d, Action.WP_OFF, None) for d in self.drones] + out[first:]


class AcksCopiesLate(ManagerModel):
    """Correct: a copy of a message it ACKed already is ACKed again, ``COPY_ACK_DELAY`` s late
    (past a 0.2 s --rto: "ACKed again, however late", MCP-ACK-1; latency is MCP-ACK-7's)."""

    COPY_ACK_DELAY = 0.3

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._acked: set[tuple[int, int]] = set()  # (src, seq) of the messages it ACKed
        self._late: set[tuple[int, int]] = set()  # (drone, seq) whose next ACK goes late
        self.late_acks = 0  # how many ACKs went late (a run that made none proved nothing)

    def receive(self, data: bytes, addr: Any, now: float) -> None:
        head = peek_header(data)
        super().receive(data, addr, now)
        if head is not None and head[0] == self.node_id and head[3] != Action.ACK:
            key = (head[1], head[2])
            if key in self._acked:
                self._late.add(key)
            self._acked.add(key)

    def drain(self, now: float) -> list[tuple[bytes, Any, float]]:
        """What goes on the wire, each with its delay (``sim.transport``'s wire of a model)."""
        out = []
        for data, addr in self.ep.datagrams_to_send(now):
            delay = 0.0
            try:
                m = decode(data)
            except DecodeError:
                m = None
            if m is not None and m.action == Action.ACK and (m.dst, m.payload) in self._late:
                self._late.discard((m.dst, m.payload))
                delay = self.COPY_ACK_DELAY
                self.late_acks += 1
            out.append((data, addr, delay))
        return out


class AfterEnd(ManagerModel):
    """A WP_Off to the first drone after its End_Mission."""

    def plan(self) -> list[tuple[int, int, Any]]:
        return [*super().plan(), (self.drones[0], Action.WP_OFF, None)]


class BroadcastsMission(ManagerModel):
    """Correct (D-11): Start_Mission to each drone, then the challenge's messages broadcast once
    to every drone (never ACKed: MCP-ACK-4; never sent again: MCP-RTX-4) -- one WP_List, each
    waypoint's WP_On and WP_Off, one Obstacles_List -- then End_Mission to each; the C manager's
    ``VARIANT=BROADCAST`` (examples/mcp_c/manager), the C++ one's ``--broadcast-lists``."""

    def plan(self) -> list[tuple[int, int, Any]]:
        out = super().plan()
        n = len(self.drones)
        return out[:n] + [(BROADCAST_ID, a, p) for d, a, p in out[n:-n] if d == self.drones[0]] + out[-n:]

    def _next(self, now: float) -> None:
        self._broadcasts(now)
        super()._next(now)

    def _broadcasts(self, now: float) -> None:
        """The broadcasts at the head of the plan, each on the wire at once (no outcome event)."""
        while self._plan and self._plan[0][0] == BROADCAST_ID:
            _, action, payload = self._plan.pop(0)
            self.ep.send(action, payload, BROADCAST_ID, now=now)
            self.sent.append((action, BROADCAST_ID))


class BroadcastEarly(BroadcastsMission):
    """Faulty (MCP-FLOW-4): the challenge's broadcast goes as the last drone's Start_Mission goes
    out, before its ACK: no command of that drone's mission (D-11)."""

    def _next(self, now: float) -> None:
        super()._next(now)
        if self._current is not None and self._current[:2] == (self.drones[-1], Action.START_MISSION):
            self._broadcasts(now)


class BroadcastAfterEnd(BroadcastsMission):
    """Faulty (MCP-BLK-6): challenge 2 broadcast as :class:`BroadcastsMission` does, then one WP_Off
    more broadcast once every End_Mission is ACKed -- a command to each drone after its
    End_Mission (a broadcast goes to every drone: "it will send no further commands in the
    current mission"), and in no drone's mission (D-11: no WP_Off without a WP_On, MCP-FLOW-5)."""

    def plan(self) -> list[tuple[int, int, Any]]:
        return [*super().plan(), (BROADCAST_ID, Action.WP_OFF, None)]


class SkipsAWaypoint(ManagerModel):
    """Faulty (MCP-FLOW-5, "WP_On messages carry the mission's waypoints"): challenge 2 with the
    third waypoint's WP_Ons carrying the second again -- one waypoint repeated, one skipped, in
    the middle of the mission; every WP_On still a mission waypoint, every WP_Off after one."""

    def plan(self) -> list[tuple[int, int, Any]]:
        items = self.items
        if len(items) < 3:
            return super().plan()
        return [(d, a, items[1] if a == Action.WP_ON and p == items[2] else p) for d, a, p in super().plan()]


class BroadcastSkipsAWaypoint(BroadcastsMission, SkipsAWaypoint):
    """Faulty (MCP-FLOW-5): :class:`SkipsAWaypoint`'s WP_Ons broadcast once to every drone after every
    Start_Mission is ACKed (D-11), as :class:`BroadcastsMission` broadcasts them."""


class ReissuesAfterGiveUp(ManagerModel):
    """Faulty (MCP-RTX-1): each unicast sent twice at most (with :class:`sim.faults.GiveUpAfterTwo`'s
    endpoint at a retry limit of 1), and a Start_Mission given up sent once more as a new message
    -- the endpoint's next number, its own two copies -- before the drone is dropped.
    "Retransmissions of the same message are identified by repeating sequence number": seq N's
    two copies, then seq N+1, are two messages of two copies each, not three copies of one
    renumbered (MCP-SEQ-2); the drone role's re-announcing drone (tests/sim/test_reannounce.py).
    Only Start_Mission: a list sent again so (the silent drone's WP_List) is a second list,
    MCP-FLOW-4's too (one fault, one rule)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.reissued = 0  # how many commands it sent again after a give-up (none: nothing shown)
        self._again = False  # the current command is the one sent again

    def _outcome(self, ev: DeliveryConfirmed | DeliveryFailed, now: float) -> None:
        if (isinstance(ev, DeliveryFailed) and ev.handle == self._handle and self._current is not None
                and self._current[1] == Action.START_MISSION and not self._again):
            dst, action, payload = self._current
            self._again = True
            self.reissued += 1
            self._handle = self.ep.send(action, payload, dst, now=now)
            return
        if ev.handle == self._handle:
            self._again = False
        super()._outcome(ev, now)


class PausesMidMission(ManagerModel):
    """Correct: quiet for ``HOLD`` s mid-mission, longer than the runner's idle window
    (``max(2.5 --rto, 2 --ack-window, 1 s)``) -- challenge 2, each waypoint held active that
    long before its WP_Offs (H-cmanager's C manager's ``--hold``); 1 and 3, a pause before the
    lists. No rule asks a manager to go on at any pace (MCP-FLOW-3/5)."""

    HOLD = 2.5
    BEFORE = (int(Action.WP_OFF), int(Action.WP_LIST), int(Action.OBSTACLES_LIST))

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._wake: float | None = None
        self._last: int | None = None  # the action of the last command sent
        self._resumed = False
        self.pauses = 0  # how many pauses it made (a run that made none proved nothing)

    def _next(self, now: float) -> None:
        nxt = self._plan[0][1] if self._plan else None
        if nxt in self.BEFORE and nxt != self._last and not self._resumed:
            self._wake = now + self.HOLD
            self.pauses += 1
            return
        self._resumed = False
        super()._next(now)
        self._last = self._current[1] if self._current is not None else None

    def timer(self) -> float | None:
        t = super().timer()
        return self._wake if t is None or (self._wake is not None and self._wake < t) else t

    def on_timer(self, now: float) -> None:
        if self._wake is not None and now >= self._wake:
            self._wake, self._resumed = None, True
            self._next(now)
        super().on_timer(now)


class StallsMidMission(PausesMidMission):
    """Faulty (MCP-FLOW-3, and the challenge's FLOW-4/5/6): quiet for ever where
    :class:`PausesMidMission` pauses, alive -- a manager stalled mid-mission. Not in
    :data:`MANAGER_FAULTS` (it breaks more than one rule): ``tests/sim/test_manager_pause_sim.py``."""

    HOLD = math.inf


@dataclass(frozen=True)
class ManagerFault:
    """A manager fault: the rule it breaks (None: none), the challenge its rule is observed at,
    the model class and its endpoint class (None: the reference endpoint), its retry limit
    (None: the model's)."""

    name: str
    rule: str | None
    challenge: int = 1
    model: type[ManagerModel] = ManagerModel
    endpoint: type[FaultMixin] | None = None
    retries: int | None = None
    what: str = ""


def _from_faults() -> dict[str, ManagerFault]:
    return {f.name: ManagerFault(f.name, f.rule, 1, ManagerModel, f.cls, f.retries, f.what)
            for f in FAULTS.values() if f.role == "manager"}


MANAGER_FAULTS: dict[str, ManagerFault] = {**_from_faults(), **{f.name: f for f in (
    ManagerFault("start-early", "MCP-BLK-2", 1, StartEarly, what="starts once every drone but one is ready"),
    ManagerFault("count-duplicates", "MCP-BLK-2", 1, CountDuplicates,
                 what="counts Mission_Ready messages, not drones"),
    ManagerFault("rtx-new-seq", "MCP-SEQ-2", 1, endpoint=RtxNewSeq,
                 what="each retransmission takes a new seq (an ACK of any of them ends it)"),
    ManagerFault("wrong-count", "MCP-PAY-3", 1, endpoint=WrongCount,
                 what="WP_List/Obstacles_List count is one more than the items"),
    ManagerFault("le-count", "MCP-PAY-3", 3, endpoint=LeCount,
                 what="WP_List/Obstacles_List count packed little-endian"),
    ManagerFault("out-of-order", "MCP-FLOW-4", 1, OutOfOrder, what="WP_List carries the waypoints reversed"),
    ManagerFault("field-changed", "MCP-FLOW-4", 1, FieldChanged,
                 what="WP_List's second waypoint is 1 m higher than the file's"),
    ManagerFault("wp-off-first", "MCP-FLOW-5", 2, WpOffFirst, what="a WP_Off before the first WP_On to each drone"),
    ManagerFault("after-end", "MCP-BLK-6", 2, AfterEnd, what="a WP_Off to the first drone after its End_Mission"),
    ManagerFault("ack-ack", "MCP-ACK-6", 1, endpoint=AckAck, what="ACKs the ACKs addressed to it"),
    ManagerFault("broadcast-early", "MCP-BLK-3", 1, BroadcastEarly,
                 what="the WP_List broadcast before the last drone's Start_Mission is ACKed"),
    ManagerFault("broadcast-after-end", "MCP-BLK-6", 2, BroadcastAfterEnd,
                 what="a WP_Off broadcast after every drone's End_Mission"),
    ManagerFault("skips-a-waypoint", "MCP-FLOW-5", 2, SkipsAWaypoint,
                 what="the third waypoint's WP_Ons carry the second again (one repeated, one skipped)"),
    ManagerFault("broadcast-skips-a-waypoint", "MCP-FLOW-5", 2, BroadcastSkipsAWaypoint,
                 what="the WP_Ons broadcast, the third waypoint's carrying the second again"),
    ManagerFault("reissues-after-two", "MCP-RTX-1", 1, ReissuesAfterGiveUp, endpoint=GiveUpAfterTwo, retries=1,
                 what="each unicast sent twice at most, a Start_Mission given up sent again under a new "
                      "number (two copies), then the drone dropped"),
    # correct managers unlike the reference one: no rule broken
    ManagerFault("acks-copies-late", None, 1, AcksCopiesLate, what="a copy is ACKed again 0.3 s late"),
    ManagerFault("give-up-after-three", None, 1, endpoint=GiveUpAfterTwo, retries=2,
                 what="each unicast sent 3 times at most (a retry limit of 2: spec min_copies), then the drone dropped"),
    ManagerFault("broadcasts-mission", None, 1, BroadcastsMission,
                 what="the challenge's messages broadcast once to every drone after every Start_Mission's ACK (D-11)"),
    ManagerFault("pauses-mid-mission", None, 2, PausesMidMission,
                 what="quiet 2.5 s mid-mission (a waypoint held active), past the runner's idle window"),
)}}

"""The MCP nodes of a simulated mission: the drone and the manager as the reference
implementation drives them (``reference_impl.drone`` / ``reference_impl.manager``), over its
sans-I/O :class:`~reference_impl.endpoint.Endpoint`, and their faults (:mod:`sim.faults`).

A model is a party of :class:`sim.world.World`: bytes and ``now`` in (:meth:`NodeModel.receive`,
:meth:`NodeModel.on_timer`), datagrams and the next timer out (:meth:`NodeModel.outbox`,
:meth:`NodeModel.timer`). No socket, thread or clock.

- The drone (``drone.py``'s "Main module" steps): ACKs from the start (MCP-ACK-1: "While
  receiving, a node ACKs every well-formed unicast message addressed to its own ID"); once
  ready (``ready_at``, its GPS fix: MCP-BLK-5) it sends Mission_Ready unicast to ID 0 until
  ACKed (MCP-FLOW-1); it gives up when the endpoint does (exits at once, as ``drone.py``
  returns 1); after End_Mission it keeps ACKing for ``2 x rto`` (``--linger``), then closes.
- The manager (``manager.py``): waits for every drone's Mission_Ready (MCP-BLK-2), then
  sends each command unicast and waits for its outcome before the next (``send_unicast_message``
  blocks: MCP-BLK-1/3): Start_Mission to each drone, the challenge (MCP-FLOW-4/5/6), End_Mission
  to each (MCP-FLOW-3, BLK-6); a drone whose command is given up gets nothing more; then it
  closes.

With an autopilot (:meth:`DroneModel.use_autopilot`: the runner's vehicle, :mod:`sim.vehicle`)
the drone is ``reference_impl.drone``'s with its MAVLink link (:mod:`sim.autopilot`): it waits
for the autopilot's HEARTBEAT, then its 3D fix (MCP-BLK-5), then sends Mission_Ready; it hands
Start_Mission (GUIDED, arm, take off: MCP-BLK-4), WP_List (the mission upload), Mav_Passthrough
(the frame forwarded once: MCP-PAY-8) and End_Mission (RTL: MCP-BLK-7) to the client's jobs,
and after End_Mission waits for them (``drain_timeout``) before its linger.
"""

from __future__ import annotations

import math
import random
from collections.abc import Callable
from typing import Any

from mcp_conform.reference_impl.drone import DroneConfig
from mcp_conform.reference_impl.endpoint import Endpoint
from mcp_conform.reference_impl.events import (
    DeliveryConfirmed,
    DeliveryFailed,
    DuplicateDiscarded,
    MessageDelivered,
)
from mcp_conform.sim.autopilot import AutopilotClient, Flow, Steps
from mcp_conform.spec.codec import (
    BROADCAST_ID,
    MANAGER_ID,
    Action,
    Message,
    MissionItem,
    peek_header,
)

__all__ = ["DroneModel", "ExitingDrone", "ManagerModel", "NodeModel", "mission_items"]

MANAGER_ADDR = ("127.0.0.1", 7889)

#: An endpoint factory: ``(node_id, rto, retries, rng) -> Endpoint`` (a fault's subclass).
EndpointFactory = Callable[[int, float, int, random.Random], Endpoint]


def drone_addr(drone_id: int) -> tuple[str, int]:
    return (f"127.0.1.{drone_id % 250 + 1}", 7890)


def mission_items(n: int, seed: int) -> tuple[MissionItem, ...]:
    """``n`` mission items (MAV_CMD_NAV_WAYPOINT, frame GLOBAL_RELATIVE_ALT) near one point."""
    rng = random.Random(seed)
    return tuple(MissionItem(0.0, 0.0, 0.0, 0.0, -35.363 + rng.uniform(-1e-3, 1e-3),
                             149.165 + rng.uniform(-1e-3, 1e-3), float(10 + i), i, 16, 1, 0, 3, 0, 1)
                 for i in range(n))


def plain_endpoint(node_id: int, rto: float, retries: int, rng: random.Random) -> Endpoint:
    return Endpoint(node_id, timeout=rto, retries=retries, rng=rng)


class NodeModel:
    """What both roles share: the endpoint, the outbox, closing, and the deliveries made."""

    def __init__(self, node_id: int, addr: tuple[str, int], rto: float, retries: int, rng: random.Random,
                 endpoint: EndpointFactory | None = None) -> None:
        self.node_id = node_id
        self.addr = addr
        self.rto = rto
        self.ep = (endpoint or plain_endpoint)(node_id, rto, retries, rng)
        self.closed = False
        self.closed_at: float | None = None
        self.outcome = "running"
        #: (action, src, seq) of every message delivered to the application (MCP-DUP-1's truth)
        self.delivered: list[tuple[int, int, int]] = []
        self.last_delivered: Message | None = None  # the message ``_delivered`` is called for

    def start(self, now: float) -> None:
        """The node's process starts (its socket is open from here)."""

    def receive(self, data: bytes, addr: Any, now: float) -> None:
        self.ep.receive_datagram(data, addr, now)
        self._events(now)

    def timer(self) -> float | None:
        return self.ep.get_timer()

    def on_timer(self, now: float) -> None:
        self.ep.handle_timer(now)
        self._events(now)

    def outbox(self, now: float) -> list[bytes]:
        return [d for d, _ in self.ep.datagrams_to_send(now)]

    def close(self, now: float, outcome: str) -> None:
        self.closed, self.closed_at, self.outcome = True, now, outcome

    def _events(self, now: float) -> None:
        for ev in self.ep.events():
            if isinstance(ev, MessageDelivered):
                m = self.last_delivered = ev.msg
                self.delivered.append((m.action, m.src, m.seq))
                self._delivered(m.action, m.src, now)
            elif isinstance(ev, (DeliveryConfirmed, DeliveryFailed)):
                self._outcome(ev, now)
            elif isinstance(ev, DuplicateDiscarded):
                pass

    def _delivered(self, action: int, src: int, now: float) -> None:
        """A message reached the application."""

    def _outcome(self, ev: DeliveryConfirmed | DeliveryFailed, now: float) -> None:
        """One of our unicasts was ACKed or given up."""


_DRONE = DroneConfig(drone_id=1)


class DroneModel(NodeModel):
    """The drone role (see the module docstring); ``ready_at``: when its GPS fix comes (without
    an autopilot; with one, when the autopilot reports it)."""

    takeoff_alt = _DRONE.takeoff_alt
    drain_timeout = _DRONE.drain_timeout
    heartbeat_timeout = _DRONE.heartbeat_timeout
    #: Mission_Ready given up: it exits (``drone.py`` returns 1), or goes on (False)
    exits_on_give_up = True

    def __init__(self, drone_id: int, rto: float, retries: int, rng: random.Random, *, ready_at: float,
                 linger: float | None = None, endpoint: EndpointFactory | None = None) -> None:
        super().__init__(drone_id, drone_addr(drone_id), rto, retries, rng, endpoint)
        self.ready_at = ready_at
        self.linger = 2 * rto if linger is None else linger
        self.close_at = math.inf
        self._ready_sent = False
        self.started = False
        self.ended = False
        self.ready_acked = False
        self.autopilot: AutopilotClient | None = None
        self._main = Steps()
        self.now = 0.0

    # ------------------------------------------------------------------ the autopilot
    def use_autopilot(self, addr: tuple[str, int]) -> None:
        """Before :meth:`start`: the node reaches the runner's vehicle from ``addr``."""
        self.autopilot = self.make_autopilot(addr)

    def make_autopilot(self, addr: tuple[str, int]) -> AutopilotClient:
        return AutopilotClient(addr)

    def start(self, now: float) -> None:
        self.now = now
        if self.autopilot is not None:
            self.autopilot.start(now)
            self._main = Steps(self.main())
            self._progress(now)

    def receive_autopilot(self, data: bytes, now: float) -> None:
        """Bytes from the vehicle."""
        if self.autopilot is not None and not self.closed:
            self.autopilot.receive(data, now)
            self._progress(now)

    def _until(self, pred: Callable[[], bool], timeout: float) -> Flow:
        return (yield (pred, self.now + timeout))

    def main(self) -> Flow:
        """``reference_impl.drone.Drone._run`` with an autopilot, after the sockets open."""
        ap = self.autopilot
        assert ap is not None
        if not (yield from self._until(lambda: ap.heartbeat, self.heartbeat_timeout)):
            self.close(self.now, "exit:2")  # RoleError: no HEARTBEAT from the autopilot
            return
        yield from self._until(lambda: ap.fix, math.inf)  # MCP-BLK-5
        self.send_ready(self.now)
        yield from self._until(lambda: self.ended, math.inf)
        yield from self._until(ap.idle, self.drain_timeout)  # the RTL and the work before it
        self.close_at = self.now + self.linger

    def submit(self, kind: str, arg: Any = None) -> None:
        if self.autopilot is not None:
            self.autopilot.submit(kind, arg, self.now)

    def _progress(self, now: float) -> None:
        self.now = now
        if not self.closed:
            self._main.advance(now)

    # ------------------------------------------------------------------ MCP
    def send_ready(self, now: float) -> None:
        self._ready_sent = True
        # MCP-FLOW-1 / MCP-PAY-2: "Mission_Ready carries no payload ... it is unicast to ID 0"
        self.ep.send(Action.MISSION_READY, None, MANAGER_ID, now=now)

    def receive(self, data: bytes, addr: Any, now: float) -> None:
        self.now = now
        super().receive(data, addr, now)
        self._progress(now)

    def timer(self) -> float | None:
        t = self.ep.get_timer()
        nxt = self.close_at if t is None else min(t, self.close_at)
        if self.autopilot is not None:
            nxt = min(nxt, self.autopilot.timer(), self._main.deadline())
        elif not self._ready_sent:
            nxt = min(nxt, self.ready_at)
        return None if nxt == math.inf else nxt

    def on_timer(self, now: float) -> None:
        self.now = now
        if self.autopilot is None and not self._ready_sent and now >= self.ready_at:
            self.send_ready(now)
        if now >= self.close_at:
            self.close(now, "end_mission")
            return
        if self.autopilot is not None:
            self.autopilot.on_timer(now)
        super().on_timer(now)
        self._progress(now)

    def _delivered(self, action: int, src: int, now: float) -> None:
        if self.ended:
            return  # after End_Mission: recorded, not acted on
        msg = self.last_delivered
        if action == Action.START_MISSION:
            if not self.started:
                self.submit("takeoff", self.takeoff_alt)
            self.started = True
        elif action == Action.WP_LIST and msg is not None and msg.payload:
            self.submit("mission", tuple(msg.payload))
        elif action == Action.MAV_PASSTHROUGH and msg is not None and isinstance(msg.payload, (bytes, bytearray)):
            self.forward(bytes(msg.payload))
        elif action == Action.END_MISSION:
            self.ended = True
            self.end_mission(now)

    def forward(self, frame: bytes) -> None:
        """A delivered Mav_Passthrough frame to the autopilot (MCP-PAY-8)."""
        self.submit("forward", frame)

    def end_mission(self, now: float) -> None:
        """End_Mission: the RTL (MCP-BLK-7), then ACKing for the linger (with an autopilot:
        once its work is done, :meth:`main`)."""
        if self.autopilot is None:
            self.close_at = now + self.linger
        else:
            self.submit("rtl")

    def _outcome(self, ev: DeliveryConfirmed | DeliveryFailed, now: float) -> None:
        if isinstance(ev, DeliveryFailed):
            if self.exits_on_give_up:  # else it goes on, ACKing and serving (the C drone's way)
                self.close(now, "mission_ready_failed")
        else:
            self.ready_acked = True



class ExitingDrone(DroneModel):
    """The reference drone whose process ends by itself ``exit_after`` s after its ``exit_on``-th
    Mission_Ready copy leaves, with exit code ``exit_code`` (negative: killed by that signal): a
    give-up on a timer of its own (``exit_after`` its period, as the C++ drone's ``--retries``),
    or a crash as it sends (``exit_after`` near 0) -- what the runner tells apart
    (``harness.drone_giveup``). Its retry limit stays its endpoint's (set it past ``exit_on``)."""

    exit_on = 2
    exit_after = 0.0
    exit_code = 1

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.ready_copies = 0
        self.exit_at = math.inf

    def drain(self, now: float) -> list[tuple[bytes, Any, float]]:
        """What it sends (``sim.transport``'s wire hook), its Mission_Ready copies counted."""
        items = [(d, a, 0.0) for d, a in self.ep.datagrams_to_send(now)]
        for data, _, _ in items:
            header = peek_header(data)
            if header is not None and header[3] == int(Action.MISSION_READY):
                self.ready_copies += 1
                if self.ready_copies == self.exit_on:
                    self.exit_at = now + self.exit_after
        return items

    def timer(self) -> float | None:
        t = super().timer()
        return self.exit_at if t is None or self.exit_at < t else t

    def on_timer(self, now: float) -> None:
        if now >= self.exit_at:
            self.close(now, f"exit:{self.exit_code}")
            return
        super().on_timer(now)

class ManagerModel(NodeModel):
    """The Mission Manager (see the module docstring) for ``drones`` and ``challenge`` 1-3."""

    def __init__(self, drones: tuple[int, ...], challenge: int, items: tuple[MissionItem, ...], rto: float,
                 retries: int, rng: random.Random, *, endpoint: EndpointFactory | None = None) -> None:
        super().__init__(MANAGER_ID, MANAGER_ADDR, rto, retries, rng, endpoint)
        self.drones = drones
        self.challenge = challenge
        self.items = items
        self.ready: list[int] = []
        self.failed: list[int] = []
        self.sent: list[tuple[int, int]] = []
        self._plan: list[tuple[int, int, Any]] = []
        self._handle: int | None = None
        self._current: tuple[int, int, Any] | None = None

    def plan(self) -> list[tuple[int, int, Any]]:
        """Every command of the mission, in order: ``(dst, action, payload)``."""
        out: list[tuple[int, int, Any]] = [(d, Action.START_MISSION, None) for d in self.drones]
        if self.challenge == 1:  # MCP-FLOW-4
            out += [(d, Action.WP_LIST, self.items) for d in self.drones]
        elif self.challenge == 2:  # MCP-FLOW-5: "WP_Off follows a WP_On"
            for wp in self.items:
                out += [(d, Action.WP_ON, wp) for d in self.drones]
                out += [(d, Action.WP_OFF, None) for d in self.drones]
        else:  # MCP-FLOW-6
            out += [(d, Action.OBSTACLES_LIST, self.items) for d in self.drones]
        return out + [(d, Action.END_MISSION, None) for d in self.drones]

    def _delivered(self, action: int, src: int, now: float) -> None:
        if action != Action.MISSION_READY or src not in self.drones or src in self.ready:
            return
        self.ready.append(src)
        if set(self.ready) >= set(self.drones) and not self._plan and self._handle is None:
            self._plan = self.plan()  # MCP-BLK-2: every drone is ready
            self._next(now)

    def _outcome(self, ev: DeliveryConfirmed | DeliveryFailed, now: float) -> None:
        if ev.handle != self._handle:
            return
        assert self._current is not None
        dst, action, _ = self._current
        if isinstance(ev, DeliveryFailed):
            self.failed.append(dst)  # "dropped from the mission": nothing more is sent to it
        else:
            self.sent.append((action, dst))
        self._handle = self._current = None
        self._next(now)

    def _next(self, now: float) -> None:
        while self._plan:
            cmd = self._plan.pop(0)
            if cmd[0] in self.failed:
                continue
            self._current = cmd
            self._handle = self.ep.send(cmd[1], cmd[2], cmd[0], now=now)
            return
        self.close(now, "drone_failed" if self.failed else "end_mission")


def is_broadcast(dst: int) -> bool:
    return dst == BROADCAST_ID

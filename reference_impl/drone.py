"""The drone role: a drone application that speaks MCP to the manager and MAVLink to its autopilot.

It follows the description's "Main module" steps in order:

1. connect to the autopilot with pymavlink (``mavutil.mavlink_connection(url)``: ``tcp:`` as
   ArduPilot SITL serves it, ``udp:``/``udpin:`` to receive SITL's ``--out``, ``udpout:``,
   a serial device) and send it a HEARTBEAT each second; with no URL the built-in
   simulated vehicle (:class:`vehicle.SimVehicle`) is started in-process and used;
2. create the ``Mcp`` node with the application's handler (:class:`DroneApp`), so ACKs flow
   from now on (MCP-ACK-1);
3. wait for a HEARTBEAT, then for a 3D GPS fix (GPS_RAW_INT fix_type >= 3) — MCP-BLK-5:
   "The drone sends Mission_Ready only once it is ready to fly";
4. send Mission_Ready unicast to ID 0 with no payload, blocking until ACKed (MCP-FLOW-1,
   MCP-PAY-2: "Mission_Ready carries no payload ... it is unicast to ID 0");
5. on Start_Mission set GUIDED, arm and take off ("ARM the UAV and station keep at 10
   metres"); never arm before it (MCP-BLK-4);
6. keep WP_List, WP_On, WP_Off and Obstacles_List and log them, and upload WP_List's
   waypoints as the autopilot's mission (the mission protocol's handshake, item 0 home);
   forward each delivered Mav_Passthrough frame to the autopilot exactly once (MCP-PAY-8);
7. on End_Mission finish the pending autopilot work, then command RTL (MCP-BLK-7), keep
   ACKing retransmitted copies for a linger period (2 x the timeout, so a lost ACK of
   End_Mission is recovered) and return 0.

Threads. ``Mcp`` ACKs in its network thread and calls the handlers in its handler thread;
the handlers only record and enqueue. All MAVLink I/O happens in one worker thread
(:class:`AutopilotLink`) that owns the connection, reads telemetry and runs queued jobs in
order, so a climb never delays an ACK and End_Mission's RTL runs after every job queued
before it ("finishes pending actions").
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections import Counter
from dataclasses import dataclass
from typing import Any

from mcp_conform.reference_impl.api import Mcp, McpException
from mcp_conform.reference_impl.autopilot import AutopilotLink, connect_autopilot
from mcp_conform.reference_impl.handler import MissionMessageHandlerBase
from mcp_conform.reference_impl.role import (
    EventLogger,
    RoleError,
    RoleNode,
    action_name,
    write_record,
)
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import BROADCAST_ID, MANAGER_ID, Action, Message

__all__ = ["Drone", "DroneApp", "DroneConfig", "RoleError", "action_name"]

_PORTS = SPEC.protocol["ports"]


# ---------------------------------------------------------------------- application
#: Deliveries the record lists one by one (a mission has a few dozen; mcp-soak checks them for
#: exactly-once); past it they are counted: a flood of commands (a fuzz campaign, 10^6 on a bad
#: link in bench/bench_soak.py) keeps the drone's memory flat.
MAX_DELIVERIES = 10_000


class DroneApp(MissionMessageHandlerBase):
    """The drone application's handlers: record each delivery, keep the mission data,
    and hand autopilot work to the :class:`AutopilotLink` worker (never blocking here)."""

    def __init__(self, link: AutopilotLink | None, log: logging.Logger, takeoff_alt: float) -> None:
        super().__init__(link.conn if link is not None else None)
        self.link = link
        self.log = log
        self.takeoff_alt = takeoff_alt
        self.counts: Counter[str] = Counter()
        self.deliveries: list[tuple[str, int, int]] = []  # the first MAX_DELIVERIES
        self.deliveries_omitted = 0  # deliveries past MAX_DELIVERIES, counted only
        self.waypoints: tuple[Any, ...] = ()
        self.obstacles: tuple[Any, ...] = ()
        self.active: list[Any] = []
        self.started = threading.Event()
        self.ended = threading.Event()
        self._lock = threading.Lock()

    def _note(self, msg: Message | None, action: Action) -> bool:
        """Record a delivery; False when it comes after End_Mission (recorded, not acted on)."""
        name = action_name(action)
        with self._lock:
            self.counts[name] += 1
            if msg is not None:
                if len(self.deliveries) < MAX_DELIVERIES:
                    self.deliveries.append((name, msg.src, msg.seq))
                else:
                    self.deliveries_omitted += 1
        if self.ended.is_set():
            self.log.info("%s after End_Mission: not acted on", name)
            return False
        return True

    def handle_mission_ready_message(self, buffer: Any = None, msg: Message | None = None) -> None:
        self._note(msg, Action.MISSION_READY)

    def handle_start_mission_message(self, buffer: Any = None, msg: Message | None = None) -> None:
        if not self._note(msg, Action.START_MISSION):
            return
        if self.started.is_set():
            self.log.info("Start_Mission again: already started")
            return
        self.started.set()
        self.log.info("Start_Mission: arming and taking off to %.1f m", self.takeoff_alt)
        if self.link is not None:
            self.link.submit("takeoff", self.takeoff_alt)

    def handle_end_mission_message(self, buffer: Any = None, msg: Message | None = None) -> None:
        if not self._note(msg, Action.END_MISSION):
            return
        self.log.info("End_Mission: finishing pending work, then RTL")
        if self.link is not None:
            self.link.submit("rtl")
        self.ended.set()

    def handle_wp_list_message(self, buffer: Any = None, msg: Message | None = None) -> None:
        if not self._note(msg, Action.WP_LIST):
            return
        self.waypoints = tuple(buffer or ())
        self.log.info("WP_List: %d waypoints %s", len(self.waypoints), _describe(self.waypoints))
        if self.link is not None and self.waypoints:
            self.link.submit("mission", self.waypoints)

    def handle_wp_on_message(self, buffer: Any = None, msg: Message | None = None) -> None:
        if not self._note(msg, Action.WP_ON):
            return
        self.active.append(buffer)
        self.log.info("WP_On: waypoint %s active", _describe((buffer,)))

    def handle_wp_off_message(self, buffer: Any = None, msg: Message | None = None) -> None:
        """"The most recently specified waypoint to be 'active' is now 'inactive'"."""
        if not self._note(msg, Action.WP_OFF):
            return
        if self.active:
            self.log.info("WP_Off: waypoint %s inactive", _describe((self.active.pop(),)))
        else:
            self.log.info("WP_Off: no active waypoint")

    def handle_obstacle_list_message(self, buffer: Any = None, msg: Message | None = None) -> None:
        if not self._note(msg, Action.OBSTACLES_LIST):
            return
        self.obstacles = tuple(buffer or ())
        self.log.info("Obstacles_List: %d obstacles %s", len(self.obstacles), _describe(self.obstacles))

    def handle_mav_passthrough_message(self, buffer: Any = None, msg: Message | None = None) -> None:
        if not self._note(msg, Action.MAV_PASSTHROUGH):
            return
        if self.link is not None and isinstance(buffer, (bytes, bytearray)):
            self.link.submit("forward", bytes(buffer))


def _describe(items: tuple[Any, ...], limit: int = 4) -> str:
    """``[#1 35.771103,-78.674659 3.0m, ...]`` (x is the latitude, E-2)."""
    parts = []
    for it in items[:limit]:
        try:
            parts.append(f"#{it.seq} {it.x:.6f},{it.y:.6f} {it.z:.1f}m")
        except (AttributeError, TypeError, ValueError):
            parts.append(repr(it))
    more = f", +{len(items) - limit} more" if len(items) > limit else ""
    return "[" + ", ".join(parts) + more + "]"


# ---------------------------------------------------------------------- the role
@dataclass
class DroneConfig:
    """Settings of one drone node; ports and addresses default to the spec's."""

    drone_id: int
    bind_host: str = ""
    local_port: int = int(_PORTS["drone"])
    remote_host: str = str(SPEC.protocol["broadcast_address"])
    remote_port: int = int(_PORTS["manager"])
    mavlink_url: str | None = None
    rto: float | None = None
    retries: int | None = None
    gps_fix_delay: float = 0.0
    takeoff_alt: float = 10.0
    reply_to_source: bool = False
    reuse_port: bool = False  # share the port with other drones on this host (--reuse-port)
    record_path: str | None = None
    #: MCAP capture of the node's MCP traffic and its autopilot link (``--capture``)
    capture_path: str | None = None
    #: ``--live``: serve the capture's channels over the Foxglove WebSocket protocol (host, port)
    live: tuple[str, int] | None = None
    #: ``--impair``: this node's socket edge is a bad link (a ``harness.impair.ImpairSpec``)
    impair: Any = None
    heartbeat_timeout: float = 30.0
    #: Seconds to keep ACKing after End_Mission; None = 2 x the retransmission timeout.
    linger: float | None = None
    #: Longest wait for pending autopilot work (and the RTL) after End_Mission.
    drain_timeout: float = 15.0

    def __post_init__(self) -> None:
        if not 0 < self.drone_id <= 0xFFFF or self.drone_id in (MANAGER_ID, BROADCAST_ID):
            raise RoleError(f"drone ID must be 1..65534 (0 is the manager, {BROADCAST_ID} broadcast): "
                            f"{self.drone_id}")
        if not (math.isfinite(self.takeoff_alt) and self.takeoff_alt > 0):
            raise RoleError(f"takeoff altitude must be a positive number: {self.takeoff_alt}")

    @property
    def timeout(self) -> float:
        return float(SPEC.params["timeout_s"]) if self.rto is None else self.rto


class Drone(RoleNode):
    """One drone node: ``Drone(cfg).run()`` returns the exit code (0 after End_Mission).

    ``stop()`` (from another thread) ends ``run`` early, also returning 0. ``listening``
    is set once the MCP socket is bound (``port`` is then the bound port); ``record()`` is
    what the application received.
    """

    def __init__(self, cfg: DroneConfig, log: logging.Logger | None = None) -> None:
        super().__init__()
        self.cfg = cfg
        self.log = log or logging.getLogger(f"drone-{cfg.drone_id}")
        self.vehicle: Any = None
        self.link: AutopilotLink | None = None
        self.app: DroneApp | None = None
        self.ready_acked = threading.Event()

    def run(self) -> int:
        try:
            return self._run()
        finally:
            self.close()

    def _wait(self, event: threading.Event, timeout: float | None = None) -> bool:
        deadline = None if timeout is None else time.monotonic() + timeout
        while not event.is_set():
            if self._stop.is_set():
                return False
            step = 0.1 if deadline is None else min(0.1, deadline - time.monotonic())
            if step <= 0:
                return False
            event.wait(step)
        return True

    def _run(self) -> int:
        cfg = self.cfg
        url = cfg.mavlink_url
        if url is None:
            from mcp_conform.vehicle import SimVehicle

            self.vehicle = SimVehicle(sysid=1, gps_fix_delay=cfg.gps_fix_delay)
            self.vehicle.start(host="127.0.0.1", port=0)
            url = self.vehicle.url
            self.log.info("built-in simulated vehicle on %s (GPS fix in %.1f s)", url, cfg.gps_fix_delay)
        capture = self._open_capture(cfg.capture_path, "drone", cfg.drone_id, rto=cfg.rto, live=cfg.live, mavlink=url,
                                     impair=cfg.impair.text() if cfg.impair is not None else None,
                                     target=f"{cfg.remote_host}:{cfg.remote_port}")
        self.log.info("connecting to the autopilot at %s", url)
        tap = None if capture is None else (lambda d, raw: capture.mavlink(d, raw, drone=cfg.drone_id))
        self.link = AutopilotLink(connect_autopilot(url), self.log, tap=tap)
        self.app = DroneApp(self.link, self.log, cfg.takeoff_alt)
        try:
            self.mcp = Mcp(self.app, cfg.local_port, cfg.remote_port, cfg.remote_host, cfg.drone_id,
                           bind_host=cfg.bind_host, remote_host=cfg.remote_host, timeout=cfg.rto,
                           retries=cfg.retries, reply_to_source=cfg.reply_to_source,
                           reuse_port=cfg.reuse_port, on_event=EventLogger(self.log),
                           impairment=self._impairment(cfg.impair),
                           tap=None if capture is None else capture.datagram)
        except McpException as exc:
            raise RoleError(str(exc)) from None
        self._capture_bound()
        host, port = self.mcp.local_address
        self.log.info("drone %d listening on %s:%d, sending to %s:%d", cfg.drone_id, host or "0.0.0.0",
                      port, cfg.remote_host, cfg.remote_port)
        self.listening.set()
        if not self._wait(self.link.heartbeat, cfg.heartbeat_timeout):
            if self._stop.is_set():
                return self._stopped()
            raise RoleError(f"no HEARTBEAT from the autopilot at {url} within {cfg.heartbeat_timeout:g} s")
        if not self.link.fix.is_set():
            self.log.info("waiting for a 3D GPS fix (MCP-BLK-5)")
        if not self._wait(self.link.fix):
            return self._stopped()
        self.log.info("sending Mission_Ready to %d", MANAGER_ID)
        try:
            self.mcp.send_unicast_message(Action.MISSION_READY, None, MANAGER_ID)
        except McpException as exc:
            if self._stop.is_set():
                return self._stopped()
            self.log.error("Mission_Ready was never ACKed: %s", exc)
            self.outcome = "mission_ready_failed"
            return 1
        self.ready_acked.set()
        self.log.info("Mission_Ready ACKed; waiting for Start_Mission")
        if not self._wait(self.app.ended):
            return self._stopped()
        done = self.link.submit("noop")  # queued after the RTL: everything before it is done
        if not self._wait(done, cfg.drain_timeout):
            self.log.warning("autopilot work still pending after %.1f s", cfg.drain_timeout)
        linger = 2 * cfg.timeout if cfg.linger is None else cfg.linger
        self.log.info("mission over; still ACKing for %.1f s", linger)
        self._stop.wait(linger)
        self.outcome = "end_mission"
        return 0

    def _stopped(self) -> int:
        self.outcome = "stopped"
        self.log.info("stopped")
        return 0

    def record(self) -> dict[str, Any]:
        """What the application received and did, as JSON-ready data."""
        app, link = self.app, self.link
        return {
            "role": "drone",
            "id": self.cfg.drone_id,
            "outcome": self.outcome,
            "received": dict(app.counts) if app else {},
            "deliveries": [list(d) for d in app.deliveries] if app else [],
            "deliveries_omitted": app.deliveries_omitted if app else 0,
            "waypoints": len(app.waypoints) if app else 0,
            "obstacles": len(app.obstacles) if app else 0,
            "active_waypoints": len(app.active) if app else 0,
            "forwarded": link.forwarded if link else 0,
            "armed": bool(link and link.arm_accepted),  # it armed (the vehicle may have landed since)
            "rtl": bool(link and link.rtl_sent),
        }

    def close(self) -> None:
        """Close the MCP node, the autopilot link and the built-in vehicle; write the record."""
        if self.mcp is not None:
            self.mcp.close()
        if self.link is not None:
            self.link.close()
        if self.vehicle is not None:
            self.vehicle.close()
        self._close_capture()
        if self.cfg.record_path:
            write_record(self.cfg.record_path, self.record(), self.log)

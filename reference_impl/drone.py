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

import json
import logging
import math
import queue
import sys
import threading
import time
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink import mavutil

from reference_impl.api import Mcp, McpException
from reference_impl.events import (
    AckSent,
    DeliveryConfirmed,
    DeliveryFailed,
    DuplicateDiscarded,
    Event,
    Malformed,
    MessageDelivered,
    Retransmitted,
    Unexpected,
)
from reference_impl.handler import MissionMessageHandlerBase
from spec import SPEC
from spec.codec import BROADCAST_ID, MANAGER_ID, Action, Message

__all__ = ["AutopilotLink", "Drone", "DroneApp", "DroneConfig", "EventLogger", "LinkClosed", "RoleError"]

_PORTS = SPEC.protocol["ports"]
_MAV = mavutil.mavlink
#: Seconds between the drone's HEARTBEATs to its autopilot (MAVLink's 1 Hz).
HEARTBEAT_PERIOD = 1.0
#: ArduCopter custom modes, by pymavlink's table (RTL is 6, GUIDED 4).
_GUIDED = {v: k for k, v in mavutil.mode_mapping_acm.items()}["GUIDED"]
_RTL = {v: k for k, v in mavutil.mode_mapping_acm.items()}["RTL"]
#: The 3D fix that MCP-BLK-5's "ready to fly" means here (GPS_FIX_TYPE_3D_FIX).
FIX_3D = 3


class RoleError(Exception):
    """A setup problem the command line reports in one line (bad URL, port, no heartbeat)."""

    def __init__(self, message: str, exit_code: int = 2) -> None:
        super().__init__(message)
        self.exit_code = exit_code


def action_name(action: int) -> str:
    """``Action.WP_LIST`` -> ``"WP_List"``: the description's spelling, for logs and records."""
    try:
        name = Action(action).name
    except ValueError:
        return str(action)
    return "_".join(w if w in ("WP", "ACK", "ANY") else w.capitalize() for w in name.split("_"))


# ---------------------------------------------------------------------- event log
class EventLogger:
    """Logs each endpoint event as one readable line (the CLI's progress output).

    Called in the ``Mcp`` network thread, so it only formats and writes. Malformed input is
    rate-limited (``burst`` lines a second, then one summary), so a flood (MCP-ROB-7)
    does not turn the log into the bottleneck.
    """

    def __init__(self, log: logging.Logger, burst: int = 20) -> None:
        self.log = log
        self.burst = burst
        self._window = 0
        self._in_window = 0
        self._suppressed = 0

    def __call__(self, ev: Event) -> None:
        log = self.log
        if isinstance(ev, MessageDelivered):
            m = ev.msg
            cast = " (broadcast)" if m.dst == BROADCAST_ID else ""
            log.info("received %s seq %d from %d%s", action_name(m.action), m.seq, m.src, cast)
        elif isinstance(ev, AckSent):
            log.info("ACK sent for seq %d to %d", ev.acked_seq, ev.dst)
        elif isinstance(ev, DuplicateDiscarded):
            log.info("duplicate %s seq %d from %d: ACKed, not delivered again (%s)",
                     action_name(ev.msg.action), ev.msg.seq, ev.msg.src, ev.rule)
        elif isinstance(ev, Retransmitted):
            log.info("retransmitted seq %d to %d (copy %d)", ev.seq, ev.dst, ev.copy)
        elif isinstance(ev, DeliveryConfirmed):
            log.debug("seq %d ACKed by %d after %d cop%s", ev.seq, ev.dst, ev.copies,
                      "y" if ev.copies == 1 else "ies")
        elif isinstance(ev, DeliveryFailed):
            log.warning("seq %d to %d never ACKed after %d copies (%s)", ev.seq, ev.dst, ev.copies, ev.rule)
        elif isinstance(ev, Malformed):
            self._malformed(ev)
        elif isinstance(ev, Unexpected):
            what = action_name(ev.msg.action) + f" seq {ev.msg.seq} from {ev.msg.src}" if ev.msg else "input"
            # Shared-port deployments see every other drone's traffic: not-for-us is routine.
            level = logging.DEBUG if ev.rule == "MCP-ACK-5" else logging.INFO
            log.log(level, "ignored %s: %s (%s)", what, ev.reason, ev.rule)

    def _malformed(self, ev: Malformed) -> None:
        second = int(time.monotonic())
        if second != self._window:
            if self._suppressed:
                self.log.info("... %d more malformed datagrams dropped", self._suppressed)
            self._window, self._in_window, self._suppressed = second, 0, 0
        self._in_window += 1
        if self._in_window > self.burst:
            self._suppressed += 1
            return
        self.log.info("dropped malformed datagram (%d bytes) from %s: %s (%s)",
                      len(ev.data), _addr(ev.addr), ev.reason, ev.rule)


def _addr(addr: Any) -> str:
    if isinstance(addr, tuple) and len(addr) >= 2:
        return f"{addr[0]}:{addr[1]}"
    return str(addr)


# ---------------------------------------------------------------------- autopilot
def connect_autopilot(url: str, *, attempts: int = 3, delay: float = 0.5) -> Any:
    """``mavutil.mavlink_connection(url)``, retried a few times; RoleError if it cannot open."""
    last: Exception | None = None
    for attempt in range(max(1, attempts)):
        try:
            return mavutil.mavlink_connection(url, source_system=255, source_component=191,
                                              retries=0, autoreconnect=False)
        except Exception as exc:  # noqa: BLE001 - pymavlink raises anything from socket/serial
            last = exc
            if attempt + 1 < attempts:
                time.sleep(delay)
    if isinstance(last, ImportError):  # pymavlink took it for a serial device
        reason = f"not a tcp:/udp:/udpin: URL, and serial devices need pyserial ({last})"
    else:
        reason = getattr(last, "strerror", None) or str(last) or type(last).__name__
    raise RoleError(f"cannot connect to the autopilot at {url!r}: {reason}")


class LinkClosed(Exception):
    """The autopilot closed the connection (TCP EOF or reset)."""


def _link_closed(*_args: Any) -> None:
    raise LinkClosed("the autopilot closed the connection")


class AutopilotLink:
    """The MAVLink side: one worker thread owns the pymavlink connection.

    It reads telemetry continuously (HEARTBEAT, GPS_RAW_INT, GLOBAL_POSITION_INT,
    COMMAND_ACK) and runs submitted jobs in order: ``takeoff``, ``forward`` (a passthrough
    frame, written once: MCP-PAY-8) and ``rtl``. Every wait is bounded.
    """

    def __init__(self, conn: Any, log: logging.Logger, *, step_timeout: float = 3.0,
                 settle_timeout: float = 2.0, tap: Callable[[str, bytes], Any] | None = None) -> None:
        self.conn = conn
        self.log = log
        #: ``tap(direction, frame)`` sees every frame on the link, from the autopilot's point
        #: of view ("rx": written to the autopilot, "tx": read from it), for captures.
        self.tap = tap
        if tap is not None:
            write = conn.write

            def tapped_write(buf: Any) -> Any:
                result = write(buf)
                tap("rx", bytes(buf))
                return result
            conn.write = tapped_write
        # pymavlink's TCP link prints "EOF on TCP socket" to stdout and retries at once,
        # forever, when the peer goes away: turn that into one exception, handled below.
        for hook in ("handle_eof", "handle_disconnect"):
            if hasattr(conn, hook):
                setattr(conn, hook, _link_closed)
        #: True once the autopilot went away; the node stays live for MCP (MCP-ROB-5).
        self.lost = False
        self.step_timeout = step_timeout
        self.settle_timeout = settle_timeout
        self.heartbeat = threading.Event()
        self.fix = threading.Event()
        self.fix_type = 0
        self.armed = False
        self.custom_mode: int | None = None
        self.rel_alt = 0.0
        self.target_alt: float | None = None
        self.forwarded = 0
        self.rtl_sent = False
        self.takeoff_sent = False
        self._acks: dict[int, int] = {}
        self._next_heartbeat = 0.0
        self._mission_msgs: deque[Any] = deque(maxlen=64)
        self.position: tuple[int, int, float] = (0, 0, 0.0)  # home: lat, lon (degE7), alt (m)
        self.mission_result: int | None = None
        self._sys = 1
        self._comp = 1
        self._jobs: queue.Queue[tuple[str, Any, threading.Event]] = queue.Queue()
        self._stop = threading.Event()
        self._link_error: str | None = None
        self._thread = threading.Thread(target=self._run, name="mavlink-worker", daemon=True)
        self._thread.start()

    # -------------------------------------------------------------- public
    def submit(self, kind: str, arg: Any = None) -> threading.Event:
        """Queue a job (``takeoff`` alt, ``forward`` frame, ``rtl``, ``noop``); its done event."""
        done = threading.Event()
        self._jobs.put((kind, arg, done))
        return done

    def close(self) -> None:
        self._stop.set()
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=5.0)
        try:
            self.conn.close()
        except Exception:  # noqa: BLE001 - closing a dead link
            pass

    # -------------------------------------------------------------- worker
    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                kind, arg, done = self._jobs.get(timeout=0.2) if self.lost else self._jobs.get_nowait()
            except queue.Empty:
                if not self.lost:
                    self._pump(0.05)
                continue
            try:
                if self.lost and kind != "noop":
                    self.log.warning("autopilot link lost: %s not done", kind)
                else:
                    getattr(self, "_job_" + kind)(arg)
            except Exception as exc:  # noqa: BLE001 - a MAVLink failure must not stop the node
                self.log.warning("autopilot job %s failed: %s", kind, exc)
            finally:
                done.set()
        while True:  # release anyone waiting on a job that will never run
            try:
                self._jobs.get_nowait()[2].set()
            except queue.Empty:
                break

    def _pump(self, wait: float) -> None:
        if self.lost:
            self._stop.wait(wait)
            return
        try:
            self._heartbeat()
            msg = self.conn.recv_match(blocking=True, timeout=wait)
            while msg is not None:
                if self.tap is not None and msg.get_type() != "BAD_DATA":
                    self.tap("tx", bytes(msg.get_msgbuf()))
                self._observe(msg)
                msg = self.conn.recv_match(blocking=False)
        except LinkClosed as exc:
            self.lost = True
            self.log.warning("autopilot link lost: %s", exc)
        except Exception as exc:  # noqa: BLE001 - socket/serial errors: report once, keep going
            text = str(exc) or type(exc).__name__
            if text != self._link_error:
                self.log.warning("autopilot link error: %s", text)
                self._link_error = text
            self._stop.wait(0.2)

    def _heartbeat(self) -> None:
        """A HEARTBEAT to the autopilot each second, as companion computers send (over UDP
        the autopilot learns where the drone is from it)."""
        now = time.monotonic()
        if now < self._next_heartbeat:
            return
        self._next_heartbeat = now + HEARTBEAT_PERIOD
        self.conn.mav.heartbeat_send(_MAV.MAV_TYPE_ONBOARD_CONTROLLER, _MAV.MAV_AUTOPILOT_INVALID,
                                     0, 0, _MAV.MAV_STATE_ACTIVE)

    def _observe(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.type == _MAV.MAV_TYPE_GCS or msg.autopilot == _MAV.MAV_AUTOPILOT_INVALID:
                return
            self._sys, self._comp = msg.get_srcSystem(), msg.get_srcComponent()
            self.armed = bool(msg.base_mode & _MAV.MAV_MODE_FLAG_SAFETY_ARMED)
            if msg.custom_mode != self.custom_mode and self.custom_mode is not None:
                self.log.info("autopilot mode %s", mavutil.mode_mapping_acm.get(msg.custom_mode, msg.custom_mode))
            self.custom_mode = msg.custom_mode
            if not self.heartbeat.is_set():
                self.log.info("autopilot HEARTBEAT from system %d", self._sys)
                self.heartbeat.set()
        elif kind == "GPS_RAW_INT":
            self.fix_type = int(msg.fix_type)
            if self.fix_type >= FIX_3D and not self.fix.is_set():
                self.log.info("GPS 3D fix (fix_type %d, %d satellites)", self.fix_type, msg.satellites_visible)
                self.fix.set()
        elif kind == "GLOBAL_POSITION_INT":
            self.rel_alt = msg.relative_alt / 1000.0
            self.position = (msg.lat, msg.lon, msg.alt / 1000.0 - self.rel_alt)
            if self.target_alt is not None and self.rel_alt >= 0.95 * self.target_alt:
                self.log.info("reached %.1f m", self.rel_alt)
                self.target_alt = None
        elif kind in ("MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"):
            self._mission_msgs.append(msg)
        elif kind == "COMMAND_ACK":
            self._acks[int(msg.command)] = int(msg.result)
        elif kind == "STATUSTEXT":
            self.log.debug("autopilot says: %s", msg.text)

    def _wait(self, predicate: Callable[[], bool], timeout: float) -> bool:
        deadline = time.monotonic() + timeout
        while not predicate():
            remaining = deadline - time.monotonic()
            if remaining <= 0 or self._stop.is_set():
                return predicate()
            self._pump(min(0.05, remaining))
        return True

    def _command(self, command: int, *params: float, label: str) -> bool:
        """COMMAND_LONG, resent once a second until COMMAND_ACK (bounded); True if accepted."""
        p = list(params) + [0.0] * (7 - len(params))
        for _ in range(max(1, int(self.step_timeout))):
            self._acks.pop(command, None)
            self.conn.mav.command_long_send(self._sys, self._comp, command, 0, *p)
            if self._wait(lambda: command in self._acks, 1.0):
                ok = self._acks[command] == _MAV.MAV_RESULT_ACCEPTED
                if not ok:
                    self.log.warning("%s refused by the autopilot (result %d)", label, self._acks[command])
                return ok
        self.log.warning("%s: no COMMAND_ACK from the autopilot", label)
        return False

    def _set_mode(self, custom: int, label: str) -> bool:
        set_mode_id = 11  # ArduPilot acknowledges SET_MODE with COMMAND_ACK command = its msgid
        for _ in range(max(1, int(self.step_timeout))):
            self._acks.pop(set_mode_id, None)
            self.conn.mav.set_mode_send(self._sys, _MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom)
            if self._wait(lambda: set_mode_id in self._acks or self.custom_mode == custom, 1.0):
                if self.custom_mode == custom or self._acks.get(set_mode_id) == _MAV.MAV_RESULT_ACCEPTED:
                    return True
                self.log.warning("mode %s refused by the autopilot", label)
                return False
        self.log.warning("mode %s: no answer from the autopilot", label)
        return False

    def _job_noop(self, _arg: Any) -> None:
        pass

    def _job_takeoff(self, alt: float) -> None:
        """Start_Mission: GUIDED, arm (MCP-BLK-4 allows it now), take off to ``alt``."""
        if self.takeoff_sent:
            self.log.info("already flying: Start_Mission not acted on again")
            return
        if self._set_mode(_GUIDED, "GUIDED"):
            self.log.info("mode GUIDED set")
        for _ in range(3):
            if self._command(_MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1.0, label="ARM"):
                break
            self._wait(lambda: False, 0.5)
        else:
            self.log.warning("could not arm the autopilot")
            return
        self.armed = True
        self.log.info("armed")
        self.takeoff_sent = True
        if self._command(_MAV.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt, label="TAKEOFF"):
            self.target_alt = alt
            self.log.info("taking off to %.1f m", alt)

    def _mission_item(self, seq: int, wp: Any) -> None:
        """Send waypoint ``wp`` (a MISSION_ITEM payload from WP_List) as item ``seq``:
        MISSION_ITEM_INT when x/y are degrees, else as it came, for the autopilot to judge."""
        if math.isfinite(wp.x) and math.isfinite(wp.y) and abs(wp.x) <= 90 and abs(wp.y) <= 180:
            self.conn.mav.mission_item_int_send(
                self._sys, self._comp, seq, wp.frame, wp.command, 0, 1, wp.param1, wp.param2,
                wp.param3, wp.param4, int(round(wp.x * 1e7)), int(round(wp.y * 1e7)), wp.z)
        else:
            self.conn.mav.mission_item_send(
                self._sys, self._comp, seq, wp.frame, wp.command, 0, 1, wp.param1, wp.param2,
                wp.param3, wp.param4, wp.x, wp.y, wp.z)

    def _job_mission(self, waypoints: tuple[Any, ...]) -> None:
        """WP_List: upload the waypoints as the autopilot's mission (item 0 is home), with
        the mission protocol's handshake: MISSION_COUNT, each requested item, MISSION_ACK."""
        lat, lon, alt = self.position
        self._mission_msgs.clear()
        self.conn.mav.mission_count_send(self._sys, self._comp, len(waypoints) + 1)
        while True:
            if not self._wait(lambda: bool(self._mission_msgs), self.step_timeout):
                self.log.warning("mission upload: the autopilot stopped asking for items")
                return
            m = self._mission_msgs.popleft()
            if m.get_type() == "MISSION_ACK":
                self.mission_result = int(m.type)
                name = _MAV.enums["MAV_MISSION_RESULT"][m.type].name if m.type in _MAV.enums[
                    "MAV_MISSION_RESULT"] else str(m.type)
                if m.type == _MAV.MAV_MISSION_ACCEPTED:
                    self.log.info("mission of %d waypoints uploaded", len(waypoints))
                else:
                    self.log.warning("mission upload refused by the autopilot: %s", name)
                return
            if m.seq == 0:
                self.conn.mav.mission_item_int_send(
                    self._sys, self._comp, 0, _MAV.MAV_FRAME_GLOBAL, _MAV.MAV_CMD_NAV_WAYPOINT,
                    0, 1, 0, 0, 0, 0, lat, lon, alt)
            elif m.seq <= len(waypoints):
                self._mission_item(m.seq, waypoints[m.seq - 1])

    def _job_forward(self, frame: bytes) -> None:
        """Mav_Passthrough: write the frame's bytes to the autopilot once (MCP-PAY-8)."""
        self.conn.write(frame)
        self.forwarded += 1
        self.log.info("forwarded a %d-byte MAVLink frame to the autopilot", len(frame))

    def _job_rtl(self, _arg: Any) -> None:
        """End_Mission: let a climb in progress finish (bounded), then RTL (MCP-BLK-7)."""
        if self.target_alt is not None:
            self._wait(lambda: self.target_alt is None, self.settle_timeout)
        self.rtl_sent = True
        self.log.info("commanding RTL")
        if self._command(_MAV.MAV_CMD_NAV_RETURN_TO_LAUNCH, label="RTL"):
            self.log.info("RTL accepted")
        elif self._set_mode(_RTL, "RTL"):
            self.log.info("mode RTL set")


# ---------------------------------------------------------------------- application
class DroneApp(MissionMessageHandlerBase):
    """The drone application's handlers: record each delivery, keep the mission data,
    and hand autopilot work to the :class:`AutopilotLink` worker (never blocking here)."""

    def __init__(self, link: AutopilotLink | None, log: logging.Logger, takeoff_alt: float) -> None:
        super().__init__(link.conn if link is not None else None)
        self.link = link
        self.log = log
        self.takeoff_alt = takeoff_alt
        self.counts: Counter[str] = Counter()
        self.deliveries: list[tuple[str, int, int]] = []
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
                self.deliveries.append((name, msg.src, msg.seq))
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


class RoleNode:
    """What both roles share: the MCP endpoint, the ``listening`` event, the outcome, and a
    thread-safe ``stop()`` (also what Ctrl-C/SIGTERM do in the CLI)."""

    def __init__(self) -> None:
        self.mcp: Mcp | None = None
        self.listening = threading.Event()
        self.outcome = "running"
        self._stop = threading.Event()
        self.capture: Any = None

    def _open_capture(self, path: str | None, role: str, node_id: int, **meta: Any) -> Any:
        """The node's MCAP capture (``--capture``), written off the hot path; None without."""
        if not path:
            return None
        from traceio.background import BackgroundRecorder
        from traceio.recorder import RecorderError, run_metadata

        try:
            # the MCAP header names the writer: readers tell a node's own capture from a
            # test harness's (judge.judging: a harness's datagrams are its input, not judged)
            self.capture = BackgroundRecorder(path, library="mcp-node", metadata=run_metadata(
                "mcp-node", role=role, node_id=node_id, argv=" ".join(sys.argv), **meta))
        except RecorderError as exc:
            raise RoleError(str(exc)) from None
        return self.capture

    def _capture_bound(self) -> None:
        """The MCP socket is bound: it is the capture's ``local`` address."""
        if self.capture is not None and self.mcp is not None:
            self.capture.local = self.mcp.local_address

    def _close_capture(self) -> None:
        capture, self.capture = self.capture, None
        if capture is not None:
            capture.close()

    @property
    def port(self) -> int:
        assert self.mcp is not None
        return self.mcp.local_port

    def _on_stop(self) -> None:
        """Wake whatever the role waits on (before the endpoint closes)."""

    def stop(self) -> None:
        """End ``run`` early; a blocked unicast send then raises McpException."""
        self._stop.set()
        if self.outcome == "running":
            self.outcome = "stopped"
        self._on_stop()
        mcp = self.mcp
        if mcp is not None:
            mcp.close()


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
            from vehicle import SimVehicle

            self.vehicle = SimVehicle(sysid=1, gps_fix_delay=cfg.gps_fix_delay)
            self.vehicle.start(host="127.0.0.1", port=0)
            url = self.vehicle.url
            self.log.info("built-in simulated vehicle on %s (GPS fix in %.1f s)", url, cfg.gps_fix_delay)
        capture = self._open_capture(cfg.capture_path, "drone", cfg.drone_id, mavlink=url,
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
            "waypoints": len(app.waypoints) if app else 0,
            "obstacles": len(app.obstacles) if app else 0,
            "active_waypoints": len(app.active) if app else 0,
            "forwarded": link.forwarded if link else 0,
            "armed": bool(link and link.armed),
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


def write_record(path: str, record: dict[str, Any], log: logging.Logger) -> None:
    """Write ``record`` as JSON to ``path`` (atomically enough: one write); log on failure."""
    try:
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(record, fh, indent=1, sort_keys=True)
            fh.write("\n")
    except OSError as exc:
        log.error("cannot write the record to %s: %s", path, exc.strerror)

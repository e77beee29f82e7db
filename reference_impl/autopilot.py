"""The drone's autopilot link (MAVLink through pymavlink): connecting by URL, and the
``AutopilotLink`` worker thread that owns the connection, reads the telemetry (GPS fix,
mode, arming, altitude), sends the drone's HEARTBEAT and runs the application's jobs in
order — GUIDED, arm and take off on Start_Mission (never before it: MCP-BLK-4), the mission
upload with its handshake, Mav_Passthrough frames written once (MCP-PAY-8), RTL at the end
(MCP-BLK-7) — so a climb never delays an ACK."""

from __future__ import annotations

import logging
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from pymavlink import mavutil

from mcp_conform.reference_impl.role import RoleError

_MAV = mavutil.mavlink
#: Seconds between the drone's HEARTBEATs to its autopilot (MAVLink's 1 Hz).
HEARTBEAT_PERIOD = 1.0
#: ArduCopter custom modes, by pymavlink's table (RTL is 6, GUIDED 4).
_GUIDED = {v: k for k, v in mavutil.mode_mapping_acm.items()}["GUIDED"]
_RTL = {v: k for k, v in mavutil.mode_mapping_acm.items()}["RTL"]
#: The 3D fix that MCP-BLK-5's "ready to fly" means here (GPS_FIX_TYPE_3D_FIX).
FIX_3D = 3


__all__ = ["AutopilotLink", "LinkClosed", "connect_autopilot"]


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
        self.armed = False  # the autopilot's state now (its HEARTBEATs): false again once it landed
        #: the autopilot accepted our ARM: what the drone did, whatever the vehicle's state later
        #: (after End_Mission's RTL it lands and disarms, maybe before the node exits)
        self.arm_accepted = False
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
        self.armed = self.arm_accepted = True
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



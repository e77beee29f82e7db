"""Sans-I/O model of an ArduCopter autopilot as a companion computer sees it.

``VehicleModel`` takes decoded MAVLink messages and the current time and returns the
messages the autopilot would send back; ``tick(now)`` returns the telemetry that is due.
It never touches a socket or a clock: ``now`` is always passed in (the server passes
``time.monotonic()``), so every behaviour is unit-testable with a fake clock.

Behaviour (ArduCopter-like, simplified):

* HEARTBEAT at ``heartbeat_hz`` (quadrotor, ArduPilot, custom modes, SAFETY_ARMED when
  armed); SYS_STATUS, GPS_RAW_INT, GLOBAL_POSITION_INT, VFR_HUD and ATTITUDE at
  ``telemetry_hz``.
* No GPS fix until ``gps_fix_delay`` seconds after start and while withheld: GPS_RAW_INT
  then has fix_type 0 and lat/lon 0; with a fix, fix_type 3 at the home position.
* COMMAND_LONG / COMMAND_INT addressed to this system (target_system 0 or ``sysid``) get
  a COMMAND_ACK. Refusals use MAV_RESULT_FAILED, which is what ArduCopter returns when its
  checks fail: arming without a fix ("PreArm: Need 3D Fix") or in AUTO/RTL/LAND, disarming
  in flight without the force magic, entering a position mode (GUIDED, LOITER, RTL, AUTO...)
  without a fix, NAV_TAKEOFF unless armed, in GUIDED and on the ground. Commands the model
  does not simulate are ACCEPTED (lenient, so a node's housekeeping never stalls).
* SET_MODE is answered with a COMMAND_ACK whose command is 11 (the SET_MODE message id),
  as ArduPilot does.
* After an accepted takeoff the vehicle climbs at ``climb_rate`` to the requested altitude;
  in RTL or LAND it descends at ``descent_rate`` and disarms on touching down.
* The mission protocol as ArduCopter 4.x answers it (``vehicle.mission``) and AUTO flying
  the stored mission (``vehicle.flight``); every request (command, SET_MODE, mission
  message) is recorded as a ``request`` event with the answer and why.
* Every received frame is recorded (``frames()``), plus events (``events()``) and probe
  counts (see ``vehicle.probe``).
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from .codec import MAVLinkMessage, frame_version
from .flight import AutoMission, move_towards
from .mission import MissionProtocol, command_name, result_name
from .mission_messages import MissionMessages
from .probe import probe_token
from .records import (
    ACCEPTED_RESULT,
    AUTO,
    COPTER_MODE_NAMES,
    DENIED_RESULT,
    GUIDED,
    GUIDED_FLAG_MODES,
    LAND,
    NO_ARM_MODES,
    POSITION_MODES,
    RTL,
    STABILIZE,
    Event,
    Frame,
    mode_name,
)

#: MAV_CMD_COMPONENT_ARM_DISARM param2 values that skip ArduPilot's checks.
FORCE_ARM_MAGIC = 2989.0
FORCE_DISARM_MAGIC = 21196.0
#: SET_MODE's message id, used by ArduPilot as the "command" of its COMMAND_ACK.
SET_MODE_ACK_COMMAND = 11
#: Result used where ArduCopter refuses a command (its checks failing give FAILED).
REFUSED = mav.MAV_RESULT_FAILED
#: Why a mode change without MAV_MODE_FLAG_CUSTOM_MODE_ENABLED is refused (ArduPilot maps
#: only custom modes).
NO_CUSTOM_FLAG = "base_mode lacks MAV_MODE_FLAG_CUSTOM_MODE_ENABLED (only custom modes are accepted)"
#: Commands that are mode changes: MAV_CMD -> (request name, the mode it enters).
_MODE_COMMANDS: dict[int, tuple[str, int]] = {
    mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: ("rtl", RTL),
    mav.MAV_CMD_NAV_LAND: ("land", LAND),
    mav.MAV_CMD_MISSION_START: ("mission_start", AUTO),
}

_SENSORS = (
    mav.MAV_SYS_STATUS_SENSOR_3D_GYRO
    | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mav.MAV_SYS_STATUS_SENSOR_3D_MAG
    | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mav.MAV_SYS_STATUS_SENSOR_GPS
)


@dataclass
class VehicleConfig:
    """Tunables of the simulated vehicle (times in seconds, rates in m/s or Hz)."""

    sysid: int = 1
    compid: int = mav.MAV_COMP_ID_AUTOPILOT1
    home_lat: float = 35.771332
    home_lon: float = -78.674421
    #: Home altitude above mean sea level; VFR_HUD.alt and GLOBAL_POSITION_INT.alt are AMSL
    #: as in ArduCopter, so with the default 0 they equal the relative altitude.
    home_alt: float = 0.0
    gps_fix_delay: float = 0.0
    fix_withheld: bool = False
    climb_rate: float = 20.0
    descent_rate: float = 20.0
    telemetry_hz: float = 4.0
    heartbeat_hz: float = 1.0
    #: Frames and events kept (oldest dropped beyond this); probe counts are never dropped.
    max_records: int = 100_000
    #: Ask for mission items with MISSION_REQUEST_INT (True) or, as ArduCopter 4.x does,
    #: MISSION_REQUEST (False); see ``vehicle.mission``.
    mission_request_int: bool = False
    #: Horizontal speed towards a waypoint or home, m/s (ArduCopter's WPNAV_SPEED is 5).
    horizontal_speed: float = 50.0

    def __post_init__(self) -> None:
        if not (1 <= self.sysid <= 255 and 0 <= self.compid <= 255):
            raise ValueError("sysid must be 1..255 and compid 0..255")
        for name in ("climb_rate", "descent_rate", "telemetry_hz", "heartbeat_hz",
                     "horizontal_speed"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number: {value}")
        if not (math.isfinite(self.gps_fix_delay) and self.gps_fix_delay >= 0):
            raise ValueError(f"gps_fix_delay must be >= 0: {self.gps_fix_delay}")
        if not (-90 <= self.home_lat <= 90 and -180 <= self.home_lon <= 180):
            raise ValueError("home position out of range")
        if self.max_records < 1:
            raise ValueError("max_records must be >= 1")


class VehicleModel(MissionMessages):
    """The autopilot's behaviour and the observation log; not thread-safe on its own."""

    def __init__(self, config: VehicleConfig | None = None, *, now: float = 0.0) -> None:
        self.config = config or VehicleConfig()
        cfg = self.config
        self._t0 = now
        self._last = now
        self.armed = False
        self.custom_mode = STABILIZE
        self.altitude = 0.0  # metres above home
        self._target_alt: float | None = None
        self._withheld = cfg.fix_withheld
        self._fix_at = now + cfg.gps_fix_delay
        self._fix_controlled = False
        self._reported_fix: bool | None = None
        self._next_hb = now
        self._next_tel = now
        self.lat, self.lon = cfg.home_lat, cfg.home_lon
        self._target_pos: tuple[float, float] | None = None
        self.missions = MissionProtocol(
            lambda: (cfg.home_lat, cfg.home_lon, cfg.home_alt),
            lambda: self.armed and self.custom_mode == AUTO,
            request_int=cfg.mission_request_int)
        self._auto = AutoMission(self)
        #: Messages due outside a reply: (conn, message), conn 0 meaning every peer.
        self._outbox: list[tuple[int, MAVLinkMessage]] = []
        self.params: dict[str, float] = {
            "SYSID_THISMAV": float(cfg.sysid),
            "ARMING_CHECK": 1.0,
            "FRAME_CLASS": 1.0,
            "RTL_ALT": 1500.0,
            "WPNAV_SPEED": 500.0,
            "DISARM_DELAY": 10.0,
        }
        self._events: deque[Event] = deque(maxlen=cfg.max_records)
        self._frames: deque[Frame] = deque(maxlen=cfg.max_records)
        self._first: dict[str, float] = {}
        self._probes: Counter[str] = Counter()
        self.rtl_commanded = False
        #: Called with every recorded event (the server uses it for ``on_event``).
        self.listener: Callable[[Event], None] | None = None
        self._why = ""  # the reason of the answer being built (see ``_why_of``)
        self._conn = 0  # the connection of the message being handled

    # ------------------------------------------------------------------ observation
    @property
    def mode(self) -> str:
        """The current ArduCopter mode name, e.g. ``"GUIDED"``."""
        return mode_name(self.custom_mode)

    def has_fix(self, now: float) -> bool:
        """Whether the GPS reports a 3D fix at ``now``."""
        return not self._withheld and now >= self._fix_at

    def withhold_fix(self, now: float, duration: float | None = None) -> None:
        """Report no fix from ``now``: until ``give_fix`` or, if given, for ``duration`` s."""
        self._fix_controlled = True
        if duration is None:
            self._withheld = True
            return
        if not (math.isfinite(duration) and duration >= 0):
            raise ValueError(f"duration must be >= 0: {duration}")
        self._withheld = False
        self._fix_at = now + duration

    def give_fix(self, now: float) -> None:
        """Report a fix from now on (cancels any remaining ``gps_fix_delay``)."""
        self._withheld = False
        self._fix_at = min(self._fix_at, now)
        self._fix_controlled = True

    def restart_fix_clock(self, now: float) -> None:
        """Count ``gps_fix_delay`` from ``now`` unless the fix was already controlled."""
        if not self._fix_controlled:
            self._fix_at = now + self.config.gps_fix_delay

    def record(self, now: float, kind: str, **detail: Any) -> Event:
        """Append an event (also used by the server for connect/disconnect)."""
        event = Event(now, kind, detail)
        self._events.append(event)
        self._first.setdefault(kind, now)
        if self.listener is not None:
            self.listener(event)
        return event

    def events(self, kind: str | None = None) -> list[Event]:
        """Recorded events in order, optionally only those of ``kind``."""
        if kind is None:
            return list(self._events)
        return [e for e in self._events if e.kind == kind]

    def frames(self, msg_type: str | None = None) -> list[Frame]:
        """Received frames in order, optionally only those of ``msg_type``."""
        if msg_type is None:
            return list(self._frames)
        return [f for f in self._frames if f.msg_type == msg_type]

    def first_time(self, kind: str) -> float | None:
        """When the first event of ``kind`` was recorded (since the last reset)."""
        return self._first.get(kind)

    def probe_count(self, token: str) -> int:
        """How many probe frames carrying ``token`` were received."""
        return self._probes.get(token, 0)

    def probe_tokens(self) -> dict[str, int]:
        """Every probe token received, with its count."""
        return dict(self._probes)

    def reset_observations(self) -> None:
        """Forget events, frames, probe counts and ``rtl_commanded`` (not vehicle state)."""
        self._events.clear()
        self._frames.clear()
        self._first.clear()
        self._probes.clear()
        self.rtl_commanded = False

    def record_bad_data(self, now: float, nbytes: int, reason: str | None, conn: int = 0) -> None:
        """Note ``nbytes`` of received bytes that were not a valid frame."""
        self.record(now, "bad_data", bytes=nbytes, reason=reason or "bad data", conn=conn)

    # ------------------------------------------------------------------ time
    def next_deadline(self) -> float:
        """The earliest time at which ``tick`` has telemetry to send."""
        return min(self._next_hb, self._next_tel)

    def tick(self, now: float) -> list[MAVLinkMessage]:
        """Advance the simulation to ``now``; return the telemetry that is due."""
        self._advance(now)
        out: list[MAVLinkMessage] = []
        if now >= self._next_hb:
            out.append(self._heartbeat())
            self._next_hb = _reschedule(self._next_hb, 1.0 / self.config.heartbeat_hz, now)
        if now >= self._next_tel:
            out.extend(self._telemetry(now))
            self._next_tel = _reschedule(self._next_tel, 1.0 / self.config.telemetry_hz, now)
        conn, due, why = self.missions.update(now)
        for msg in due:
            self.broadcast(msg, conn)
        if why is not None:  # the upload's final answer: cancelled
            code = mav.MAV_MISSION_OPERATION_CANCELLED
            self.record(now, "request", request="mission_upload", result=DENIED_RESULT,
                        reason=f"Mission upload timeout: {why}", via="timeout", command=None,
                        name="MISSION_COUNT", mav_result=code,
                        answer="MISSION_ACK " + result_name(code), conn=conn)
        return out

    def snapshot(self, now: float) -> list[MAVLinkMessage]:
        """A heartbeat and one of each telemetry message, without touching the schedule."""
        self._advance(now)
        return [self._heartbeat(), *self._telemetry(now)]

    def _advance(self, now: float) -> None:
        dt = now - self._last
        if dt <= 0:
            return
        self._last = now
        if not self.armed:
            return
        if self.custom_mode == AUTO:
            self._auto.step(now, dt)
        elif self.custom_mode == RTL:
            cfg = self.config
            if self.fly_to((cfg.home_lat, cfg.home_lon), dt):
                self.descend(now, dt)
        elif self.custom_mode == LAND:
            self.descend(now, dt)
        else:
            if self._target_pos is not None and self.fly_to(self._target_pos, dt):
                self._target_pos = None
            if self._target_alt is not None and self.climb_to(now, self._target_alt, dt):
                self.record(now, "reached", alt=self.altitude)
                self._target_alt = None

    # ------------------------------------------------------------------ motion
    def fly_to(self, target: tuple[float, float], dt: float) -> bool:
        """Move towards ``target`` (lat, lon) for ``dt`` s; True once there."""
        self.lat, self.lon, arrived = move_towards(
            self.lat, self.lon, target, self.config.horizontal_speed * dt)
        return arrived

    def climb_to(self, now: float, alt: float, dt: float) -> bool:
        """Climb (or descend, without landing) towards ``alt`` m for ``dt`` s; True once there."""
        if self.altitude < alt:
            self.altitude = min(alt, self.altitude + self.config.climb_rate * dt)
        elif self.altitude > alt:
            self.altitude = max(alt, self.altitude - self.config.descent_rate * dt)
        return self.altitude == alt

    def descend(self, now: float, dt: float) -> bool:
        """Descend for ``dt`` s; on touching down record ``landed`` and disarm (True)."""
        self._target_alt = None
        self.altitude = max(0.0, self.altitude - self.config.descent_rate * dt)
        if self.altitude > 0.0:
            return False
        self.land_and_disarm(now, "landed")
        return True

    def land_and_disarm(self, now: float, reason: str) -> None:
        self.record(now, "landed", mode=self.mode)
        self._disarm(now, reason)

    def broadcast(self, msg: MAVLinkMessage, conn: int = 0) -> None:
        """Queue ``msg`` for every peer (``conn`` 0) or for one connection."""
        self._outbox.append((conn, msg))

    def take_outbox(self) -> list[tuple[int, MAVLinkMessage]]:
        """Messages due outside replies and telemetry: (conn, msg), conn 0 = every peer."""
        out, self._outbox = self._outbox, []
        return out

    # ------------------------------------------------------------------ telemetry
    def _vertical_speed(self) -> float:
        if not self.armed:
            return 0.0
        if self.custom_mode in (RTL, LAND) and self.altitude > 0:
            return -self.config.descent_rate
        if self._target_alt is not None:
            return self.config.climb_rate
        return 0.0

    def _heartbeat(self) -> MAVLinkMessage:
        base = mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mav.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self.custom_mode in GUIDED_FLAG_MODES:
            base |= mav.MAV_MODE_FLAG_GUIDED_ENABLED
        if self.armed:
            base |= mav.MAV_MODE_FLAG_SAFETY_ARMED
        status = mav.MAV_STATE_ACTIVE if self.armed else mav.MAV_STATE_STANDBY
        return mav.MAVLink_heartbeat_message(
            mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, base, self.custom_mode,
            status, 3,
        )

    def _telemetry(self, now: float) -> list[MAVLinkMessage]:
        cfg = self.config
        fix = self.has_fix(now)
        if fix != self._reported_fix:
            if fix:
                self.record(now, "fix", fix_type=3)
            elif self._reported_fix is not None:
                self.record(now, "fix_lost", fix_type=0)
            self._reported_fix = fix
        boot_ms = int((now - self._t0) * 1000) & 0xFFFFFFFF
        lat = int(round(self.lat * 1e7)) if fix else 0
        lon = int(round(self.lon * 1e7)) if fix else 0
        amsl = cfg.home_alt + self.altitude
        vz = self._vertical_speed()
        health = _SENSORS if fix else _SENSORS & ~mav.MAV_SYS_STATUS_SENSOR_GPS
        return [
            mav.MAVLink_sys_status_message(
                _SENSORS, _SENSORS, health, 200, 12600, 1000 if self.armed else 50, 100,
                0, 0, 0, 0, 0, 0,
            ),
            mav.MAVLink_gps_raw_int_message(
                boot_ms * 1000, 3 if fix else 0, lat, lon, int(amsl * 1000) if fix else 0,
                121 if fix else 9999, 200 if fix else 9999, 0, 0, 10 if fix else 0,
            ),
            mav.MAVLink_global_position_int_message(
                boot_ms, lat, lon, int(amsl * 1000), int(self.altitude * 1000), 0, 0,
                int(-vz * 100), 0,
            ),
            mav.MAVLink_vfr_hud_message(
                0.0, 0.0, 0, 50 if self.armed and self.altitude > 0 else 0, amsl, vz,
            ),
            mav.MAVLink_attitude_message(boot_ms, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0),
            self.missions.current_message(),
        ]

    # ------------------------------------------------------------------ input
    def handle(
        self, msg: MAVLinkMessage, now: float, *, raw: bytes | None = None, conn: int = 0
    ) -> list[MAVLinkMessage]:
        """Record one received message and return the autopilot's replies to its sender."""
        self._advance(now)
        raw_bytes = bytes(raw if raw is not None else (msg.get_msgbuf() or b""))
        fields = msg.to_dict()
        fields.pop("mavpackettype", None)
        msg_type = msg.get_type()
        frame = Frame(
            t=now, msg_type=msg_type, msgid=msg.get_msgId(), raw=raw_bytes, fields=fields,
            srcsys=msg.get_srcSystem(), srccomp=msg.get_srcComponent(), seq=msg.get_seq(),
            version=frame_version(raw_bytes) or 2, conn=conn,
        )
        self._frames.append(frame)
        self._conn = conn
        self.record(now, "frame", type=msg_type, msgid=frame.msgid, srcsys=frame.srcsys,
                    srccomp=frame.srccomp, version=frame.version, conn=conn)
        handler = getattr(self, "_on_" + msg_type.lower(), None)
        if handler is None:
            return []
        target = fields.get("target_system")
        if target is not None and target not in (0, self.config.sysid):
            return []  # addressed to another system: ArduPilot would route, not act
        return list(handler(msg, fields, now))

    def _ack(self, msg: MAVLinkMessage, command: int, result: int) -> MAVLinkMessage:
        return mav.MAVLink_command_ack_message(
            command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )

    def _on_statustext(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        token = probe_token(f.get("text"))
        if token is not None:
            self._probes[token] += 1
            self.record(now, "probe", token=token, count=self._probes[token])
        return []

    def _on_set_mode(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        custom = int(f["custom_mode"])
        if f["base_mode"] & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            result, notes = self._set_mode(custom, now, "SET_MODE")
        else:
            result, notes = REFUSED, []
            self._why = NO_CUSTOM_FLAG
        self._command_request(now, msg, "mode", None, result, notes, mode=mode_name(custom),
                              custom_mode=custom)
        return [*notes, self._ack(msg, SET_MODE_ACK_COMMAND, result)]

    def _on_command_long(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        params = tuple(float(f[f"param{i}"]) for i in range(1, 8))
        return self._command(msg, int(f["command"]), params, now)

    def _on_command_int(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        params = (float(f["param1"]), float(f["param2"]), float(f["param3"]),
                  float(f["param4"]), float(f["x"]), float(f["y"]), float(f["z"]))
        return self._command(msg, int(f["command"]), params, now)

    def _command(
        self, msg: MAVLinkMessage, cmd: int, p: tuple[float, ...], now: float
    ) -> list[MAVLinkMessage]:
        out: list[MAVLinkMessage] = []
        result = mav.MAV_RESULT_ACCEPTED
        request: str = "command"
        extra: dict[str, Any] = {"params": list(p)}
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            result, out = self._arm_disarm(p[0], p[1], now)
            if p[0] in (0.0, 1.0):
                request = "arm" if p[0] == 1.0 else "disarm"
                extra = {"forced": p[1] == (FORCE_ARM_MAGIC if p[0] == 1.0 else FORCE_DISARM_MAGIC)}
        elif cmd == mav.MAV_CMD_DO_SET_MODE:
            request, extra = "mode", {"mode": mode_name(int(p[1])), "custom_mode": int(p[1])}
            if int(p[0]) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                result, out = self._set_mode(int(p[1]), now, "DO_SET_MODE")
            else:
                result = REFUSED
                self._why = NO_CUSTOM_FLAG
        elif cmd in _MODE_COMMANDS:
            request, mode = _MODE_COMMANDS[cmd]
            extra = {"mode": mode_name(mode), "custom_mode": mode}
            result, out = self._set_mode(mode, now, command_name(cmd)[8:])
            if cmd == mav.MAV_CMD_MISSION_START and result == mav.MAV_RESULT_ACCEPTED \
                    and not self._auto.running:
                self._auto.start_or_resume(now)
        elif cmd == mav.MAV_CMD_NAV_TAKEOFF:
            request, extra = "takeoff", {"alt": p[6]}
            result = self._takeoff(p[6], now)
        elif cmd == mav.MAV_CMD_REQUEST_MESSAGE:
            wanted = int(p[0])
            out = [m for m in self.snapshot(now) if m.get_msgId() == wanted]
        self._command_request(now, msg, request, cmd, result, out, **extra)
        self.record(now, "command", command=cmd, name=command_name(cmd), params=p, result=result,
                    srcsys=msg.get_srcSystem())
        return [*out, self._ack(msg, cmd, result)]

    def _command_request(self, now: float, msg: MAVLinkMessage, request: str,
                         command: int | None, result: int, out: list[MAVLinkMessage],
                         **extra: Any) -> Event:
        """Record a command or SET_MODE with its MAV_RESULT; a refusal's reason is its
        STATUSTEXT (as the autopilot says it) and what the model noted."""
        why, self._why = self._why, ""
        accepted = result == mav.MAV_RESULT_ACCEPTED
        if not accepted:
            text = next((str(m.text) for m in out if m.get_type() == "STATUSTEXT"), "")
            why = f"{text}: {why}" if text and why else (text or why)
        return self._request(now, msg, request, accepted, why, result_text(result),
                             command=command, mav_result=result, **extra)

    def _request(self, now: float, msg: MAVLinkMessage, request: str, accepted: bool,
                 reason: str | None, answer: str, *, command: int | None = None,
                 mav_result: int | None = None, **extra: Any) -> Event:
        """Record what the peer asked for and the answer it got (``records.REQUESTS``)."""
        return self.record(
            now, "request", request=request, result=ACCEPTED_RESULT if accepted else DENIED_RESULT,
            reason=None if accepted else (reason or answer), via=msg.get_type(), command=command,
            name=command_name(command) if command is not None else msg.get_type(),
            mav_result=mav_result, answer=answer, srcsys=msg.get_srcSystem(),
            srccomp=msg.get_srcComponent(), conn=self._conn, **extra)

    def _arm_disarm(self, p1: float, p2: float, now: float) -> tuple[int, list[MAVLinkMessage]]:
        if p1 == 1.0:
            if self.armed:
                return mav.MAV_RESULT_ACCEPTED, []
            if p2 != FORCE_ARM_MAGIC:
                if not self.has_fix(now):
                    return REFUSED, [_statustext(mav.MAV_SEVERITY_CRITICAL, "PreArm: Need 3D Fix")]
                if self.custom_mode in NO_ARM_MODES:
                    return REFUSED, [_statustext(mav.MAV_SEVERITY_CRITICAL,
                                                 "Arm: Mode not armable")]
            self.armed = True
            self.record(now, "arm", mode=self.mode, forced=p2 == FORCE_ARM_MAGIC)
            return mav.MAV_RESULT_ACCEPTED, []
        if p1 == 0.0:
            if not self.armed:
                return mav.MAV_RESULT_ACCEPTED, []
            if self.altitude > 0.0 and p2 != FORCE_DISARM_MAGIC:
                self._why = "Disarm: flying (needs the force value in param2)"
                return REFUSED, []
            self._disarm(now, "command")
            return mav.MAV_RESULT_ACCEPTED, []
        self._why = f"param1 {p1:g} is neither 1 (arm) nor 0 (disarm)"
        return REFUSED, []

    def _disarm(self, now: float, reason: str) -> None:
        self.armed = False
        self.altitude = 0.0
        self._target_alt = None
        self._target_pos = None
        self.record(now, "disarm", reason=reason, mode=self.mode)

    def _set_mode(self, custom: int, now: float, via: str) -> tuple[int, list[MAVLinkMessage]]:
        known = custom in COPTER_MODE_NAMES
        ok = known and (custom not in POSITION_MODES or self.has_fix(now))
        refusal = "Flight mode change failed"
        if not known:
            self._why = f"unknown mode {custom}"
        elif not ok:
            self._why = f"{mode_name(custom)} needs a position (no GPS fix)"
        elif custom == AUTO and custom != self.custom_mode:
            refusal, self._why = self._auto.refusal() or ("", "")
            ok = not refusal
        if custom == RTL:
            self.rtl_commanded = True
            self.record(now, "rtl", via=via, accepted=ok)
        if not ok:
            return REFUSED, [_statustext(mav.MAV_SEVERITY_WARNING, refusal)]
        if custom == AUTO and self.custom_mode != AUTO:
            self._auto.start_or_resume(now)
        elif custom != AUTO:
            self._auto.stop()
        if custom != self.custom_mode:
            previous = self.mode
            self.custom_mode = custom
            self.record(now, "mode", mode=self.mode, custom_mode=custom, previous=previous,
                        via=via)
        return mav.MAV_RESULT_ACCEPTED, []

    def _takeoff(self, alt: float, now: float) -> int:
        checks = (
            (self.armed, "Takeoff: not armed"),
            (self.custom_mode == GUIDED, f"Takeoff: mode {self.mode} is not GUIDED"),
            (self.altitude <= 0.0 and self._target_alt is None, "Takeoff: already flying"),
            (math.isfinite(alt) and alt > 0, f"Takeoff: bad altitude {alt}"),
        )
        failed = [why for passed, why in checks if not passed]
        ok = not failed
        self._why = failed[0] if failed else ""
        self.record(now, "takeoff", alt=alt, accepted=ok)
        if ok:
            self._target_alt = alt
        return mav.MAV_RESULT_ACCEPTED if ok else REFUSED

    # ------------------------------------------------------------------ parameters
    def _param_value(self, name: str) -> MAVLinkMessage:
        names = list(self.params)
        return mav.MAVLink_param_value_message(
            name.encode("ascii"), self.params[name], mav.MAV_PARAM_TYPE_REAL32, len(names),
            names.index(name),
        )

    def _on_param_request_list(self, msg: MAVLinkMessage, f: dict[str, Any],
                               now: float) -> Iterable:
        return [self._param_value(name) for name in self.params]

    def _on_param_request_read(self, msg: MAVLinkMessage, f: dict[str, Any],
                               now: float) -> Iterable:
        names = list(self.params)
        name = str(f.get("param_id", ""))
        if name not in self.params and 0 <= int(f["param_index"]) < len(names):
            name = names[int(f["param_index"])]
        return [self._param_value(name)] if name in self.params else []

    def _on_param_set(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        name = str(f.get("param_id", ""))
        value = float(f["param_value"])
        if not name or not math.isfinite(value):
            return []
        self.params[name] = value
        return [self._param_value(name)]



def result_text(result: int) -> str:
    """``MAV_RESULT`` name of ``result`` (e.g. ``"MAV_RESULT_FAILED"``)."""
    entry = mav.enums["MAV_RESULT"].get(result)
    return entry.name if entry is not None else str(result)


def _statustext(severity: int, text: str) -> MAVLinkMessage:
    return mav.MAVLink_statustext_message(severity, text.encode("ascii")[:50])


def _reschedule(due: float, period: float, now: float) -> float:
    """The next due time after ``due``, skipping missed slots instead of bursting."""
    nxt = due + period
    return nxt if nxt > now else now + period

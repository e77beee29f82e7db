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
* A minimal mission protocol (MISSION_COUNT / MISSION_REQUEST_INT / MISSION_ITEM[_INT] /
  MISSION_ACK, MISSION_CLEAR_ALL, download) and a small parameter table.
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
from .probe import probe_token
from .records import (
    AUTO,
    COPTER_MODE_NAMES,
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
    #: Ask for mission items with MISSION_REQUEST_INT (True) or MISSION_REQUEST (False).
    mission_request_int: bool = True

    def __post_init__(self) -> None:
        if not (1 <= self.sysid <= 255 and 0 <= self.compid <= 255):
            raise ValueError("sysid must be 1..255 and compid 0..255")
        for name in ("climb_rate", "descent_rate", "telemetry_hz", "heartbeat_hz"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0):
                raise ValueError(f"{name} must be a positive number: {value}")
        if not (math.isfinite(self.gps_fix_delay) and self.gps_fix_delay >= 0):
            raise ValueError(f"gps_fix_delay must be >= 0: {self.gps_fix_delay}")
        if not (-90 <= self.home_lat <= 90 and -180 <= self.home_lon <= 180):
            raise ValueError("home position out of range")
        if self.max_records < 1:
            raise ValueError("max_records must be >= 1")


class VehicleModel:
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
        self.mission: list[dict[str, Any]] = []
        self._upload: dict[str, Any] | None = None
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
        if self.custom_mode in (RTL, LAND):
            self._target_alt = None
            self.altitude = max(0.0, self.altitude - self.config.descent_rate * dt)
            if self.altitude <= 0.0:
                self.record(now, "landed", mode=self.mode)
                self._disarm(now, "landed")
        elif self._target_alt is not None:
            self.altitude = min(self._target_alt, self.altitude + self.config.climb_rate * dt)
            if self.altitude >= self._target_alt:
                self.record(now, "reached", alt=self.altitude)
                self._target_alt = None

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
        lat = int(round(cfg.home_lat * 1e7)) if fix else 0
        lon = int(round(cfg.home_lon * 1e7)) if fix else 0
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
        if f["base_mode"] & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            result, notes = self._set_mode(int(f["custom_mode"]), now, "SET_MODE")
        else:
            result, notes = REFUSED, []
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
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            result, out = self._arm_disarm(p[0], p[1], now)
        elif cmd == mav.MAV_CMD_DO_SET_MODE:
            if int(p[0]) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                result, out = self._set_mode(int(p[1]), now, "DO_SET_MODE")
            else:
                result = REFUSED
        elif cmd == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            result, out = self._set_mode(RTL, now, "NAV_RETURN_TO_LAUNCH")
        elif cmd == mav.MAV_CMD_NAV_LAND:
            result, out = self._set_mode(LAND, now, "NAV_LAND")
        elif cmd == mav.MAV_CMD_NAV_TAKEOFF:
            result = self._takeoff(p[6], now)
        elif cmd == mav.MAV_CMD_MISSION_START:
            result, out = self._set_mode(AUTO, now, "MISSION_START")
        elif cmd == mav.MAV_CMD_REQUEST_MESSAGE:
            wanted = int(p[0])
            out = [m for m in self.snapshot(now) if m.get_msgId() == wanted]
        name = mav.enums["MAV_CMD"][cmd].name if cmd in mav.enums["MAV_CMD"] else str(cmd)
        self.record(now, "command", command=cmd, name=name, params=p, result=result,
                    srcsys=msg.get_srcSystem())
        return [*out, self._ack(msg, cmd, result)]

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
                return REFUSED, []
            self._disarm(now, "command")
            return mav.MAV_RESULT_ACCEPTED, []
        return REFUSED, []

    def _disarm(self, now: float, reason: str) -> None:
        self.armed = False
        self.altitude = 0.0
        self._target_alt = None
        self.record(now, "disarm", reason=reason, mode=self.mode)

    def _set_mode(self, custom: int, now: float, via: str) -> tuple[int, list[MAVLinkMessage]]:
        known = custom in COPTER_MODE_NAMES
        ok = known and (custom not in POSITION_MODES or self.has_fix(now))
        if custom == RTL:
            self.rtl_commanded = True
            self.record(now, "rtl", via=via, accepted=ok)
        if not ok:
            return REFUSED, [_statustext(mav.MAV_SEVERITY_WARNING, "Flight mode change failed")]
        if custom != self.custom_mode:
            previous = self.mode
            self.custom_mode = custom
            self.record(now, "mode", mode=self.mode, custom_mode=custom, previous=previous,
                        via=via)
        return mav.MAV_RESULT_ACCEPTED, []

    def _takeoff(self, alt: float, now: float) -> int:
        ok = (
            self.armed
            and self.custom_mode == GUIDED
            and self.altitude <= 0.0
            and self._target_alt is None
            and math.isfinite(alt)
            and alt > 0
        )
        self.record(now, "takeoff", alt=alt, accepted=ok)
        if ok:
            self._target_alt = alt
        return mav.MAV_RESULT_ACCEPTED if ok else REFUSED

    # ------------------------------------------------------------------ missions
    def _on_mission_count(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        count = int(f["count"])
        if f.get("mission_type", 0) != mav.MAV_MISSION_TYPE_MISSION:
            result = mav.MAV_MISSION_ACCEPTED if count == 0 else mav.MAV_MISSION_UNSUPPORTED
            return [self._mission_ack(msg, result, f.get("mission_type", 0))]
        if count == 0:
            self.mission = []
            self._upload = None
            self.record(now, "mission", count=0)
            return [self._mission_ack(msg, mav.MAV_MISSION_ACCEPTED)]
        self._upload = {"count": count, "items": [], "src": msg.get_srcSystem()}
        return [self._mission_request(msg, 0)]

    def _on_mission_item(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        up = self._upload
        if up is None or f.get("mission_type", 0) != mav.MAV_MISSION_TYPE_MISSION:
            return []
        expected = len(up["items"])
        if int(f["seq"]) != expected:
            return [self._mission_request(msg, expected)]
        item = dict(f)
        item["type"] = msg.get_type()
        up["items"].append(item)
        if len(up["items"]) < up["count"]:
            return [self._mission_request(msg, expected + 1)]
        self.mission = up["items"]
        self._upload = None
        self.record(now, "mission", count=len(self.mission))
        return [self._mission_ack(msg, mav.MAV_MISSION_ACCEPTED)]

    _on_mission_item_int = _on_mission_item

    def _on_mission_clear_all(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        self.mission = []
        self._upload = None
        self.record(now, "mission", count=0)
        return [self._mission_ack(msg, mav.MAV_MISSION_ACCEPTED)]

    def _on_mission_request_list(self, msg: MAVLinkMessage, f: dict[str, Any],
                                 now: float) -> Iterable:
        count = len(self.mission) if f.get("mission_type", 0) == 0 else 0
        return [mav.MAVLink_mission_count_message(msg.get_srcSystem(), msg.get_srcComponent(),
                                                  count, f.get("mission_type", 0))]

    def _on_mission_request_int(self, msg: MAVLinkMessage, f: dict[str, Any],
                                now: float) -> Iterable:
        seq = int(f["seq"])
        if f.get("mission_type", 0) != 0 or not 0 <= seq < len(self.mission):
            return [self._mission_ack(msg, mav.MAV_MISSION_INVALID_SEQUENCE)]
        it = self.mission[seq]
        x, y = it["x"], it["y"]
        want_int = msg.get_type() == "MISSION_REQUEST_INT"
        if want_int and it["type"] == "MISSION_ITEM":
            x, y = int(round(x * 1e7)), int(round(y * 1e7))
        elif not want_int and it["type"] == "MISSION_ITEM_INT":
            x, y = x / 1e7, y / 1e7
        cls = mav.MAVLink_mission_item_int_message if want_int else mav.MAVLink_mission_item_message
        return [cls(msg.get_srcSystem(), msg.get_srcComponent(), seq, it["frame"], it["command"],
                    it["current"], it["autocontinue"], it["param1"], it["param2"], it["param3"],
                    it["param4"], x, y, it["z"], 0)]

    _on_mission_request = _on_mission_request_int

    def _mission_request(self, msg: MAVLinkMessage, seq: int) -> MAVLinkMessage:
        cls = (mav.MAVLink_mission_request_int_message if self.config.mission_request_int
               else mav.MAVLink_mission_request_message)
        return cls(msg.get_srcSystem(), msg.get_srcComponent(), seq, 0)

    def _mission_ack(self, msg: MAVLinkMessage, result: int, mission_type: int = 0) -> MAVLinkMessage:
        return mav.MAVLink_mission_ack_message(msg.get_srcSystem(), msg.get_srcComponent(),
                                               result, mission_type)

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



def _statustext(severity: int, text: str) -> MAVLinkMessage:
    return mav.MAVLink_statustext_message(severity, text.encode("ascii")[:50])


def _reschedule(due: float, period: float, now: float) -> float:
    """The next due time after ``due``, skipping missed slots instead of bursting."""
    nxt = due + period
    return nxt if nxt > now else now + period

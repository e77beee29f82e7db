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
* COMMAND_LONG / COMMAND_INT addressed to this system (target_system 0 or ``sysid``) and
  to this component (target_component 0 or ``compid``) get a COMMAND_ACK; a message for
  another component of the system is not acted on (mavlink.io's routing, MAV-CMD-14;
  ArduPilot 4.x's ``MAVLink_routing`` processes it locally when nothing took it). Refusals use MAV_RESULT_FAILED, which is what ArduCopter returns when its
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
* Every received frame is recorded (``frames()``), plus events (``events()``), probe
  counts (see ``vehicle.probe``) and the received bytes that did not parse as a frame
  (``unparsed()``: an altered passthrough frame, MCP-PAY-8).

The commands, modes and parameters are handled by the ``vehicle.commands`` mixin, the
mission protocol's messages by ``vehicle.mission_messages``; this module owns the state,
time, motion, telemetry and the dispatch of what arrives.
"""

from __future__ import annotations

import math
from collections import Counter, deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from .codec import MAVLinkMessage, frame_version
from .commands import CommandMessages
from .flight import METRES_PER_DEGREE, AutoMission, move_towards
from .guided import GuidedMessages
from .mission import MissionProtocol, result_name
from .mission_messages import MissionMessages
from .params import ParamMessages, ParamTable, copter_parameters
from .records import (
    AUTO,
    DENIED_RESULT,
    GUIDED,
    GUIDED_FLAG_MODES,
    LAND,
    MAX_UNPARSED,
    MAX_UNPARSED_BYTES,
    RTL,
    STABILIZE,
    Event,
    Frame,
    Unparsed,
    mode_name,
)
from .telemetry import (
    FIRMWARE_VERSION,
    HOME_INTERVAL,
    ON_REQUEST,
    STREAMED,
    Streams,
    autopilot_version,
    ekf_status_report,
    home_position,
    sys_status,
)


@dataclass
class VehicleConfig:
    """Tunables of the simulated vehicle (times in seconds, rates in m/s or Hz)."""

    sysid: int = 1
    compid: int = mav.MAV_COMP_ID_AUTOPILOT1
    home_lat: float = 35.771332
    home_lon: float = -78.674421
    #: Home altitude above mean sea level, metres; VFR_HUD.alt, GLOBAL_POSITION_INT.alt and
    #: HOME_POSITION.altitude are AMSL as in ArduCopter. The default is the ground's height
    #: at the default home (Raleigh, NC): not 0, because dronekit leaves
    #: ``location.global_frame`` at (None, None, None) until it sees a non-zero AMSL altitude
    #: (``dronekit/locations.py``: "Require first alt value to be non-0").
    home_alt: float = 96.0
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


class VehicleModel(MissionMessages, CommandMessages, ParamMessages, GuidedMessages):
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
        self.home_set = False
        rate = 1.0 / cfg.telemetry_hz
        defaults = {mav.MAVLINK_MSG_ID_HEARTBEAT: 1.0 / cfg.heartbeat_hz,
                    **dict.fromkeys(STREAMED, rate),
                    mav.MAVLINK_MSG_ID_HOME_POSITION: HOME_INTERVAL,
                    **{m: 0.0 for m in ON_REQUEST if m != mav.MAVLINK_MSG_ID_HEARTBEAT}}
        self.streams = Streams(defaults, now)
        #: Velocity north, east, down (m/s) over the last step of the simulation.
        self.velocity = (0.0, 0.0, 0.0)
        self.yaw = 0.0  # radians, 0 = north
        self.init_guided()
        self.lat, self.lon = cfg.home_lat, cfg.home_lon
        self._target_pos: tuple[float, float] | None = None
        self.missions = MissionProtocol(
            lambda: (cfg.home_lat, cfg.home_lon, cfg.home_alt),
            lambda: self.armed and self.custom_mode == AUTO,
            request_int=cfg.mission_request_int)
        self._auto = AutoMission(self)
        #: Messages due outside a reply: (conn, message), conn 0 meaning every peer.
        self._outbox: list[tuple[int, MAVLinkMessage]] = []
        self.params = ParamTable(copter_parameters(cfg.sysid))
        self._events: deque[Event] = deque(maxlen=cfg.max_records)
        self._frames: deque[Frame] = deque(maxlen=cfg.max_records)
        self._unparsed: deque[Unparsed] = deque(maxlen=MAX_UNPARSED)
        self._first: dict[str, float] = {}
        self._probes: Counter[str] = Counter()
        self.rtl_commanded = False
        #: Called with every recorded event (the server uses it for ``on_event``).
        self.listener: Callable[[Event], None] | None = None
        self._why = ""  # the reason of the answer being built (see ``_why_of``)
        self._busy: str | None = None  # what ``pending_action`` last showed ("busy"/"idle" events)
        self._conn = 0  # the connection of the message being handled

    # ------------------------------------------------------------------ observation
    @property
    def mode(self) -> str:
        """The current ArduCopter mode name, e.g. ``"GUIDED"``."""
        return mode_name(self.custom_mode)

    def pending_action(self) -> str | None:
        """What the vehicle is still carrying out of an earlier command, as a node that waits
        for it would see it (MCP-BLK-7's "pending actions", a busy node of D-6): a take-off not
        yet at its altitude, or an AUTO mission still flying its items; None when neither."""
        if not self.armed:
            return None
        if self.taking_off and self._target_alt is not None and self.custom_mode == GUIDED:
            return f"a take-off to {self._target_alt:g} m, at {self.altitude:.1f} m"
        if self.custom_mode == AUTO and self._auto.running:
            return f"an AUTO mission, at item {self._auto.index} of {max(len(self.missions.items) - 1, 0)}"
        return None

    def _note_pending(self, now: float) -> None:
        """Record when :meth:`pending_action` starts showing something in progress ("busy",
        detail: what) and when it stops ("idle"): the record from which a monitor, live or from
        a capture, judges MCP-BLK-7's "finishes pending actions, then commands RTL" as the case
        does from :meth:`pending_action` itself (one judge)."""
        busy = self.pending_action()
        if (busy is None) != (self._busy is None):
            self.record(now, "busy" if busy is not None else "idle", action=busy or self._busy)
        self._busy = busy

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

    def unparsed(self, since: float | None = None) -> list[Unparsed]:
        """Received bytes that did not parse as a MAVLink frame (MCP-PAY-8: an altered
        passthrough frame arrives as such), whose first byte arrived at ``since`` or later;
        the last ``MAX_UNPARSED`` are kept."""
        return [u for u in self._unparsed if since is None or u.t >= since]

    def record_unparsed(self, now: float, t: float, raw: bytes, reason: str, conn: int = 0) -> Unparsed:
        """Keep bytes received at ``t`` that did not parse (known not to at ``now``)."""
        u = Unparsed(t=t, raw=bytes(raw[:MAX_UNPARSED_BYTES]), reason=reason, length=len(raw),
                     conn=conn, seen=now)
        self._unparsed.append(u)
        return u

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
        """Forget events, frames, unparsed bytes, probe counts and ``rtl_commanded`` (not
        vehicle state)."""
        self._events.clear()
        self._frames.clear()
        self._unparsed.clear()
        self._first.clear()
        self._probes.clear()
        self.rtl_commanded = False

    def record_bad_data(self, now: float, nbytes: int, reason: str | None, conn: int = 0) -> None:
        """Note ``nbytes`` of received bytes that were not a valid frame."""
        self.record(now, "bad_data", bytes=nbytes, reason=reason or "bad data", conn=conn)

    # ------------------------------------------------------------------ time
    def next_deadline(self) -> float:
        """The earliest time at which ``tick`` has telemetry to send."""
        return self.streams.next_deadline()

    def tick(self, now: float) -> list[MAVLinkMessage]:
        """Advance the simulation to ``now``; return the telemetry that is due."""
        self._advance(now)
        self._note_pending(now)
        self._update_home(now)
        out = [m for m in (self.message(i, now) for i in self.streams.due(now)) if m is not None]
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
        """A heartbeat and one of each streamed message, without touching the schedule."""
        self._advance(now)
        self._update_home(now)
        ids = (mav.MAVLINK_MSG_ID_HEARTBEAT, *STREAMED)
        return [m for m in (self.message(i, now) for i in ids) if m is not None]

    def _update_home(self, now: float) -> None:
        """Home is set at the first fix, and ArduPilot then sends HOME_POSITION unasked
        (``AP_AHRS::set_home``)."""
        if not self.home_set and self.has_fix(now):
            self.home_set = True
            home = self.message(mav.MAVLINK_MSG_ID_HOME_POSITION, now)
            if home is not None:
                self.broadcast(home)

    def _advance(self, now: float) -> None:
        dt = now - self._last
        if dt <= 0:
            return
        self._last = now
        if not self.armed:
            self.velocity = (0.0, 0.0, 0.0)
            return
        before = (self.lat, self.lon, self.altitude)
        self._fly(now, dt)
        north = (self.lat - before[0]) * METRES_PER_DEGREE
        east = (self.lon - before[1]) * METRES_PER_DEGREE * math.cos(math.radians(self.lat))
        self.velocity = (north / dt, east / dt, -(self.altitude - before[2]) / dt)

    def _fly(self, now: float, dt: float) -> None:
        if self.custom_mode == AUTO:
            self._auto.step(now, dt)
        elif self.custom_mode == RTL:
            cfg = self.config
            if self.fly_to((cfg.home_lat, cfg.home_lon), dt):
                self.descend(now, dt)
        elif self.custom_mode == LAND:
            self.descend(now, dt)
        else:
            if self.custom_mode == GUIDED:
                self.guided_step(now, dt)
            if self._target_pos is not None and self.fly_to(self._target_pos, dt):
                self._target_pos = None
            if self._target_alt is not None and self.climb_to(now, self._target_alt, dt):
                self.record(now, "reached", alt=self.altitude)
                self._target_alt = None
                self.taking_off = False

    # ------------------------------------------------------------------ motion
    def fly_to(self, target: tuple[float, float], dt: float) -> bool:
        """Move towards ``target`` (lat, lon) for ``dt`` s; True once there."""
        self.lat, self.lon, arrived = move_towards(
            self.lat, self.lon, target, (self.speed_xy or self.config.horizontal_speed) * dt)
        return arrived

    def climb_to(self, now: float, alt: float, dt: float) -> bool:
        """Climb (or descend, without landing) towards ``alt`` m for ``dt`` s; True once there."""
        up = self.speed_up or self.config.climb_rate
        down = self.speed_down or self.config.descent_rate
        if self.altitude < alt:
            self.altitude = min(alt, self.altitude + up * dt)
        elif self.altitude > alt:
            self.altitude = max(alt, self.altitude - down * dt)
        return self.altitude == alt

    def descend(self, now: float, dt: float) -> bool:
        """Descend for ``dt`` s; on touching down record ``landed`` and disarm (True)."""
        self._target_alt = None
        self.altitude = max(0.0, self.altitude - (self.speed_down or self.config.descent_rate) * dt)
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
    def banner(self) -> list[MAVLinkMessage]:
        """The STATUSTEXTs ArduPilot sends before a parameter list (``send_banner``)."""
        version = ".".join(map(str, FIRMWARE_VERSION))
        return [_text(f"ArduCopter V{version} (simulated)"), _text("Frame: QUAD/X")]

    def landed_state(self) -> int:
        """MAV_LANDED_STATE as ``GCS_MAVLINK_Copter::landed_state`` reports it."""
        if not self.armed or self.altitude <= 0.0 and self._target_alt is None:
            return mav.MAV_LANDED_STATE_ON_GROUND
        if self.custom_mode in (RTL, LAND) and self.velocity[2] > 0 or self.landing:
            return mav.MAV_LANDED_STATE_LANDING
        if self.taking_off:
            return mav.MAV_LANDED_STATE_TAKEOFF
        return mav.MAV_LANDED_STATE_IN_AIR

    def message(self, msgid: int, now: float) -> MAVLinkMessage | None:
        """The message ``msgid`` as the vehicle would send it now (None: nothing to send,
        or not a message it sends)."""
        cfg = self.config
        fix = self.has_fix(now)
        if msgid == mav.MAVLINK_MSG_ID_GPS_RAW_INT:  # the first report of a fix (or its loss)
            self._note_fix(now, fix)
        boot_ms = int((now - self._t0) * 1000) & 0xFFFFFFFF
        lat = int(round(self.lat * 1e7)) if fix else 0
        lon = int(round(self.lon * 1e7)) if fix else 0
        amsl = cfg.home_alt + self.altitude
        vn, ve, vd = self.velocity
        heading = int(round(math.degrees(self.yaw))) % 360
        speed = math.hypot(vn, ve)
        builders: dict[int, Callable[[], MAVLinkMessage | None]] = {
            mav.MAVLINK_MSG_ID_HEARTBEAT: self._heartbeat,
            mav.MAVLINK_MSG_ID_SYS_STATUS: lambda: sys_status(
                fix, self.armed, self.params["FENCE_ENABLE"] != 0),
            mav.MAVLINK_MSG_ID_GPS_RAW_INT: lambda: mav.MAVLink_gps_raw_int_message(
                boot_ms * 1000, 3 if fix else 0, lat, lon, int(amsl * 1000) if fix else 0,
                121 if fix else 9999, 200 if fix else 9999, round(speed * 100) if fix else 0,
                heading * 100 if fix else 65535, 10 if fix else 0),
            mav.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: lambda: mav.MAVLink_global_position_int_message(
                boot_ms, lat, lon, round(amsl * 1000), round(self.altitude * 1000),
                round(vn * 100), round(ve * 100), round(vd * 100), heading * 100),
            mav.MAVLINK_MSG_ID_LOCAL_POSITION_NED: lambda: None if not self.home_set else (
                mav.MAVLink_local_position_ned_message(
                    boot_ms, (self.lat - cfg.home_lat) * METRES_PER_DEGREE,
                    (self.lon - cfg.home_lon) * METRES_PER_DEGREE
                    * math.cos(math.radians(cfg.home_lat)), -self.altitude, vn, ve, vd)),
            mav.MAVLINK_MSG_ID_VFR_HUD: lambda: mav.MAVLink_vfr_hud_message(
                speed, speed, heading, 50 if self.armed and self.altitude > 0 else 0, amsl, -vd),
            mav.MAVLINK_MSG_ID_ATTITUDE: lambda: mav.MAVLink_attitude_message(
                boot_ms, 0.0, 0.0, _wrap_pi(self.yaw), 0.0, 0.0, 0.0),
            mav.MAVLINK_MSG_ID_MISSION_CURRENT: self.missions.current_message,
            mav.MAVLINK_MSG_ID_EKF_STATUS_REPORT: lambda: ekf_status_report(fix),
            mav.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: lambda: mav.MAVLink_extended_sys_state_message(
                mav.MAV_VTOL_STATE_UNDEFINED, self.landed_state()),
            mav.MAVLINK_MSG_ID_HOME_POSITION: lambda: home_position(
                cfg.home_lat, cfg.home_lon, cfg.home_alt, int((now - self._t0) * 1e6))
            if self.home_set else None,
            mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION: lambda: autopilot_version(cfg.sysid),
            mav.MAVLINK_MSG_ID_POSITION_TARGET_GLOBAL_INT: lambda: self.position_target(boot_ms),
        }
        build = builders.get(msgid)
        return build() if build is not None else None

    def _note_fix(self, now: float, fix: bool) -> None:
        if fix != self._reported_fix:
            if fix:
                self.record(now, "fix", fix_type=3)
            elif self._reported_fix is not None:
                self.record(now, "fix_lost", fix_type=0)
            self._reported_fix = fix

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
        component = fields.get("target_component")
        if target == self.config.sysid and component is not None and component not in (0, self.config.compid):
            # another component of this system (a camera, a gimbal): mavlink.io's routing
            # processes a message locally only for a matching system and component, or a
            # broadcast (https://mavlink.io/en/guide/routing.html; MAV-CMD-14)
            return []
        replies = list(handler(msg, fields, now))
        self._note_pending(now)
        return replies


def _wrap_pi(angle: float) -> float:
    return (angle + math.pi) % (2 * math.pi) - math.pi


def _text(text: str) -> MAVLinkMessage:
    return mav.MAVLink_statustext_message(mav.MAV_SEVERITY_INFO, text.encode("ascii")[:50])

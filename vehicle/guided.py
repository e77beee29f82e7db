"""GUIDED flight from a companion computer, as ArduCopter 4.x flies it (sans-I/O mixin).

The messages and commands (``ArduCopter/GCS_Mavlink.cpp``; mavlink.io "Offboard Control
Interface" / SET_POSITION_TARGET_*):

* SET_POSITION_TARGET_LOCAL_NED and SET_POSITION_TARGET_GLOBAL_INT are acted on only in
  GUIDED (``in_guided_mode``); otherwise ignored, as ArduCopter ignores them (they have no
  answer), but recorded. ``type_mask`` as ArduCopter reads it: position used unless any of
  the X/Y/Z ignore bits is set, likewise velocity and acceleration; position alone flies
  there, velocity alone flies at it (stopping after GUID_TIMEOUT s without a new one,
  ``ModeGuided``'s velocity timeout), position and velocity go to the position; any other
  mix, or a frame ArduCopter does not take, makes GUIDED hold position (``mode_guided.init``).
  Local frames: LOCAL_NED (from home), LOCAL_OFFSET_NED, BODY_NED, BODY_OFFSET_NED (rotated by
  the heading); global frames: GLOBAL[_INT] (AMSL), GLOBAL_RELATIVE_ALT[_INT]; a latitude or
  longitude out of range holds position. Yaw is taken unless YAW_IGNORE is set.
* MAV_CMD_DO_REPOSITION (``handle_command_int_do_reposition``): DENIED outside GUIDED unless
  param2 has MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, DENIED for a bad or zero position or a
  frame ArduCopter does not take; FAILED when GUIDED cannot be entered (no fix); else flies
  there (altitude NaN: the current one).
* MAV_CMD_CONDITION_YAW: param1 0..360 and param4 0 (absolute) or 1 (relative, param3 the
  direction) are ACCEPTED and turn the vehicle at once; anything else is FAILED.
* MAV_CMD_DO_CHANGE_SPEED: param2 must be positive (else FAILED); param1 0/1 sets the
  horizontal speed, 2 the climb, 3 the descent speed; FAILED outside AUTO, GUIDED and RTL
  (``Mode::set_speed_xy`` is false in other modes).

While a takeoff climbs EXTENDED_SYS_STATE says TAKEOFF; POSITION_TARGET_GLOBAL_INT reports
the GUIDED position target.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from .codec import MAVLinkMessage
from .flight import METRES_PER_DEGREE
from .records import AUTO, GUIDED, RTL

if TYPE_CHECKING:
    from .records import Event

_POS = (mav.POSITION_TARGET_TYPEMASK_X_IGNORE | mav.POSITION_TARGET_TYPEMASK_Y_IGNORE
        | mav.POSITION_TARGET_TYPEMASK_Z_IGNORE)
_VEL = (mav.POSITION_TARGET_TYPEMASK_VX_IGNORE | mav.POSITION_TARGET_TYPEMASK_VY_IGNORE
        | mav.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
_ACC = (mav.POSITION_TARGET_TYPEMASK_AX_IGNORE | mav.POSITION_TARGET_TYPEMASK_AY_IGNORE
        | mav.POSITION_TARGET_TYPEMASK_AZ_IGNORE)
_LOCAL_FRAMES = frozenset({mav.MAV_FRAME_LOCAL_NED, mav.MAV_FRAME_LOCAL_OFFSET_NED,
                           mav.MAV_FRAME_BODY_NED, mav.MAV_FRAME_BODY_OFFSET_NED})
_BODY_FRAMES = frozenset({mav.MAV_FRAME_BODY_NED, mav.MAV_FRAME_BODY_OFFSET_NED})
_AMSL_FRAMES = frozenset({mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT})
_RELATIVE_FRAMES = frozenset({mav.MAV_FRAME_GLOBAL_RELATIVE_ALT,
                              mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT})
_SPEED_MODES = frozenset({AUTO, GUIDED, RTL})


class GuidedMessages:
    """Position/velocity targets, DO_REPOSITION, CONDITION_YAW, DO_CHANGE_SPEED."""

    config: Any
    params: Any
    armed: bool
    custom_mode: int
    altitude: float
    lat: float
    lon: float
    yaw: float
    _target_pos: tuple[float, float] | None
    _target_alt: float | None
    _why: str

    if TYPE_CHECKING:
        @property
        def mode(self) -> str: ...

        def _request(self, now: float, msg: MAVLinkMessage, request: str, accepted: bool,
                     reason: str | None, answer: str, *, command: int | None = None,
                     mav_result: int | None = None, **extra: Any) -> Event: ...

        def _set_mode(self, custom: int, now: float, via: str) -> tuple[int, list]: ...

        def has_fix(self, now: float) -> bool: ...

        def fly_to(self, target: tuple[float, float], dt: float) -> bool: ...

        def climb_to(self, now: float, alt: float, dt: float) -> bool: ...

        def land_and_disarm(self, now: float, reason: str) -> None: ...

    def init_guided(self) -> None:
        #: GUIDED velocity target (north, east, down m/s) and when it stops.
        self._guided_vel: tuple[float, float, float] | None = None
        self._vel_until = 0.0
        self.taking_off = False
        self.landing = False
        #: Speeds set by DO_CHANGE_SPEED (m/s), else the config's.
        self.speed_xy: float | None = None
        self.speed_up: float | None = None
        self.speed_down: float | None = None

    # ------------------------------------------------------------------ flying
    def guided_step(self, now: float, dt: float) -> None:
        """Fly ``dt`` s of a GUIDED velocity target (positions are flown by the model)."""
        if self._guided_vel is None or self.altitude <= 0.0:
            return
        if now >= self._vel_until:
            self._guided_vel = None
            return
        vn, ve, vd = self._guided_vel
        self.lat += vn * dt / METRES_PER_DEGREE
        self.lon += ve * dt / (METRES_PER_DEGREE * max(math.cos(math.radians(self.lat)), 1e-6))
        self.altitude -= vd * dt
        if self.altitude <= 0.0:
            self.altitude = 0.0
            self._guided_vel = None
            self.land_and_disarm(now, "landed")

    def hold_position(self) -> None:
        """Stop: no target (``mode_guided.init``)."""
        self._guided_vel = None
        self._target_pos = None
        self._target_alt = None

    def position_target(self, boot_ms: int) -> MAVLinkMessage | None:
        """POSITION_TARGET_GLOBAL_INT of a GUIDED position target (None without one)."""
        if self.custom_mode != GUIDED or self._target_pos is None:
            return None
        lat, lon = self._target_pos
        alt = self._target_alt if self._target_alt is not None else self.altitude
        return mav.MAVLink_position_target_global_int_message(
            boot_ms, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, _VEL | _ACC
            | mav.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE, int(round(lat * 1e7)),
            int(round(lon * 1e7)), alt, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, self.yaw, 0.0)

    # ------------------------------------------------------------------ targets
    def _on_set_position_target_local_ned(self, msg: MAVLinkMessage, f: dict[str, Any],
                                          now: float) -> Iterable:
        frame = int(f["coordinate_frame"])
        pos = vel = None
        if frame in _LOCAL_FRAMES:
            x, y, z = float(f["x"]), float(f["y"]), float(f["z"])
            vx, vy, vz = float(f["vx"]), float(f["vy"]), float(f["vz"])
            if frame in _BODY_FRAMES:
                x, y = _rotate(x, y, self.yaw)
                vx, vy = _rotate(vx, vy, self.yaw)
            if frame == mav.MAV_FRAME_LOCAL_NED:
                cfg = self.config
                lat = cfg.home_lat + x / METRES_PER_DEGREE
                lon = cfg.home_lon + y / (METRES_PER_DEGREE * math.cos(math.radians(cfg.home_lat)))
                pos = (lat, lon, -z)
            else:
                lat = self.lat + x / METRES_PER_DEGREE
                lon = self.lon + y / (METRES_PER_DEGREE * math.cos(math.radians(self.lat)))
                pos = (lat, lon, self.altitude - z)
            vel = (vx, vy, vz)
        return self._position_target(msg, f, now, frame, pos, vel)

    def _on_set_position_target_global_int(self, msg: MAVLinkMessage, f: dict[str, Any],
                                           now: float) -> Iterable:
        frame = int(f["coordinate_frame"])
        pos = vel = None
        if frame in _AMSL_FRAMES or frame in _RELATIVE_FRAMES:
            alt = float(f["alt"])
            if frame in _AMSL_FRAMES:
                alt -= self.config.home_alt
            pos = (int(f["lat_int"]) * 1e-7, int(f["lon_int"]) * 1e-7, alt)
            vel = (float(f["vx"]), float(f["vy"]), float(f["vz"]))
        return self._position_target(msg, f, now, frame, pos, vel)

    def _position_target(self, msg: MAVLinkMessage, f: dict[str, Any], now: float, frame: int,
                         pos: tuple[float, float, float] | None,
                         vel: tuple[float, float, float] | None) -> list[MAVLinkMessage]:
        mask = int(f["type_mask"])
        use_pos, use_vel, use_acc = not mask & _POS, not mask & _VEL, not mask & _ACC
        detail: dict[str, Any] = {"frame": frame, "type_mask": mask, "position": list(pos) if pos else None,
                  "velocity": list(vel) if vel else None}
        if self.custom_mode != GUIDED:
            self._request(now, msg, "position_target", False,
                          f"mode {self.mode} is not GUIDED: ignored, as ArduCopter", "none",
                          **detail)
            return []
        why = ""
        if pos is None or vel is None:
            why = f"frame {frame} is not one ArduCopter takes"
        elif use_pos and not (-90 <= pos[0] <= 90 and -180 <= pos[1] <= 180
                              and all(math.isfinite(v) for v in pos)):
            why = f"position {pos} is out of range"
        elif use_vel and not all(math.isfinite(v) for v in vel):
            why = f"velocity {vel} is not finite"
        elif not use_pos and not use_vel:
            why = ("acceleration-only targets are not flown" if use_acc
                   else "no position, velocity or acceleration")
        if not mask & mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE and math.isfinite(float(f["yaw"])):
            self.yaw = float(f["yaw"])
        if why:
            self.hold_position()
            self._request(now, msg, "position_target", False, why + ": GUIDED holds position",
                          "none", **detail)
            return []
        assert pos is not None and vel is not None
        if use_pos:
            self._guided_vel = None
            self._target_pos = (pos[0], pos[1])
            self._target_alt = max(pos[2], 0.0)
            flown = "position"
        else:
            self._target_pos = self._target_alt = None
            self._guided_vel = vel
            self._vel_until = now + float(self.params["GUID_TIMEOUT"])
            flown = "velocity"
        note = None if self.armed and self.altitude > 0 else "on the ground: flown after takeoff"
        self._request(now, msg, "position_target", True, None, f"flying to the {flown}",
                      note=note, **detail)
        return []

    # ------------------------------------------------------------------ commands
    def _cmd_reposition(self, msg: MAVLinkMessage, p: tuple[float, ...],
                        now: float) -> tuple[int, list]:
        is_int = msg.get_type() == "COMMAND_INT"
        frame = int(msg.frame) if is_int else mav.MAV_FRAME_GLOBAL_RELATIVE_ALT
        change_mode = int(p[1]) & mav.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE if math.isfinite(
            p[1]) else 0
        lat, lon = (p[4] * 1e-7, p[5] * 1e-7) if is_int else (p[4], p[5])
        if self.custom_mode != GUIDED and not change_mode:
            self._why = f"mode {self.mode} is not GUIDED and param2 lacks CHANGE_MODE"
            return mav.MAV_RESULT_DENIED, []
        if not (math.isfinite(lat) and math.isfinite(lon) and -90 <= lat <= 90
                and -180 <= lon <= 180) or (lat == 0 and lon == 0):
            self._why = f"position ({p[4]}, {p[5]}) is not valid"
            return mav.MAV_RESULT_DENIED, []
        if frame not in _AMSL_FRAMES and frame not in _RELATIVE_FRAMES:
            self._why = f"frame {frame} is not one ArduCopter takes"
            return mav.MAV_RESULT_DENIED, []
        alt = p[6]
        if not math.isfinite(alt):
            alt = self.altitude
        elif frame in _AMSL_FRAMES:
            alt -= self.config.home_alt
        if self.custom_mode != GUIDED:
            result, out = self._set_mode(GUIDED, now, "DO_REPOSITION")
            if result != mav.MAV_RESULT_ACCEPTED:
                return mav.MAV_RESULT_FAILED, out
        self._guided_vel = None
        self._target_pos = (lat, lon)
        self._target_alt = max(alt, 0.0)
        return mav.MAV_RESULT_ACCEPTED, []

    def _cmd_condition_yaw(self, p: tuple[float, ...]) -> int:
        angle, direction, relative = p[0], p[2], p[3]
        if not (0.0 <= angle <= 360.0 and relative in (0.0, 1.0)):
            self._why = f"angle {angle:g} not in 0..360 or param4 {relative:g} not 0/1"
            return mav.MAV_RESULT_FAILED
        if relative:
            sign = -1.0 if direction < 0 else 1.0
            self.yaw += sign * math.radians(angle)
        else:
            self.yaw = math.radians(angle)
        self.yaw %= 2 * math.pi
        return mav.MAV_RESULT_ACCEPTED

    def _cmd_change_speed(self, p: tuple[float, ...]) -> int:
        kind, speed = p[0], p[1]
        if not (math.isfinite(speed) and speed > 0):
            self._why = f"speed {speed:g} is not positive"
            return mav.MAV_RESULT_FAILED
        if kind not in (0.0, 1.0, 2.0, 3.0):
            self._why = f"speed type {kind:g} is not 0..3"
            return mav.MAV_RESULT_FAILED
        if self.custom_mode not in _SPEED_MODES:
            self._why = f"mode {self.mode} does not take a speed"
            return mav.MAV_RESULT_FAILED
        if kind in (0.0, 1.0):
            self.speed_xy = speed
        elif kind == 2.0:
            self.speed_up = speed
        else:
            self.speed_down = speed
        return mav.MAV_RESULT_ACCEPTED


def _rotate(forward: float, right: float, yaw: float) -> tuple[float, float]:
    """Body frame (forward, right) to (north, east) for heading ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    return forward * c - right * s, forward * s + right * c

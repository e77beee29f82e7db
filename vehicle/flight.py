"""Flying the stored mission in AUTO, as ArduCopter's ModeAuto does it (simplified, sans-I/O).

``AutoMission`` steps through the mission of a ``VehicleModel`` (``model.missions``) while
the vehicle is armed in AUTO: NAV_TAKEOFF climbs to its altitude, NAV_WAYPOINT (and the
loiter/spline variants) flies there at ``horizontal_speed`` and the climb/descent rates,
NAV_RETURN_TO_LAUNCH flies home and lands, NAV_LAND lands (at its position if it has one);
DO_JUMP jumps its repeat count; other DO_/CONDITION_ commands complete at once. Each
command announces itself with STATUSTEXT "Mission: <n> <name>" when it starts and
MISSION_ITEM_REACHED when it completes (``ModeAuto::verify_command``); MISSION_CURRENT
follows. At the end of the mission the vehicle holds position in AUTO (``exit_mission``'s
loiter) or, landed, disarms.

Entering AUTO needs a mission (more than the home item) and, armed on the ground, a
NAV_TAKEOFF first ("Auto: Missing Takeoff Cmd"), as ``ModeAuto::init`` checks.
"""

from __future__ import annotations

import math
from typing import Any, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mav


class Airframe(Protocol):
    """What flying a mission needs of the vehicle (``vehicle.model.VehicleModel`` has it):
    its state, its stored mission, and the moves and records it makes."""

    config: Any
    missions: Any
    lat: float
    lon: float
    altitude: float
    armed: bool

    def broadcast(self, msg: Any) -> Any: ...
    def climb_to(self, *args: Any, **kwargs: Any) -> Any: ...
    def descend(self, *args: Any, **kwargs: Any) -> Any: ...
    def fly_to(self, *args: Any, **kwargs: Any) -> Any: ...
    def land_and_disarm(self, *args: Any, **kwargs: Any) -> Any: ...
    def record(self, *args: Any, **kwargs: Any) -> Any: ...

#: Metres per degree of latitude (and of longitude at the equator), WGS-84 mean.
METRES_PER_DEGREE = 111_319.5
#: How close counts as "at" a waypoint, metres (ArduCopter's WPNAV_RADIUS is 2 m).
ARRIVAL_RADIUS = 1.0

_SHORT_NAMES = {
    mav.MAV_CMD_NAV_WAYPOINT: "WP", mav.MAV_CMD_NAV_TAKEOFF: "Takeoff",
    mav.MAV_CMD_NAV_LAND: "Land", mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: "RTL",
    mav.MAV_CMD_NAV_LOITER_TIME: "LoitTime", mav.MAV_CMD_NAV_LOITER_UNLIM: "LoitUnlim",
    mav.MAV_CMD_NAV_LOITER_TURNS: "LoitTurns", mav.MAV_CMD_NAV_SPLINE_WAYPOINT: "SplineWP",
    mav.MAV_CMD_DO_JUMP: "Jump", mav.MAV_CMD_DO_CHANGE_SPEED: "ChangeSpeed",
}
_FLY_TO = frozenset({
    mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_SPLINE_WAYPOINT, mav.MAV_CMD_NAV_LOITER_TIME,
    mav.MAV_CMD_NAV_LOITER_TURNS, mav.MAV_CMD_NAV_LOITER_UNLIM,
    mav.MAV_CMD_NAV_CONTINUE_AND_CHANGE_ALT, mav.MAV_CMD_NAV_LOITER_TO_ALT,
})
#: Frames whose altitude is above mean sea level (others are relative to home).
_AMSL_FRAMES = frozenset({mav.MAV_FRAME_GLOBAL, mav.MAV_FRAME_GLOBAL_INT})


def distance_m(lat1: float, lon1: float, lat2: float, lon2: float) -> float:
    """Flat-earth distance in metres (fine over the few kilometres of a mission)."""
    north = (lat2 - lat1) * METRES_PER_DEGREE
    east = (lon2 - lon1) * METRES_PER_DEGREE * math.cos(math.radians((lat1 + lat2) / 2))
    return math.hypot(north, east)


def move_towards(lat: float, lon: float, target: tuple[float, float],
                 step_m: float) -> tuple[float, float, bool]:
    """Move up to ``step_m`` metres towards ``target``: (lat, lon, arrived)."""
    dist = distance_m(lat, lon, target[0], target[1])
    if dist <= max(step_m, ARRIVAL_RADIUS):
        return target[0], target[1], True
    frac = step_m / dist
    return lat + (target[0] - lat) * frac, lon + (target[1] - lon) * frac, False


def command_label(cmd: int) -> str:
    if cmd in _SHORT_NAMES:
        return _SHORT_NAMES[cmd]
    entry = mav.enums["MAV_CMD"].get(cmd)
    return entry.name.removeprefix("MAV_CMD_") if entry is not None else str(cmd)


class AutoMission:
    """The mission as flown in AUTO (see the module docstring)."""

    def __init__(self, model: Airframe) -> None:
        self.model = model
        self.running = False
        self.started = False
        self.complete = False
        self.index = 0
        self._begun = -1
        self._jumps: dict[int, int] = {}

    # ------------------------------------------------------------------ entry
    def refusal(self) -> tuple[str, str] | None:
        """Why AUTO cannot be entered now (``ModeAuto::init``): (STATUSTEXT, detail), or None."""
        m = self.model
        if len(m.missions.items) <= 1:  # no mission: init fails
            return "Flight mode change failed", "AUTO needs a mission (more than the home item)"
        if m.armed and m.altitude <= 0.0:
            first = m.missions.first_nav()
            if first is None or int(first["command"]) != mav.MAV_CMD_NAV_TAKEOFF:
                return "Auto: Missing Takeoff Cmd", ""
        return None

    def start_or_resume(self, now: float, restart: bool = False) -> None:
        """Run the mission: from the start when new, complete or ``restart``; else resume."""
        if restart or not self.started or self.complete or self.index >= len(self.model.missions.items):
            self.index = 1
            self._jumps.clear()
            self._begun = -1
        self.started = self.running = True
        self.complete = False
        self.model.missions.current = self.index

    def stop(self) -> None:
        self.running = False

    # ------------------------------------------------------------------ flying
    def step(self, now: float, dt: float) -> None:
        """Fly ``dt`` seconds of the mission (armed, in AUTO)."""
        m = self.model
        for _ in range(64):  # bounded: DO commands complete at once, jumps may loop
            if not (self.running and m.armed):
                return
            items = m.missions.items
            if self.index >= len(items):
                self._finish(now)
                return
            item = items[self.index]
            if self._begun != self.index:
                self._begun = self.index
                m.missions.current = self.index
                m.broadcast(_text(mav.MAV_SEVERITY_INFO,
                                  f"Mission: {self.index} {command_label(int(item['command']))}"))
            if not self._run(item, now, dt):
                return
            dt = 0.0
            self._reached(now, item)
            if self.index >= len(items):
                self._finish(now)
                return

    def _reached(self, now: float, item: dict[str, Any]) -> None:
        m = self.model
        seq, cmd = self.index, int(item["command"])
        m.broadcast(mav.MAVLink_mission_item_reached_message(seq))
        m.record(now, "item_reached", seq=seq, command=command_label(cmd))
        if cmd == mav.MAV_CMD_DO_JUMP:
            target, repeat = int(item["param1"]), int(item["param2"])
            done = self._jumps.get(seq, 0)
            if repeat < 0 or done < repeat:
                self._jumps[seq] = done + 1
                self.index = target
                return
        self.index += 1

    def _finish(self, now: float) -> None:
        m = self.model
        self.running = False
        self.complete = True
        m.record(now, "mission_complete", items=len(m.missions.items) - 1)
        if m.altitude <= 0.0 and m.armed:  # landed: disarm; flying: hold position in AUTO
            m.land_and_disarm(now, "mission complete")

    def _run(self, item: dict[str, Any], now: float, dt: float) -> bool:
        """Advance one command by ``dt``; True once it is complete."""
        m = self.model
        cmd = int(item["command"])
        if cmd == mav.MAV_CMD_NAV_TAKEOFF:
            return m.climb_to(now, max(float(item["z"]), 0.0), dt)
        if cmd in _FLY_TO:
            target = self._position(item)
            at = m.fly_to(target, dt)
            up = m.climb_to(now, self._relative_alt(item), dt)
            return at and up and cmd != mav.MAV_CMD_NAV_LOITER_UNLIM
        if cmd == mav.MAV_CMD_NAV_RETURN_TO_LAUNCH:
            cfg = m.config
            if not m.fly_to((cfg.home_lat, cfg.home_lon), dt):
                return False
            return m.descend(now, dt)
        if cmd == mav.MAV_CMD_NAV_LAND:
            if not m.fly_to(self._position(item), dt):
                return False
            return m.descend(now, dt)
        return True  # DO_/CONDITION_ commands and NAV_DELAY complete at once

    def _position(self, item: dict[str, Any]) -> tuple[float, float]:
        x, y = int(item["x"]), int(item["y"])
        if x == 0 and y == 0:  # ArduPilot: no position means "here"
            return self.model.lat, self.model.lon
        return x * 1e-7, y * 1e-7

    def _relative_alt(self, item: dict[str, Any]) -> float:
        z = float(item["z"])
        if int(item["frame"]) in _AMSL_FRAMES:
            z -= self.model.config.home_alt
        return max(z, 0.0)


def _text(severity: int, text: str) -> Any:
    return mav.MAVLink_statustext_message(severity, text.encode("ascii")[:50])

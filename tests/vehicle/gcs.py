"""A ground station session on pymavlink, as a companion application runs it against the vehicle.

``run_session(conn)``: heartbeat both ways, wait for a 3D fix, GUIDED, arm, a mission upload
with the handshake done right (answer each MISSION_REQUEST[_INT] with that item, until
MISSION_ACK), then RTL. Every wait is bounded; a step that fails raises AssertionError
naming it.
"""

from __future__ import annotations

import time
from typing import Any

from pymavlink import mavutil

MAV = mavutil.mavlink
WAIT = 5.0
#: Takeoff then two waypoints near the description's Raleigh sample (degE7).
MISSION = [
    (MAV.MAV_CMD_NAV_WAYPOINT, 357713320, -786744210, 0.0),  # item 0: home (ArduPilot)
    (MAV.MAV_CMD_NAV_TAKEOFF, 0, 0, 10.0),
    (MAV.MAV_CMD_NAV_WAYPOINT, 357711030, -786746590, 10.0),
    (MAV.MAV_CMD_NAV_WAYPOINT, 357715000, -786742000, 12.0),
]


def recv(conn: Any, types: list[str], what: str, timeout: float = WAIT,
         heartbeat: bool = True) -> Any:
    """The next message of ``types`` (a GCS heartbeat goes out each second meanwhile)."""
    deadline = time.monotonic() + timeout
    next_hb = 0.0
    while time.monotonic() < deadline:
        if heartbeat and time.monotonic() >= next_hb:
            conn.mav.heartbeat_send(MAV.MAV_TYPE_GCS, MAV.MAV_AUTOPILOT_INVALID, 0, 0,
                                    MAV.MAV_STATE_ACTIVE)
            next_hb = time.monotonic() + 1.0
        m = conn.recv_match(type=types, blocking=True, timeout=0.2)
        if m is not None and m.get_srcSystem() != conn.mav.srcSystem:
            return m
    raise AssertionError(f"no {'/'.join(types)} within {timeout:g} s: {what}")


def command_ack(conn: Any, command: int, what: str) -> int:
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        m = recv(conn, ["COMMAND_ACK"], what, deadline - time.monotonic())
        if m.command == command:
            return int(m.result)
    raise AssertionError(f"no COMMAND_ACK for {command}: {what}")


def upload_mission(conn: Any, target: tuple[int, int], mission: list = MISSION) -> int:
    """MISSION_COUNT, answer each request with its item, return the MISSION_ACK type."""
    conn.mav.mission_count_send(target[0], target[1], len(mission))
    sent = 0
    while True:
        m = recv(conn, ["MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"],
                 f"mission upload after {sent} items")
        if m.get_type() == "MISSION_ACK":
            return int(m.type)
        cmd, x, y, z = mission[m.seq]
        frame = MAV.MAV_FRAME_GLOBAL if m.seq == 0 else MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT
        conn.mav.mission_item_int_send(target[0], target[1], m.seq, frame, cmd, 0, 1,
                                       0, 0, 0, 0, x, y, z)
        sent += 1


def run_session(conn: Any) -> dict[str, Any]:
    """The whole session; returns what was observed (for the caller's asserts)."""
    hb = recv(conn, ["HEARTBEAT"], "vehicle heartbeat")
    target = (hb.get_srcSystem(), hb.get_srcComponent())
    deadline = time.monotonic() + WAIT
    while recv(conn, ["GPS_RAW_INT"], "GPS fix").fix_type < 3:
        assert time.monotonic() < deadline, "no 3D fix"
    conn.mav.set_mode_send(target[0], MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4)  # GUIDED
    mode = command_ack(conn, 11, "SET_MODE GUIDED")
    conn.mav.command_long_send(target[0], target[1], MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                               1, 0, 0, 0, 0, 0, 0)
    arm = command_ack(conn, MAV.MAV_CMD_COMPONENT_ARM_DISARM, "arm")
    mission = upload_mission(conn, target)
    conn.mav.command_long_send(target[0], target[1], MAV.MAV_CMD_NAV_RETURN_TO_LAUNCH, 0,
                               0, 0, 0, 0, 0, 0, 0)
    rtl = command_ack(conn, MAV.MAV_CMD_NAV_RETURN_TO_LAUNCH, "RTL")
    return {"target": target, "mode": mode, "arm": arm, "mission": mission, "rtl": rtl}

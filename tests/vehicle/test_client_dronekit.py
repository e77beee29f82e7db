"""DroneKit-Python (dronekit2) against the simulated vehicle, over TCP and UDP, with the idioms
of DroneKit's own examples (simple_goto.py, guided_set_speed_yaw.py): ``connect(...,
wait_ready=True)``, ``while not vehicle.is_armable``, GUIDED and ``armed = True``,
``simple_takeoff`` until the altitude, velocity by SET_POSITION_TARGET_LOCAL_NED built with
``message_factory`` (``send_ned_velocity``), a mode change. Issue 35: ``is_armable`` never
became True (no EKF_STATUS_REPORT), ``version`` was ``APM:Copter-None.None.None`` and
``capabilities`` raised (no AUTOPILOT_VERSION), ``global_frame`` stayed (None, None, None).

And the end-to-end check of hostile input (MCP-vehicle robustness, issue 35's last Done-when
line): parameter, command and mission messages no client should send, sent first with
pymavlink; DroneKit then still gets every parameter with its value.
"""

from __future__ import annotations

import math
import time

import pytest
from pymavlink import mavutil

from tests.vehicle.clients import (
    CONNECT_WAIT,
    MAV,
    TRANSPORTS,
    WAIT,
    Link,
    dronekit_vehicle,
    north_east_m,
    pymavlink_params,
    require_dronekit,
    served,
    unrecorded_requests,
    wait_until,
)

ALT = 10.0


def state(v) -> str:
    """What dronekit sees, for failure messages."""
    return (f"mode={v.mode.name} armed={v.armed} is_armable={v.is_armable} ekf_ok={v.ekf_ok} "
            f"gps={v.gps_0} frame={v.location.global_frame} "
            f"rel={v.location.global_relative_frame}")


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_wait_ready_then_armable_after_the_fix(transport: str) -> None:
    """connect(wait_ready=True) returns within a bound; is_armable is False while the fix is
    withheld and True after it; version, capabilities and global_frame are whole."""
    require_dronekit()
    home = (35.5, -78.25)  # not the default: seen from the vehicle, not assumed
    with served(transport, fix_withheld=True, home_lat=home[0], home_lon=home[1]) as (sim, link):
        t0 = time.monotonic()
        with dronekit_vehicle(link, wait_ready=True) as v:
            took = time.monotonic() - t0
            print(f"dronekit connect(wait_ready=True) over {transport}: {took:.2f} s")
            assert took < CONNECT_WAIT
            assert len(v.parameters) > 0
            # while the fix is withheld: sample a second of it
            end = time.monotonic() + 1.0
            while time.monotonic() < end:
                assert not v.is_armable, f"armable without a fix: {state(v)}"
                time.sleep(0.1)
            sim.give_fix()
            wait_until(lambda: v.is_armable, WAIT, "is_armable after the fix",
                       show=lambda: state(v))
            assert v.ekf_ok
            assert v.version.major is not None, f"vehicle.version: {v.version}"
            assert v.version.major == 4, f"not ArduCopter 4.x: {v.version}"
            assert v.version.autopilot_type == MAV.MAV_AUTOPILOT_ARDUPILOTMEGA
            caps = v.capabilities
            # ArduCopter's bits (GCS_MAVLINK::capabilities): MISSION_INT, COMMAND_INT,
            # SET_POSITION_TARGET_LOCAL_NED (dronekit's set_attitude_target_local_ned)
            assert caps.mission_int is True and caps.command_int is True
            assert caps.set_attitude_target_local_ned is True
            wait_until(lambda: None not in (v.location.global_frame.lat,
                                            v.location.global_frame.lon,
                                            v.location.global_frame.alt),
                       WAIT, "location.global_frame whole", show=lambda: state(v))
            # DroneKit's home: download the commands, then home_location (mission item 0)
            v.commands.download()
            v.commands.wait_ready(timeout=WAIT)
            got = v.home_location
            assert got is not None and got.alt is not None, f"home_location: {got}"
            assert abs(got.lat - home[0]) < 1e-5 and abs(got.lon - home[1]) < 1e-5, got
        assert not unrecorded_requests(sim), unrecorded_requests(sim)


def fly_up(dronekit, v) -> None:
    """DroneKit's arm_and_takeoff: wait armable, GUIDED, arm, simple_takeoff, reach 95 %."""
    wait_until(lambda: v.is_armable, WAIT, "is_armable", show=lambda: state(v))
    v.mode = dronekit.VehicleMode("GUIDED")
    wait_until(lambda: v.mode.name == "GUIDED", WAIT, "GUIDED", show=lambda: state(v))
    v.armed = True
    wait_until(lambda: v.armed, WAIT, "armed", show=lambda: state(v))
    v.simple_takeoff(ALT)
    wait_until(lambda: (v.location.global_relative_frame.alt or 0) >= ALT * 0.95, WAIT,
               f"simple_takeoff({ALT:g}) reaching {ALT * 0.95:g} m", show=lambda: state(v))


def send_ned_velocity(v, vx: float, vy: float, vz: float, duration: float) -> None:
    """DroneKit's guided_set_speed_yaw.py send_ned_velocity, sent every 0.2 s."""
    msg = v.message_factory.set_position_target_local_ned_encode(
        0, 0, 0, mavutil.mavlink.MAV_FRAME_LOCAL_NED,
        0b0000111111000111,  # only the velocities
        0, 0, 0, vx, vy, vz, 0, 0, 0, 0, 0)
    end = time.monotonic() + duration
    while time.monotonic() < end:
        v.send_mavlink(msg)
        time.sleep(0.2)


@pytest.mark.slow
@pytest.mark.parametrize("transport", TRANSPORTS)
def test_arm_takeoff_velocity_and_mode(transport: str) -> None:
    """GUIDED, arm, simple_takeoff to 10 m, fly north by velocity (the vehicle moves north,
    not east), then LAND: the mode changes and the vehicle comes down."""
    dronekit = require_dronekit()
    with served(transport) as (sim, link), dronekit_vehicle(link, wait_ready=True) as v:
        fly_up(dronekit, v)
        start = v.location.global_frame
        send_ned_velocity(v, 5.0, 0.0, 0.0, 2.0)
        now = v.location.global_frame
        north, east = north_east_m(start.lat, start.lon, now.lat, now.lon)
        print(f"velocity north 5 m/s for 2 s over {transport}: moved {north:.1f} m N, "
              f"{east:.1f} m E")
        assert north > 2.0, f"velocity control did not move the vehicle north: {state(v)}"
        assert abs(east) < north / 2
        send_ned_velocity(v, 0.0, -5.0, 0.0, 1.0)  # west
        later = v.location.global_frame
        _, west = north_east_m(now.lat, now.lon, later.lat, later.lon)
        assert west < -1.0, f"velocity west did not move the vehicle west: {state(v)}"
        v.mode = dronekit.VehicleMode("LAND")
        wait_until(lambda: v.mode.name == "LAND" and sim.mode == "LAND", WAIT, "LAND",
                   show=lambda: state(v))
        wait_until(lambda: (v.location.global_relative_frame.alt or 0) < ALT * 0.5, WAIT,
                   "coming down in LAND", show=lambda: state(v))
        assert not unrecorded_requests(sim), unrecorded_requests(sim)


def hostile(link: Link) -> int:
    """Parameter, command, mission, position-target and MAVFTP messages no client should send,
    requests for another system, a truncated frame and garbage; returns how many."""
    conn = mavutil.mavlink_connection(link.pymavlink, source_system=251)
    sent = 0
    try:
        hb = None
        deadline = time.monotonic() + WAIT
        while hb is None and time.monotonic() < deadline:
            conn.mav.heartbeat_send(MAV.MAV_TYPE_GCS, MAV.MAV_AUTOPILOT_INVALID, 0, 0, 0)
            hb = conn.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        assert hb is not None, "no HEARTBEAT for the hostile sender"
        s, c = hb.get_srcSystem(), hb.get_srcComponent()
        real32 = MAV.MAV_PARAM_TYPE_REAL32
        msgs = [
            # parameters: not ASCII, unknown, NaN/inf, no NUL, empty, bad type, bad indexes
            MAV.MAVLink_param_set_message(s, c, b"\xff\xfe\xc3\xa9BAD", 1.0, real32),
            MAV.MAVLink_param_set_message(s, c, "\u00e9T\u00e9".encode(), 2.0, real32),
            MAV.MAVLink_param_set_message(s, c, b"NO_SUCH_PARAM", 3.0, real32),
            MAV.MAVLink_param_set_message(s, c, b"SYSID_THISMAV", math.nan, real32),
            MAV.MAVLink_param_set_message(s, c, b"SYSID_THISMAV", math.inf, real32),
            MAV.MAVLink_param_set_message(s, c, b"A" * 16, 4.0, real32),
            MAV.MAVLink_param_set_message(s, c, b"", 5.0, real32),
            MAV.MAVLink_param_set_message(s, c, b"\x00HIDDEN", 6.0, real32),
            MAV.MAVLink_param_set_message(s, c, b"NO_SUCH_PARAM", 7.0, 200),
            MAV.MAVLink_param_request_read_message(s, c, b"\xff\xfe", -1),
            MAV.MAVLink_param_request_read_message(s, c, b"", 32767),
            MAV.MAVLink_param_request_read_message(s, c, b"", -2),
            # commands: unknown ids, NaN parameters, nonsense modes and message ids
            MAV.MAVLink_command_long_message(s, c, 65535, 0, *[math.nan] * 7),
            MAV.MAVLink_command_long_message(s, c, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                             math.nan, math.inf, 0, 0, 0, 0, 0),
            MAV.MAVLink_command_long_message(s, c, MAV.MAV_CMD_DO_SET_MODE, 0,
                                             1, 9999, 0, 0, 0, 0, 0),
            MAV.MAVLink_command_long_message(s, c, MAV.MAV_CMD_REQUEST_MESSAGE, 0,
                                             65535, 0, 0, 0, 0, 0, 0),
            MAV.MAVLink_command_long_message(s, c, MAV.MAV_CMD_SET_MESSAGE_INTERVAL, 0,
                                             MAV.MAVLINK_MSG_ID_HEARTBEAT, -2, 0, 0, 0, 0, 0),
            MAV.MAVLink_command_long_message(s, c, MAV.MAV_CMD_NAV_TAKEOFF, 0,
                                             0, 0, 0, 0, math.nan, math.nan, -1e9),
            MAV.MAVLink_command_int_message(s, c, 255, MAV.MAV_CMD_DO_REPOSITION, 0, 0,
                                            -1, 0, 0, math.nan, 2**31 - 1, -2**31, math.inf),
            MAV.MAVLink_set_mode_message(s, 0, 4242),
            # missions: absurd counts, items out of any transfer, requests beyond the end
            MAV.MAVLink_mission_count_message(s, c, 65535),
            MAV.MAVLink_mission_item_int_message(s, c, 9000, 0, 16, 0, 1, 0, 0, 0, 0,
                                                 2**31 - 1, 2**31 - 1, math.nan),
            MAV.MAVLink_mission_request_int_message(s, c, 60000),
            MAV.MAVLink_mission_request_list_message(s, c),
            MAV.MAVLink_mission_ack_message(s, c, MAV.MAV_MISSION_ERROR),
            MAV.MAVLink_mission_set_current_message(s, c, 65000),
            MAV.MAVLink_mission_write_partial_list_message(s, c, 5, 2),
            MAV.MAVLink_mission_count_message(s, c, 0),
            # position targets, streams and MAVFTP (as tests/vehicle/test_ardupilot_hostile.py)
            MAV.MAVLink_set_position_target_local_ned_message(
                0, s, c, 250, 0, math.nan, math.inf, 0, 0, 0, 0, 0, 0, 0, 0, 0),
            MAV.MAVLink_set_position_target_global_int_message(
                0, s, c, MAV.MAV_FRAME_GLOBAL_INT, 0, 2**31 - 1, 0, math.nan, 0, 0, 0, 0, 0, 0,
                math.nan, 0),
            MAV.MAVLink_request_data_stream_message(s, c, 99, 10, 7),
            MAV.MAVLink_file_transfer_protocol_message(0, s, c, b"\xff" * 251),
            # valid requests for another system: not this vehicle's to take
            MAV.MAVLink_param_set_message(99, c, b"RTL_ALT", 1.0, MAV.MAV_PARAM_TYPE_INT32),
            MAV.MAVLink_command_long_message(99, c, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0,
                                             1, 0, 0, 0, 0, 0, 0),
        ]
        for msg in msgs:
            conn.mav.send(msg)
            sent += 1
            conn.recv_match(blocking=True, timeout=0.02)  # let the vehicle answer, in order
        # a PARAM_SET whose payload was cut short, then garbage
        raw = bytearray(MAV.MAVLink_param_set_message(s, c, b"CUT", 1.0, real32).pack(conn.mav))
        conn.write(bytes(raw[:-6]))
        conn.write(bytes(range(256)) * 2)
        sent += 2
        time.sleep(0.5)  # the vehicle reports held bytes stale after 0.2 s (vehicle.codec)
        return sent
    finally:
        conn.close()


@pytest.mark.slow
@pytest.mark.parametrize("transport", TRANSPORTS)
def test_hostile_messages_leave_every_parameter_to_a_real_client(transport: str) -> None:
    """Hostile parameter, command and mission messages first (pymavlink), then DroneKit's
    connect(wait_ready=True) still gets every parameter with its value, none of the hostile
    names among them, and the vehicle still arms."""
    dronekit = require_dronekit()
    with served(transport) as (sim, link):
        before = pymavlink_params(link)
        mode = sim.mode
        assert hostile(link) > 20
        assert not sim.armed and sim.mode == mode, "hostile commands armed or moved the vehicle"
        after = pymavlink_params(link)
        assert after == before, "PARAM_REQUEST_LIST after hostile input differs"
        with dronekit_vehicle(link, wait_ready=True) as v:
            got = {k.upper(): v.parameters[k] for k in v.parameters.keys()}
            assert set(got) == {k.upper() for k in before}
            for name, value in before.items():
                assert math.isclose(got[name.upper()], value, rel_tol=1e-6), name
            errors = [e.detail for e in sim.events("error")]
            assert not errors, f"the vehicle failed inside on hostile input: {errors[:3]}"
            wait_until(lambda: v.is_armable, WAIT, "is_armable after hostile input",
                       show=lambda: state(v))
            v.mode = dronekit.VehicleMode("GUIDED")
            wait_until(lambda: v.mode.name == "GUIDED", WAIT, "GUIDED", show=lambda: state(v))
            v.armed = True
            wait_until(lambda: v.armed, WAIT, "armed after hostile input", show=lambda: state(v))
        assert not unrecorded_requests(sim), unrecorded_requests(sim)

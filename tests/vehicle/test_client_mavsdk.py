"""MAVSDK (the native 4.x binding over the MAVSDK C++ core) against the simulated vehicle, over
TCP and UDP, with the idioms of MAVSDK's own examples (takeoff_and_land, goto, offboard_velocity,
mission_raw): wait for ``health().is_global_position_ok and is_home_position_ok`` (and
``is_armable``), ``info.get_version()``, arm, takeoff until ``in_air``, ``goto_location``,
``mission_raw`` upload/download/start, offboard velocity. Issue 35: ``is_home_position_ok``
and ``is_armable`` stayed False (no HOME_POSITION, SYS_STATUS without the pre-arm bit),
``get_version()`` said INFORMATION_NOT_RECEIVED_YET (no AUTOPILOT_VERSION), ``in_air`` was False
at 10 m (no EXTENDED_SYS_STATE), DO_REPOSITION and SET_POSITION_TARGET_* were not flown.
"""

from __future__ import annotations

import math
import time

import pytest

from tests.vehicle.clients import (
    MAV,
    TRANSPORTS,
    WAIT,
    MavsdkLog,
    mavsdk_system,
    north_east_m,
    require_mavsdk,
    served,
    unrecorded_requests,
    wait_until,
)

ALT = 10.0


def plugins():
    """The plugin classes (imported only once the binding is known to be installed)."""
    require_mavsdk()
    from mavsdk.plugins.action import Action
    from mavsdk.plugins.info import Info
    from mavsdk.plugins.mission_raw import MissionItem, MissionRaw
    from mavsdk.plugins.offboard import Offboard, VelocityNedYaw
    from mavsdk.plugins.param import Param
    from mavsdk.plugins.telemetry import LandedState, Telemetry

    return {"Action": Action, "Info": Info, "MissionItem": MissionItem,
            "MissionRaw": MissionRaw, "Offboard": Offboard, "VelocityNedYaw": VelocityNedYaw,
            "Param": Param, "LandedState": LandedState, "Telemetry": Telemetry}


def health(tel) -> str:
    h = tel.health()
    return (f"global={h.is_global_position_ok} home={h.is_home_position_ok} "
            f"armable={h.is_armable} in_air={tel.in_air()} landed={tel.landed_state()!r}\n"
            f"{MavsdkLog.tail(8)}")


def ready(tel) -> bool:
    h = tel.health()
    return bool(h.is_global_position_ok and h.is_home_position_ok and h.is_armable)


def take_off(p, system, tel):
    """takeoff_and_land.py: wait for health, arm, takeoff, until in_air and near ALT."""
    action = p["Action"](system)
    wait_until(lambda: ready(tel), WAIT, "health: global, home position ok, armable",
               show=lambda: health(tel))
    action.set_takeoff_altitude(ALT)
    action.arm()
    action.takeoff()
    wait_until(lambda: tel.in_air(), WAIT, "in_air after takeoff", show=lambda: health(tel))
    wait_until(lambda: tel.position().relative_altitude_m >= ALT * 0.9, WAIT,
               f"relative altitude {ALT * 0.9:g} m", show=lambda: vars(tel.position()))
    assert tel.landed_state() == p["LandedState"].IN_AIR, health(tel)
    return action


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_health_home_armable_and_version(transport: str) -> None:
    """While the fix is withheld, health() is not ready (no global position, not armable);
    after it, global and home position ok and armable; info.get_version() is ArduCopter 4.x;
    the autopilot is ArduPilot; on the ground, landed_state is ON_GROUND; an ArduPilot integer
    parameter reads as one."""
    p = plugins()
    from mavsdk import Autopilot

    with served(transport, sysid=3, fix_withheld=True) as (sim, link), \
            mavsdk_system(link) as system:
        tel, info = p["Telemetry"](system), p["Info"](system)
        end = time.monotonic() + 1.0
        while time.monotonic() < end:
            h = tel.health()
            assert not (h.is_global_position_ok or h.is_armable), f"without a fix: {health(tel)}"
            time.sleep(0.1)
        sim.give_fix()
        t0 = time.monotonic()
        wait_until(lambda: ready(tel), WAIT, "health: global, home position ok, armable",
                   show=lambda: health(tel))
        print(f"MAVSDK health ready over {transport}: {time.monotonic() - t0:.2f} s after "
              f"the fix")
        assert not math.isnan(tel.home().latitude_deg)
        version = wait_until(lambda: _version(info), WAIT, "info.get_version()",
                             show=MavsdkLog.tail)
        assert version.flight_sw_major == 4, vars(version)
        assert system.autopilot_type() == Autopilot.ARDUPILOT
        wait_until(lambda: tel.landed_state() == p["LandedState"].ON_GROUND, WAIT,
                   "landed_state ON_GROUND on the ground", show=lambda: health(tel))
        assert not tel.in_air()
        assert p["Param"](system).get_param_int("SYSID_THISMAV") == 3
    assert not unrecorded_requests(sim, sysid=3), unrecorded_requests(sim, sysid=3)


def _version(info):
    from mavsdk.plugins.info import InfoError

    try:
        return info.get_version()
    except InfoError:
        return None


@pytest.mark.slow
@pytest.mark.parametrize("transport", TRANSPORTS)
def test_arm_takeoff_in_air_and_goto_location(transport: str) -> None:
    """Arm, takeoff: in_air and IN_AIR; goto_location 40 m north: the vehicle gets there;
    return_to_launch: landed (ON_GROUND, not in_air) and disarmed."""
    p = plugins()
    with served(transport) as (sim, link), mavsdk_system(link) as system:
        tel = p["Telemetry"](system)
        action = take_off(p, system, tel)
        here = tel.position()
        target_lat = here.latitude_deg + 40.0 / 111_320.0
        action.goto_location(target_lat, here.longitude_deg, here.absolute_altitude_m, 0.0)

        def left() -> float:
            now = tel.position()
            north, east = north_east_m(now.latitude_deg, now.longitude_deg, target_lat,
                                       here.longitude_deg)
            return math.hypot(north, east)

        wait_until(lambda: left() < 5.0, WAIT, "goto_location reaching 5 m of the target",
                   show=lambda: (f"{left():.1f} m left", sim.mode, vars(tel.position())))
        print(f"goto_location 40 m north over {transport}: {left():.1f} m left")
        action.return_to_launch()
        wait_until(lambda: tel.landed_state() == p["LandedState"].ON_GROUND and not tel.armed(),
                   WAIT, "return_to_launch: landed and disarmed",
                   show=lambda: (sim.mode, health(tel)))
        assert not tel.in_air()
    assert not unrecorded_requests(sim), unrecorded_requests(sim)


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_mission_raw_upload_download_start(transport: str) -> None:
    """mission_raw: upload four items (home, takeoff, two waypoints), download the same four,
    arm and start: the vehicle is in AUTO, climbs and the progress moves on."""
    p = plugins()
    with served(transport) as (sim, link), mavsdk_system(link) as system:
        tel, mission = p["Telemetry"](system), p["MissionRaw"](system)
        wait_until(lambda: ready(tel), WAIT, "health ready", show=lambda: health(tel))
        home = tel.home()
        lat, lon = int(home.latitude_deg * 1e7), int(home.longitude_deg * 1e7)
        rel = MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT
        rows = [  # (frame, command, x, y, z)
            (MAV.MAV_FRAME_GLOBAL_INT, MAV.MAV_CMD_NAV_WAYPOINT, lat, lon, 0.0),
            (rel, MAV.MAV_CMD_NAV_TAKEOFF, 0, 0, ALT),
            (rel, MAV.MAV_CMD_NAV_WAYPOINT, lat + 2000, lon, ALT),
            (rel, MAV.MAV_CMD_NAV_WAYPOINT, lat + 2000, lon + 2000, ALT),
        ]
        items = [p["MissionItem"](seq=i, frame=f, command=c, current=int(i == 0),
                                  autocontinue=1, x=x, y=y, z=z, mission_type=0)
                 for i, (f, c, x, y, z) in enumerate(rows)]
        mission.upload_mission(items)
        assert [(i["command"], i["x"], i["y"]) for i in sim.mission] == [
            (c, x, y) for _, c, x, y, _ in rows]
        back = mission.download_mission()
        assert [(i.seq, i.command, i.x, i.y) for i in back] == [
            (n, c, x, y) for n, (_, c, x, y, _) in enumerate(rows)]
        assert [round(i.z, 3) for i in back[1:]] == [ALT] * 3
        p["Action"](system).arm()
        mission.start_mission()
        wait_until(lambda: sim.mode == "AUTO", WAIT, "AUTO after start_mission",
                   show=lambda: (sim.mode, health(tel)))
        wait_until(lambda: tel.position().relative_altitude_m > ALT * 0.5, WAIT,
                   "climbing in the mission", show=lambda: vars(tel.position()))
        wait_until(lambda: mission.mission_progress().current >= 2, WAIT,
                   "mission_progress past the takeoff",
                   show=lambda: vars(mission.mission_progress()))
    assert not unrecorded_requests(sim), unrecorded_requests(sim)


@pytest.mark.slow
@pytest.mark.parametrize("transport", TRANSPORTS)
def test_offboard_velocity_moves_the_vehicle(transport: str) -> None:
    """offboard_velocity_ned.py: a first setpoint, start, 5 m/s east: the vehicle moves east,
    not north; stop."""
    p = plugins()
    with served(transport) as (sim, link), mavsdk_system(link) as system:
        tel = p["Telemetry"](system)
        take_off(p, system, tel)
        offboard = p["Offboard"](system)
        vel = p["VelocityNedYaw"]
        offboard.set_velocity_ned(vel(0.0, 0.0, 0.0, 0.0))
        offboard.start()
        start = tel.position()
        offboard.set_velocity_ned(vel(0.0, 5.0, 0.0, 0.0))

        def moved() -> tuple[float, float]:
            now = tel.position()
            return north_east_m(start.latitude_deg, start.longitude_deg,
                                now.latitude_deg, now.longitude_deg)

        wait_until(lambda: moved()[1] > 5.0, WAIT, "offboard velocity east moving 5 m",
                   show=lambda: (moved(), sim.mode, health(tel)))
        north, east = moved()
        print(f"offboard 5 m/s east over {transport}: {east:.1f} m E, {north:.1f} m N")
        assert abs(north) < east / 2
        offboard.set_velocity_ned(vel(0.0, 0.0, 0.0, 0.0))
        offboard.stop()
    assert not unrecorded_requests(sim), unrecorded_requests(sim)

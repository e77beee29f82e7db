"""GUIDED flight as ArduCopter flies it: velocity and position targets move the vehicle,
DO_REPOSITION, CONDITION_YAW and DO_CHANGE_SPEED answer as ArduCopter answers, and what is
ignored is still recorded. Sans-I/O: the model with a fake clock."""

from __future__ import annotations

import math

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from mcp_conform.vehicle.flight import distance_m
from tests.vehicle.test_model import ACCEPTED, FAILED, ack_of, armed_in_guided, by_type, make

POS_IGNORE = (mav.POSITION_TARGET_TYPEMASK_X_IGNORE | mav.POSITION_TARGET_TYPEMASK_Y_IGNORE
              | mav.POSITION_TARGET_TYPEMASK_Z_IGNORE)
VEL_IGNORE = (mav.POSITION_TARGET_TYPEMASK_VX_IGNORE | mav.POSITION_TARGET_TYPEMASK_VY_IGNORE
              | mav.POSITION_TARGET_TYPEMASK_VZ_IGNORE)
ACC_IGNORE = (mav.POSITION_TARGET_TYPEMASK_AX_IGNORE | mav.POSITION_TARGET_TYPEMASK_AY_IGNORE
              | mav.POSITION_TARGET_TYPEMASK_AZ_IGNORE | mav.POSITION_TARGET_TYPEMASK_YAW_IGNORE
              | mav.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE)


def flying(alt: float = 10.0):
    model, gcs = armed_in_guided()
    gcs.command(mav.MAV_CMD_NAV_TAKEOFF, *[0] * 6, alt, now=0.0)
    model.tick(1.0)
    assert model.altitude == alt
    return model, gcs


def velocity(vn: float, ve: float, vd: float, frame: int = mav.MAV_FRAME_LOCAL_NED):
    return mav.MAVLink_set_position_target_local_ned_message(
        0, 1, 1, frame, POS_IGNORE | ACC_IGNORE, 0, 0, 0, vn, ve, vd, 0, 0, 0, 0, 0)


def last_request(model) -> dict:
    return model.events("request")[-1].detail


def test_velocity_target_moves_the_vehicle_and_stops_after_guid_timeout() -> None:
    model, gcs = flying()
    lat0, lon0 = model.lat, model.lon
    gcs.send(velocity(5.0, 0.0, -1.0), now=1.0)
    pos = by_type(model.tick(3.0), "GLOBAL_POSITION_INT")
    assert distance_m(lat0, lon0, model.lat, model.lon) == pytest.approx(10.0, abs=0.01)
    assert model.lat > lat0 and model.altitude == pytest.approx(12.0)
    assert (pos.vx, pos.vz) == (500, -100)  # cm/s, north and down
    local = by_type(model.tick(3.25), "LOCAL_POSITION_NED")
    assert local.x == pytest.approx(11.25, abs=0.01) and local.z == pytest.approx(-12.25)
    model.tick(6.0)  # GUID_TIMEOUT (3 s) after the last target: stopped
    held = (model.lat, model.lon)
    model.tick(8.0)
    assert (model.lat, model.lon) == held
    assert last_request(model)["result"] == "accepted"


def test_body_frame_velocity_is_rotated_by_the_heading() -> None:
    model, gcs = flying()
    assert ack_of(gcs.command(mav.MAV_CMD_CONDITION_YAW, 90, 0, 1, 0, now=1.0), 115) == ACCEPTED
    lon0 = model.lon
    gcs.send(velocity(2.0, 0.0, 0.0, mav.MAV_FRAME_BODY_OFFSET_NED), now=1.0)
    model.tick(2.0)
    assert model.lon > lon0  # forward, facing east
    assert by_type(model.tick(2.25), "VFR_HUD").heading == 90


def test_global_position_target_flies_there() -> None:
    model, gcs = flying()
    target = (357723320, -786744210)  # about 111 m north
    gcs.send(mav.MAVLink_set_position_target_global_int_message(
        0, 1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, VEL_IGNORE | ACC_IGNORE, *target, 20.0,
        0, 0, 0, 0, 0, 0, 0, 0), now=1.0)
    pt = by_type(model.tick(1.5), "POSITION_TARGET_GLOBAL_INT")
    assert (pt.lat_int, pt.lon_int, pt.alt) == (*target, 20.0)
    model.tick(5.0)
    assert (round(model.lat * 1e7), round(model.lon * 1e7)) == target
    assert model.altitude == 20.0


def test_position_targets_outside_guided_are_ignored_but_recorded() -> None:
    model, gcs = make()
    gcs.send(velocity(5.0, 0.0, 0.0), now=0.0)
    rec = last_request(model)
    assert (rec["request"], rec["result"]) == ("position_target", "denied")
    assert rec["reason"] == "mode STABILIZE is not GUIDED: ignored, as ArduCopter"


def test_an_unsupported_frame_holds_position() -> None:
    model, gcs = flying()
    gcs.send(velocity(5.0, 0.0, 0.0), now=1.0)
    gcs.send(velocity(5.0, 0.0, 0.0, mav.MAV_FRAME_GLOBAL), now=1.5)
    held = (model.lat, model.lon)
    model.tick(3.0)
    assert (model.lat, model.lon) == held
    assert "GUIDED holds position" in last_request(model)["reason"]


def test_do_reposition_needs_guided_or_the_change_mode_flag() -> None:
    model, gcs = make()
    model.tick(0.0)
    cmd = lambda flags, now: gcs.send(mav.MAVLink_command_int_message(  # noqa: E731
        1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, flags,
        0, math.nan, 357723320, -786744210, 15.0), now)
    assert ack_of(cmd(0, 0.0), mav.MAV_CMD_DO_REPOSITION) == mav.MAV_RESULT_DENIED
    assert ack_of(cmd(mav.MAV_DO_REPOSITION_FLAGS_CHANGE_MODE, 0.1), 192) == ACCEPTED
    assert model.mode == "GUIDED" and last_request(model)["request"] == "reposition"


def test_do_reposition_flies_there_in_guided() -> None:
    model, gcs = flying()
    replies = gcs.send(mav.MAVLink_command_int_message(
        1, 1, mav.MAV_FRAME_GLOBAL_INT, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, math.nan,
        357723320, -786744210, model.config.home_alt + 30.0), now=1.0)
    assert ack_of(replies, mav.MAV_CMD_DO_REPOSITION) == ACCEPTED
    model.tick(6.0)
    assert round(model.lat * 1e7) == 357723320 and model.altitude == pytest.approx(30.0)


def test_do_reposition_to_zero_zero_is_denied() -> None:
    model, gcs = flying()
    replies = gcs.send(mav.MAVLink_command_int_message(
        1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, mav.MAV_CMD_DO_REPOSITION, 0, 0, -1, 0, 0, 0,
        0, 0, 10.0), now=1.0)
    assert ack_of(replies, mav.MAV_CMD_DO_REPOSITION) == mav.MAV_RESULT_DENIED


@pytest.mark.parametrize(("params", "result"), [((45, 0, 1, 0), ACCEPTED), ((400, 0, 1, 0), FAILED),
                                                ((45, 0, 1, 2), FAILED)])
def test_condition_yaw_checks_its_parameters(params: tuple, result: int) -> None:
    model, gcs = make()
    assert ack_of(gcs.command(mav.MAV_CMD_CONDITION_YAW, *params, now=0.0), 115) == result


def test_do_change_speed_slows_the_guided_flight_and_needs_a_speed_mode() -> None:
    model, gcs = make()
    assert ack_of(gcs.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 5, now=0.0), 178) == FAILED
    model, gcs = flying()
    assert ack_of(gcs.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, -1, now=1.0), 178) == FAILED
    assert ack_of(gcs.command(mav.MAV_CMD_DO_CHANGE_SPEED, 1, 5, now=1.0), 178) == ACCEPTED
    lat0, lon0 = model.lat, model.lon
    gcs.send(mav.MAVLink_set_position_target_global_int_message(
        0, 1, 1, mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, VEL_IGNORE | ACC_IGNORE, 357723320,
        -786744210, 10.0, 0, 0, 0, 0, 0, 0, 0, 0), now=1.0)
    model.tick(3.0)
    assert distance_m(lat0, lon0, model.lat, model.lon) == pytest.approx(10.0, abs=0.01)

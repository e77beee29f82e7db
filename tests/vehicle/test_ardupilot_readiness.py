"""The vehicle looks ready (or not) to a client library as ArduCopter 4.x looks: SYS_STATUS,
EKF_STATUS_REPORT, HOME_POSITION, AUTOPILOT_VERSION, EXTENDED_SYS_STATE, message rates,
parameters with their types, MAVFTP refused at once, unknown commands UNSUPPORTED.
Sans-I/O: the model with a fake clock."""

from __future__ import annotations

import struct
from collections import Counter

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from tests.vehicle.test_model import ACCEPTED, FAILED, ack_of, armed_in_guided, by_type, make

PREARM = mav.MAV_SYS_STATUS_PREARM_CHECK
GPS = mav.MAV_SYS_STATUS_SENSOR_GPS
FENCE = mav.MAV_SYS_STATUS_GEOFENCE
ID = {"ATTITUDE": mav.MAVLINK_MSG_ID_ATTITUDE, "HOME": mav.MAVLINK_MSG_ID_HOME_POSITION,
      "VERSION": mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION}


def requests(model) -> list[dict]:
    return [e.detail for e in model.events("request")]


def counts(model, start: float, end: float, step: float = 0.05) -> Counter:
    """How many of each message ``tick`` sends from ``start`` to ``end``."""
    n: Counter = Counter()
    t = start
    while t <= end:
        n.update(m.get_type() for m in model.tick(t))
        t = round(t + step, 6)
    return n


def count(model, msg_type: str, start: float, end: float) -> int:
    return counts(model, start, end)[msg_type]


# ---------------------------------------------------------------- readiness
def test_without_a_fix_nothing_says_ready() -> None:
    model, _ = make(fix_withheld=True)
    msgs = model.tick(0.0)
    st = by_type(msgs, "SYS_STATUS")
    assert st.onboard_control_sensors_present & PREARM and st.onboard_control_sensors_enabled & PREARM
    assert not st.onboard_control_sensors_health & PREARM  # MCP-BLK-4/5: no fix -> not armable
    assert not st.onboard_control_sensors_health & GPS
    ekf = by_type(msgs, "EKF_STATUS_REPORT")
    assert ekf.flags & mav.EKF_CONST_POS_MODE
    assert not ekf.flags & (mav.EKF_POS_HORIZ_ABS | mav.EKF_PRED_POS_HORIZ_ABS)
    assert not [m for m in msgs + model.take_outbox() if m.get_type() == "HOME_POSITION"]
    assert by_type(msgs, "EXTENDED_SYS_STATE").landed_state == mav.MAV_LANDED_STATE_ON_GROUND


def test_with_a_fix_everything_says_ready_and_home_is_sent() -> None:
    model, gcs = make(fix_withheld=True)
    model.tick(0.0)
    model.give_fix(1.0)
    msgs = model.tick(1.0)
    st = by_type(msgs, "SYS_STATUS")
    assert st.onboard_control_sensors_health & (PREARM | GPS) == PREARM | GPS
    # the geofence: present, not enabled (FENCE_ENABLE 0), healthy (no breach)
    assert st.onboard_control_sensors_present & FENCE and st.onboard_control_sensors_health & FENCE
    assert not st.onboard_control_sensors_enabled & FENCE
    ekf = by_type(msgs, "EKF_STATUS_REPORT")
    assert ekf.flags & mav.EKF_POS_HORIZ_ABS and ekf.flags & mav.EKF_PRED_POS_HORIZ_ABS
    assert not ekf.flags & mav.EKF_CONST_POS_MODE
    home = [m for _, m in model.take_outbox() if m.get_type() == "HOME_POSITION"]
    assert len(home) == 1 and home[0].altitude == round(model.config.home_alt * 1000)
    assert count(model, "HOME_POSITION", 1.05, 11.0) == 2  # then every 5 s
    ack = gcs.command(mav.MAV_CMD_GET_HOME_POSITION, now=11.1)
    assert ack_of(ack, mav.MAV_CMD_GET_HOME_POSITION) == ACCEPTED
    assert by_type(ack, "HOME_POSITION").latitude == round(model.config.home_lat * 1e7)


def test_get_home_position_before_a_fix_fails_as_ardupilot() -> None:
    model, gcs = make(fix_withheld=True)
    assert ack_of(gcs.command(mav.MAV_CMD_GET_HOME_POSITION, now=0.0), 410) == FAILED
    assert requests(model)[-1]["reason"] == "home is not set (no GPS fix yet)"


def test_global_position_altitude_is_amsl_and_not_zero_on_the_ground() -> None:
    model, _ = make()
    pos = by_type(model.tick(0.0), "GLOBAL_POSITION_INT")
    assert pos.relative_alt == 0 and pos.alt == round(model.config.home_alt * 1000) != 0


@pytest.mark.parametrize("how", ["request_message", "capabilities"])
def test_autopilot_version_names_arducopter_4(how: str) -> None:
    model, gcs = make()
    if how == "request_message":
        replies = gcs.command(mav.MAV_CMD_REQUEST_MESSAGE, ID["VERSION"], now=0.0)
    else:
        replies = gcs.command(mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1, now=0.0)
    version = by_type(replies, "AUTOPILOT_VERSION")
    raw = version.flight_sw_version
    assert (raw >> 24, raw >> 16 & 0xFF, raw & 0xFF) == (4, 5, mav.FIRMWARE_VERSION_TYPE_OFFICIAL)
    caps = version.capabilities
    for bit in ("MISSION_INT", "COMMAND_INT", "SET_POSITION_TARGET_LOCAL_NED",
                "SET_POSITION_TARGET_GLOBAL_INT", "MAVLINK2", "PARAM_ENCODE_C_CAST"):
        assert caps & getattr(mav, f"MAV_PROTOCOL_CAPABILITY_{bit}"), bit
    assert not caps & mav.MAV_PROTOCOL_CAPABILITY_FTP  # it answers FTP with NAKs only
    assert requests(model)[-1]["request"] == "message"


def test_capabilities_request_needs_param1_1() -> None:
    model, gcs = make()
    replies = gcs.command(mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 0, now=0.0)
    assert ack_of(replies, mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES) == FAILED
    assert not [m for m in replies if m.get_type() == "AUTOPILOT_VERSION"]


def test_extended_sys_state_follows_takeoff_flight_and_landing() -> None:
    model, gcs = armed_in_guided()
    state = lambda t: by_type(model.tick(t), "EXTENDED_SYS_STATE").landed_state  # noqa: E731
    assert state(0.0) == mav.MAV_LANDED_STATE_ON_GROUND
    gcs.command(mav.MAV_CMD_NAV_TAKEOFF, *[0] * 6, 10.0, now=0.0)
    assert state(0.25) == mav.MAV_LANDED_STATE_TAKEOFF
    assert state(1.0) == mav.MAV_LANDED_STATE_IN_AIR
    gcs.command(mav.MAV_CMD_NAV_LAND, now=1.0)
    assert state(1.25) == mav.MAV_LANDED_STATE_LANDING
    assert state(3.0) == mav.MAV_LANDED_STATE_ON_GROUND and not model.armed


# ---------------------------------------------------------------- rates
def test_set_message_interval_changes_stops_and_resets_one_message() -> None:
    model, gcs = make()
    assert count(model, "ATTITUDE", 0.0, 2.0) == 9  # 4 Hz
    ok = gcs.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, ID["ATTITUDE"], 1e6, now=2.0)
    assert ack_of(ok, mav.MAV_CMD_SET_MESSAGE_INTERVAL) == ACCEPTED
    sent = counts(model, 2.05, 6.0)
    assert (sent["ATTITUDE"], sent["VFR_HUD"]) == (4, 16)  # 1 Hz; the others untouched
    gcs.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, ID["ATTITUDE"], -1, now=6.0)
    assert count(model, "ATTITUDE", 6.05, 8.0) == 0
    replies = gcs.command(mav.MAV_CMD_GET_MESSAGE_INTERVAL, ID["ATTITUDE"], now=8.0)
    assert by_type(replies, "MESSAGE_INTERVAL").interval_us == -1
    gcs.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, ID["ATTITUDE"], 0, now=8.0)  # default
    assert count(model, "ATTITUDE", 8.05, 10.0) == 8
    assert [d["request"] for d in requests(model)] == ["message_interval"] * 4


def test_set_message_interval_of_a_message_it_does_not_send_fails() -> None:
    model, gcs = make()
    replies = gcs.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, mav.MAVLINK_MSG_ID_RAW_IMU, 1e5,
                          now=0.0)
    assert ack_of(replies, mav.MAV_CMD_SET_MESSAGE_INTERVAL) == FAILED
    assert "RAW_IMU" in requests(model)[-1]["reason"]


def test_a_requested_interval_streams_a_message_sent_only_on_request() -> None:
    model, gcs = make()
    gcs.command(mav.MAV_CMD_SET_MESSAGE_INTERVAL, ID["VERSION"], 5e5, now=0.0)
    assert count(model, "AUTOPILOT_VERSION", 0.05, 2.0) == 4


def test_request_data_stream_sets_a_stream_and_all_streams() -> None:
    model, gcs = make()
    gcs.send(mav.MAVLink_request_data_stream_message(1, 1, mav.MAV_DATA_STREAM_EXTRA1, 0, 0), 0.0)
    sent = counts(model, 0.0, 2.0)
    assert (sent["ATTITUDE"], sent["VFR_HUD"]) == (0, 9)
    gcs.send(mav.MAVLink_request_data_stream_message(1, 1, mav.MAV_DATA_STREAM_ALL, 2, 1), 4.0)
    sent = counts(model, 4.05, 6.0)
    assert (sent["ATTITUDE"], sent["VFR_HUD"], sent["HEARTBEAT"]) == (4, 4, 2)  # 2 Hz, 1 Hz
    got = [(d["request"], d["stream"], d["rate"]) for d in requests(model)]
    assert got == [("data_stream", mav.MAV_DATA_STREAM_EXTRA1, 0),
                   ("data_stream", mav.MAV_DATA_STREAM_ALL, 2)]


# ---------------------------------------------------------------- parameters
def _params(gcs, now: float = 0.0) -> dict:
    replies = gcs.send(mav.MAVLink_param_request_list_message(1, 1), now)
    return {m.param_id: m for m in replies if m.get_type() == "PARAM_VALUE"}


def test_parameters_have_ardupilot_names_and_types() -> None:
    _, gcs = make()
    params = _params(gcs)
    types = {n: params[n].param_type for n in ("SYSID_THISMAV", "RTL_ALT", "WPNAV_SPEED",
                                                "DISARM_DELAY", "ARMING_CHECK")}
    assert types == {"SYSID_THISMAV": mav.MAV_PARAM_TYPE_INT16,
                     "RTL_ALT": mav.MAV_PARAM_TYPE_INT32, "WPNAV_SPEED": mav.MAV_PARAM_TYPE_REAL32,
                     "DISARM_DELAY": mav.MAV_PARAM_TYPE_INT8,
                     "ARMING_CHECK": mav.MAV_PARAM_TYPE_INT32}
    assert params["RTL_ALT"].param_value == 1500.0  # the integer cast to float, not byte-packed
    assert sorted(m.param_index for m in params.values()) == list(range(len(params)))


@pytest.mark.parametrize(("value", "stored"), [(2.6, 2.0), (2.999, 3.0), (-3.7, -3.0),
                                               (300.0, 127.0), (-1e9, -128.0)])
def test_param_set_of_an_integer_rounds_and_clamps_as_ap_param(value: float,
                                                               stored: float) -> None:
    model, gcs = make()
    echo = by_type(gcs.send(mav.MAVLink_param_set_message(1, 1, b"DISARM_DELAY", value,
                                                          mav.MAV_PARAM_TYPE_INT8), 0.0),
                   "PARAM_VALUE")
    assert (echo.param_value, echo.param_index) == (stored, 65535)
    assert model.params["DISARM_DELAY"] == stored


def test_param_set_of_an_unknown_name_is_ignored_and_recorded() -> None:
    model, gcs = make()
    before = model.params.as_dict()
    assert gcs.send(mav.MAVLink_param_set_message(1, 1, b"NO_SUCH_PARAM", 1.0, 9), 0.0) == []
    assert model.params.as_dict() == before
    rec = requests(model)[-1]
    assert (rec["request"], rec["result"], rec["answer"]) == ("param_set", "denied", "none")
    assert "unknown parameter 'NO_SUCH_PARAM'" in rec["reason"]


def test_param_request_read_by_index_and_by_name() -> None:
    model, gcs = make()
    names = model.params.names()
    by_index = gcs.send(mav.MAVLink_param_request_read_message(1, 1, b"", 3), 0.0)
    assert by_type(by_index, "PARAM_VALUE").param_id == names[3]
    by_name = gcs.send(mav.MAVLink_param_request_read_message(1, 1, b"RTL_ALT", -1), 0.0)
    assert (by_type(by_name, "PARAM_VALUE").param_value,
            by_type(by_name, "PARAM_VALUE").param_index) == (1500.0, 65535)
    assert gcs.send(mav.MAVLink_param_request_read_message(1, 1, b"", 999), 0.0) == []
    assert gcs.send(mav.MAVLink_param_request_read_message(1, 1, b"NOPE", -1), 0.0) == []
    assert [d["result"] for d in requests(model)] == ["accepted", "accepted", "denied", "denied"]


# ---------------------------------------------------------------- MAVFTP, commands
def test_mavftp_open_is_refused_at_once_with_a_nak() -> None:
    model, gcs = make()
    name = b"@PARAM/param.pck?withdefaults=1"
    req = struct.pack("<HBBBBBBI", 7, 0, 4, len(name), 0, 0, 0, 0) + name  # OpenFileRO
    replies = gcs.send(mav.MAVLink_file_transfer_protocol_message(
        0, 1, 1, req.ljust(251, b"\0")), 0.0)
    reply = by_type(replies, "FILE_TRANSFER_PROTOCOL")
    seq, _s, opcode, size, req_opcode = struct.unpack_from("<HBBBB", bytes(reply.payload))
    assert (seq, opcode, size, req_opcode, reply.payload[12]) == (8, 129, 1, 4, 10)
    assert (reply.target_system, reply.target_component) == (42, 191)  # to the asker
    rec = requests(model)[-1]
    assert (rec["request"], rec["answer"]) == ("ftp", "FILE_TRANSFER_PROTOCOL NAK FileNotFound")


def test_a_command_the_vehicle_does_not_handle_is_unsupported_never_accepted() -> None:
    model, gcs = make()
    replies = gcs.command(mav.MAV_CMD_DO_DIGICAM_CONTROL, now=0.0)
    assert ack_of(replies, mav.MAV_CMD_DO_DIGICAM_CONTROL) == mav.MAV_RESULT_UNSUPPORTED
    assert requests(model)[-1]["answer"] == "MAV_RESULT_UNSUPPORTED"

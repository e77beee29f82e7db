"""The mission protocol as ArduCopter 4.x answers it, and AUTO flying the mission (fake clock).

Each expectation cites the ArduPilot code it follows (see ``vehicle.mission``)."""

from __future__ import annotations

import pytest
from pymavlink.dialects.v10 import ardupilotmega as mav1
from pymavlink.dialects.v20 import ardupilotmega as mav

from mcp_conform.vehicle import VehicleConfig, VehicleModel
from mcp_conform.vehicle.mission import REQUEST_RESEND, UPLOAD_TIMEOUT
from tests.vehicle.test_model import Gcs, by_type, make

LAT, LON = 357713320, -786744210  # degE7
WP, TAKEOFF, RTL_CMD = mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_TAKEOFF, mav.MAV_CMD_NAV_RETURN_TO_LAUNCH
REL = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT


def item_int(seq: int, cmd: int = WP, x: int = LAT, y: int = LON, z: float = 20.0, **kw):
    return mav.MAVLink_mission_item_int_message(1, 1, seq, kw.get("frame", REL), cmd,
                                                kw.get("current", 0), 1, 0, 0, 0, 0, x, y, z)


def item_float(seq: int, cmd: int = WP, x: float = 35.771332, y: float = -78.674421,
               z: float = 20.0):
    return mav.MAVLink_mission_item_message(1, 1, seq, REL, cmd, 0, 1, 0, 0, 0, 0, x, y, z)


def ack(replies: list) -> int:
    return by_type(replies, "MISSION_ACK").type


def requests(model: VehicleModel, **detail) -> list[dict]:
    out = [e.detail for e in model.events("request")]
    return [d for d in out if all(d.get(k) == v for k, v in detail.items())]


def upload(gcs: Gcs, items: list, now: float = 0.0) -> list:
    replies = gcs.send(mav.MAVLink_mission_count_message(1, 1, len(items)), now)
    for it in items:
        replies = gcs.send(it, now)
    return replies


def test_upload_asks_with_mission_request_like_arducopter() -> None:
    model, gcs = make()
    replies = gcs.send(mav.MAVLink_mission_count_message(1, 1, 3), 0.0)
    assert by_type(replies, "MISSION_REQUEST").seq == 0  # queued_request_send()
    replies = gcs.send(item_int(0), 0.1)
    assert by_type(replies, "MISSION_REQUEST").seq == 1
    replies = gcs.send(item_float(1), 0.2)  # MISSION_ITEM accepted, with a warning
    texts = [m.text for m in replies if m.get_type() == "STATUSTEXT"]
    assert "got MISSION_ITEM; GCS should send MISSION_ITEM_INT" in texts
    replies = gcs.send(item_int(2, TAKEOFF), 0.3)
    assert ack(replies) == mav.MAV_MISSION_ACCEPTED
    assert "Flight plan received" in [m.text for m in replies if m.get_type() == "STATUSTEXT"]
    assert len(model.mission) == 3 and abs(model.mission[1]["x"] - LAT) <= 10  # float32 degrees
    assert model.events("mission")[-1].detail["count"] == 3
    recs = requests(model, request="mission_item", via="MISSION_ITEM_INT")
    assert [r["seq"] for r in recs] == [0, 2] and all(r["result"] == "accepted" for r in recs)
    assert [r["answer"] for r in recs] == ["MISSION_REQUEST seq=1", "MISSION_ACK MAV_MISSION_ACCEPTED"]
    assert recs[1]["name"] == "MAV_CMD_NAV_TAKEOFF" and recs[1]["reason"] is None


def test_request_int_option() -> None:
    model = VehicleModel(VehicleConfig(mission_request_int=True), now=0.0)
    replies = Gcs(model).send(mav.MAVLink_mission_count_message(1, 1, 1), 0.0)
    assert by_type(replies, "MISSION_REQUEST_INT").seq == 0


def test_dege7_latitude_sent_as_degrees_is_invalid_param5_x_and_upload_goes_on() -> None:
    model, gcs = make()
    gcs.send(mav.MAVLink_mission_count_message(1, 1, 2), 0.0)
    gcs.send(item_int(0), 0.0)
    bad = gcs.send(item_float(1, x=357713320.0, y=-786744210.0), 0.1)
    assert ack(bad) == mav.MAV_MISSION_INVALID_PARAM5_X  # convert_MISSION_ITEM_to_..._INT
    rec = requests(model, via="MISSION_ITEM", seq=1)[-1]
    assert rec["answer"] == "MISSION_ACK MAV_MISSION_INVALID_PARAM5_X"
    assert (rec["request"], rec["result"], rec["mav_result"]) == (
        "mission_item", "denied", mav.MAV_MISSION_INVALID_PARAM5_X)
    assert "degE7" in rec["reason"]
    assert model.missions.upload is not None  # the transfer never saw it: still waiting
    assert ack(gcs.send(item_float(1), 0.2)) == mav.MAV_MISSION_ACCEPTED


@pytest.mark.parametrize(("kw", "code"), [
    ({"x": 950_000_000}, mav.MAV_MISSION_INVALID_PARAM5_X),
    ({"y": -1_900_000_000}, mav.MAV_MISSION_INVALID_PARAM6_Y),
    ({"z": float("nan")}, mav.MAV_MISSION_INVALID_PARAM7),
    ({"cmd": 31337}, mav.MAV_MISSION_UNSUPPORTED),
    ({"frame": mav.MAV_FRAME_BODY_FRD}, mav.MAV_MISSION_UNSUPPORTED_FRAME),
])
def test_bad_item_int_ends_the_upload(kw: dict, code: int) -> None:
    model, gcs = make()
    gcs.send(mav.MAVLink_mission_count_message(1, 1, 2), 0.0)
    assert ack(gcs.send(item_int(0, **kw), 0.1)) == code
    assert model.missions.upload is None
    assert ack(gcs.send(item_int(1), 0.2)) == mav.MAV_MISSION_ERROR  # now unrequested


def test_unrequested_item_is_refused_with_mission_error() -> None:
    model, gcs = make()
    assert ack(gcs.send(item_int(0), 0.0)) == mav.MAV_MISSION_ERROR
    assert model.mission == []
    assert "unrequested" in requests(model, request="mission_item")[-1]["reason"]


def test_wrong_seq_and_other_sender() -> None:
    model, gcs = make()
    gcs.send(mav.MAVLink_mission_count_message(1, 1, 2), 0.0)
    assert ack(gcs.send(item_int(1), 0.1)) == mav.MAV_MISSION_INVALID_SEQUENCE
    other = Gcs(model, srcsys=77)
    assert ack(other.send(item_int(0), 0.2)) == mav.MAV_MISSION_DENIED
    assert ack(other.send(mav.MAVLink_mission_count_message(1, 1, 1), 0.2)) == mav.MAV_MISSION_DENIED
    assert ack(gcs.send(mav.MAVLink_mission_request_list_message(1, 1), 0.3)) == mav.MAV_MISSION_DENIED
    assert by_type(gcs.send(item_int(0), 0.4), "MISSION_REQUEST").seq == 1


def test_partial_upload_is_re_requested_then_cancelled() -> None:
    model, gcs = make()
    gcs.send(mav.MAVLink_mission_count_message(1, 1, 3), 0.0)
    gcs.send(item_int(0), 0.0)
    model.tick(REQUEST_RESEND + 0.1)
    out = model.take_outbox()
    assert [m.seq for _, m in out if m.get_type() == "MISSION_REQUEST"] == [1]
    model.tick(UPLOAD_TIMEOUT + 0.1)
    out = [m for _, m in model.take_outbox()]
    assert by_type(out, "MISSION_ACK").type == mav.MAV_MISSION_OPERATION_CANCELLED
    assert "Mission upload timeout" in [m.text for m in out if m.get_type() == "STATUSTEXT"]
    assert model.missions.upload is None and len(model.mission) == 1  # kept, as ArduPilot
    cancel = requests(model, answer="MISSION_ACK MAV_MISSION_OPERATION_CANCELLED")
    assert cancel[-1]["request"] == "mission_upload" and "timeout" in cancel[-1]["reason"]


def test_download_item_zero_is_home_and_past_the_end_is_an_error() -> None:
    model, gcs = make()
    upload(gcs, [item_int(0, x=1, y=2), item_int(1)])
    assert by_type(gcs.send(mav.MAVLink_mission_request_list_message(1, 1), 1.0),
                   "MISSION_COUNT").count == 2
    home = by_type(gcs.send(mav.MAVLink_mission_request_int_message(1, 1, 0), 1.0),
                   "MISSION_ITEM_INT")
    assert home.x == round(model.config.home_lat * 1e7)
    wp = by_type(gcs.send(mav.MAVLink_mission_request_message(1, 1, 1), 1.0), "MISSION_ITEM")
    assert abs(wp.x - LAT * 1e-7) < 1e-5
    replies = gcs.send(mav.MAVLink_mission_request_int_message(1, 1, 5), 1.0)
    assert by_type(replies, "MISSION_COUNT").count == 2 and ack(replies) == mav.MAV_MISSION_ERROR


def test_mavlink1_peer_and_clear_all() -> None:
    model = VehicleModel(VehicleConfig(), now=0.0)
    gcs = Gcs(model, version=1)
    replies = gcs.send(mav1.MAVLink_mission_count_message(1, 1, 1), 0.0)
    assert by_type(replies, "MISSION_REQUEST").seq == 0
    assert ack(gcs.send(mav1.MAVLink_mission_item_message(1, 1, 0, 3, WP, 0, 1, 0, 0, 0, 0,
                                                          35.7, -78.6, 10.0), 0.1)) == 0
    assert ack(gcs.send(mav1.MAVLink_mission_clear_all_message(1, 1), 0.2)) == 0
    assert model.mission == []


def arm_guided(model: VehicleModel, gcs: Gcs, now: float) -> None:
    gcs.send(mav.MAVLink_set_mode_message(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4), now)
    gcs.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, now=now)
    assert model.armed and model.mode == "GUIDED"


def test_mission_start_flies_the_mission_and_reports_items_reached() -> None:
    model, gcs = make(horizontal_speed=100.0, climb_rate=20.0, descent_rate=20.0)
    mission = [item_int(0), item_int(1, TAKEOFF, 0, 0, 20.0),
               item_int(2, x=LAT + 5000, y=LON + 5000, z=30.0), item_int(3, RTL_CMD, 0, 0, 0)]
    assert ack(upload(gcs, mission)) == 0
    arm_guided(model, gcs, 0.5)
    replies = gcs.command(mav.MAV_CMD_MISSION_START, now=1.0)
    assert by_type(replies, "COMMAND_ACK").result == mav.MAV_RESULT_ACCEPTED
    assert model.mode == "AUTO"
    reached, t = [], 1.0
    while t < 20 and model.armed:
        t += 0.1
        model.tick(t)
        reached += [m.seq for _, m in model.take_outbox() if m.get_type() == "MISSION_ITEM_REACHED"]
    assert reached == [1, 2, 3] and not model.armed
    assert [e.detail["seq"] for e in model.events("item_reached")] == [1, 2, 3]
    assert model.events("landed") and model.events("mission_complete")
    assert abs(model.lat - model.config.home_lat) < 1e-6


def test_auto_needs_a_mission_and_a_takeoff_when_armed_on_the_ground() -> None:
    model, gcs = make()
    arm_guided(model, gcs, 0.0)
    replies = gcs.command(mav.MAV_CMD_MISSION_START, now=0.1)
    assert by_type(replies, "COMMAND_ACK").result == mav.MAV_RESULT_FAILED
    upload(gcs, [item_int(0), item_int(1)], 0.2)
    replies = gcs.command(mav.MAV_CMD_MISSION_START, now=0.3)
    assert by_type(replies, "COMMAND_ACK").result == mav.MAV_RESULT_FAILED
    rec = requests(model, request="mission_start")[-1]
    assert rec["reason"] == "Auto: Missing Takeoff Cmd" and rec["answer"] == "MAV_RESULT_FAILED"


def test_mission_current_is_streamed() -> None:
    model, gcs = make()
    upload(gcs, [item_int(0), item_int(1)])
    cur = by_type(model.tick(0.0), "MISSION_CURRENT")
    assert cur.total == 1


def test_command_requests_are_recorded_with_the_reason() -> None:
    model, gcs = make(fix_withheld=True)
    gcs.command(mav.MAV_CMD_COMPONENT_ARM_DISARM, 1, now=0.0)
    rec = requests(model, request="arm")[-1]
    assert (rec["answer"], rec["result"], rec["reason"], rec["via"], rec["forced"]) == (
        "MAV_RESULT_FAILED", "denied", "PreArm: Need 3D Fix", "COMMAND_LONG", False)
    gcs.command(mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10, now=0.1)
    assert requests(model, request="takeoff")[-1]["reason"] == "Takeoff: not armed"
    gcs.send(mav.MAVLink_set_mode_message(1, mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, 4), 0.2)
    rec = requests(model, request="mode")[-1]
    assert rec["reason"] == "Flight mode change failed: GUIDED needs a position (no GPS fix)"
    assert (rec["mode"], rec["name"], rec["command"]) == ("GUIDED", "SET_MODE", None)

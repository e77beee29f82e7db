"""The vehicle survives what it is sent, over a real TCP link: hostile parameter, command,
mission, position-target and FTP messages (non-ASCII names, NaN/inf, out-of-range indexes,
wrong target ids, truncated frames, garbage) leave the parameter table as it was, raise
nothing inside the vehicle, and a later PARAM_REQUEST_LIST still returns every parameter.
Every request the peer made is a line of the ``--record`` file, with the answer and the
reason."""

from __future__ import annotations

import io
import json
import math
import time

from pymavlink import mavutil

from mcp_conform.vehicle import SimVehicle
from mcp_conform.vehicle.recordfile import RecordFile

MAV = mavutil.mavlink
INF, NAN = math.inf, math.nan
GARBAGE = bytes(range(256)) * 2  # its tail looks like the start of a long frame


def param_list(conn, timeout: float = 5.0) -> dict[str, float]:
    conn.mav.param_request_list_send(1, 1)
    got: dict[str, float] = {}
    count = None
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and (count is None or len(got) < count):
        m = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.2)
        if m is not None:
            got[m.param_id] = m.param_value
            count = m.param_count
    assert count is not None and len(got) == count, f"{len(got)} of {count} parameters"
    return got


def hostile(conn) -> int:
    """Send the hostile messages; return how many are requests addressed to the vehicle."""
    m = conn.mav
    sent = [
        m.param_set_encode(1, 1, b"\xc3\xa9T\xff\x80", 5.0, MAV.MAV_PARAM_TYPE_REAL32),
        m.param_set_encode(1, 1, b"RTL_ALT", NAN, MAV.MAV_PARAM_TYPE_INT32),
        m.param_set_encode(1, 1, b"RTL_ALT", INF, MAV.MAV_PARAM_TYPE_INT32),
        m.param_set_encode(1, 1, b"WPNAV_SPEED", -INF, MAV.MAV_PARAM_TYPE_REAL32),
        m.param_set_encode(1, 1, b"NOT_A_PARAM_NAME", 1.0, MAV.MAV_PARAM_TYPE_REAL32),
        m.param_set_encode(1, 1, b"", 1.0, MAV.MAV_PARAM_TYPE_REAL32),
        m.param_set_encode(1, 1, b" RTL_ALT", 1.0, MAV.MAV_PARAM_TYPE_REAL32),
        m.param_request_read_encode(1, 1, b"", 32767),
        m.param_request_read_encode(1, 1, b"", -2),
        m.param_request_read_encode(1, 1, b"\xfe\xfe", -1),
        m.command_long_encode(1, 1, MAV.MAV_CMD_DO_SET_MODE, 0, NAN, INF, 0, 0, 0, 0, 0),
        m.command_long_encode(1, 1, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0, INF, NAN, 0, 0, 0, 0, 0),
        m.command_long_encode(1, 1, MAV.MAV_CMD_REQUEST_MESSAGE, 0, NAN, 0, 0, 0, 0, 0, 0),
        m.command_long_encode(1, 1, MAV.MAV_CMD_REQUEST_MESSAGE, 0, 1e30, 0, 0, 0, 0, 0, 0),
        m.command_long_encode(1, 1, MAV.MAV_CMD_SET_MESSAGE_INTERVAL, 0, 30, NAN, 0, 0, 0, 0, 0),
        m.command_long_encode(1, 1, MAV.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 0, NAN),
        m.command_long_encode(1, 1, MAV.MAV_CMD_CONDITION_YAW, 0, NAN, 0, 0, NAN, 0, 0, 0),
        m.command_long_encode(1, 1, MAV.MAV_CMD_DO_CHANGE_SPEED, 0, NAN, INF, 0, 0, 0, 0, 0),
        m.command_long_encode(1, 1, 65535, 0, 0, 0, 0, 0, 0, 0, 0),
        m.command_int_encode(1, 1, 200, MAV.MAV_CMD_DO_REPOSITION, 0, 0, NAN, NAN, 0, 0,
                             2 ** 31 - 1, -2 ** 31, NAN),
        m.set_position_target_local_ned_encode(0, 1, 1, 250, 0, NAN, INF, 0, 0, 0, 0, 0, 0, 0, 0,
                                               0),
        m.set_position_target_global_int_encode(0, 1, 1, MAV.MAV_FRAME_GLOBAL_INT, 0,
                                                2 ** 31 - 1, 0, NAN, 0, 0, 0, 0, 0, 0, NAN, 0),
        m.request_data_stream_encode(1, 1, 99, 10, 7),
        m.mission_count_encode(1, 1, 65535, 0),
        m.mission_request_int_encode(1, 1, 9999, 0),
        m.mission_item_int_encode(1, 1, 4000, MAV.MAV_FRAME_GLOBAL, MAV.MAV_CMD_NAV_WAYPOINT, 0,
                                  1, NAN, INF, 0, 0, 2 ** 31 - 1, -2 ** 31, NAN, 0),
        m.mission_set_current_encode(1, 1, 65535),
        m.mission_clear_all_encode(1, 1, 77),
        m.file_transfer_protocol_encode(0, 1, 1, b"\xff" * 251),
        m.file_transfer_protocol_encode(0, 1, 1, b"\x01\x00\x00\xc8" + b"\0" * 247),
    ]
    to_others = [
        m.param_set_encode(99, 1, b"RTL_ALT", 1.0, MAV.MAV_PARAM_TYPE_INT32),
        m.command_long_encode(99, 1, MAV.MAV_CMD_COMPONENT_ARM_DISARM, 0, 1, 0, 0, 0, 0, 0, 0),
        m.mission_clear_all_encode(99, 1, 0),
    ]
    for msg in sent + to_others:
        conn.write(msg.pack(m))
        m.seq = (m.seq + 1) % 256
    conn.write(b"\xfd\x40\x00\x00\x07\xff\x01\x17\x00\x00")  # a truncated PARAM_SET frame
    conn.write(GARBAGE)
    return len(sent)


def garbage_reported(vehicle) -> bool:
    """The garbage's incomplete tail was reported stale: the vehicle has read every byte sent."""
    return any(u.reason.startswith("incomplete frame") and bytes(u.raw).endswith(GARBAGE[-2:])
               for u in vehicle.unparsed())


def test_hostile_messages_leave_the_table_as_it_was_and_every_request_is_recorded() -> None:
    stream = io.StringIO()
    record = RecordFile(stream, time.monotonic())
    with SimVehicle(on_event=record) as vehicle:
        conn = mavutil.mavlink_connection(vehicle.url, source_system=201, source_component=190)
        try:
            conn.wait_heartbeat(timeout=5)
            before = param_list(conn)
            lines_before = record.written
            requests = hostile(conn)
            # the garbage ends inside what looks like a long frame: once it is reported stale,
            # the next request is a frame of its own, not the rest of that one. Wait for that
            # report itself: "nothing held" also holds before the garbage has arrived, and a
            # request sent then is, rightly, read as the rest of the long frame.
            assert vehicle.wait_for(lambda: vehicle.holding() == 0
                                    and record.written >= lines_before + requests
                                    and garbage_reported(vehicle), 5.0)
            after = param_list(conn)
            assert after == before  # nothing stored, nothing lost
            assert not vehicle.events("error"), vehicle.events("error")
            assert vehicle.armed is False
        finally:
            conn.close()
    lines = [json.loads(line) for line in stream.getvalue().splitlines()]
    hostile_lines = lines[1:1 + requests]  # after the first PARAM_REQUEST_LIST
    assert len(hostile_lines) == requests and all(r["result"] == "denied" for r in hostile_lines
                                                 if r["request"].startswith("param_"))
    assert all(r["answer"] and ("reason" in r) for r in hostile_lines)
    assert [r["request"] for r in hostile_lines[:7]] == ["param_set"] * 7
    assert "unknown parameter" in hostile_lines[0]["reason"]
    assert lines[-1]["request"] == "param_list"
    assert not [r for r in lines if r.get("srcsys") != 201]  # the frames to system 99: none

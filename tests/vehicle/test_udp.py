"""The vehicle over UDP, as SITL serves it: pymavlink ground stations on udpin: and udpout:.

Each runs a whole session (heartbeat both ways, fix, GUIDED, arm, mission upload with the
handshake, RTL) and the vehicle's request records show each request with its answer."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import pytest
from pymavlink import mavutil

from mcp_conform.vehicle import SimVehicle
from tests.vehicle.gcs import MAV, WAIT, recv, run_session, upload_mission

pytestmark = pytest.mark.slow


def check_records(v: SimVehicle) -> None:
    reqs = [e.detail for e in v.events("request")]
    kinds = [(r["request"], r["via"], r["result"]) for r in reqs]
    assert ("mode", "SET_MODE", "accepted") in kinds
    assert ("arm", "COMMAND_LONG", "accepted") in kinds
    assert ("rtl", "COMMAND_LONG", "accepted") in kinds
    items = [r for r in reqs if r["request"] == "mission_item"]
    assert [r["seq"] for r in items] == [0, 1, 2, 3]
    assert all(r["result"] == "accepted" and r["via"] == "MISSION_ITEM_INT" for r in items)
    assert items[-1]["answer"] == "MISSION_ACK MAV_MISSION_ACCEPTED"
    assert v.frames("HEARTBEAT"), "the ground station's heartbeat never arrived"
    assert v.events("arm") and v.events("rtl") and v.mode == "RTL"


def test_ground_station_on_udpin_gets_the_udp_out_telemetry() -> None:
    gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255)
    try:
        port = gcs.port.getsockname()[1]
        v = SimVehicle(climb_rate=100.0)
        v.start(port=None, udp_out=[("127.0.0.1", port)])
        try:
            seen = run_session(gcs)
            assert seen["mode"] == seen["arm"] == seen["rtl"] == MAV.MAV_RESULT_ACCEPTED
            assert seen["mission"] == MAV.MAV_MISSION_ACCEPTED
            check_records(v)
            assert v.connected and v.connections == 1
            assert v.events("connect")[0].detail["transport"] == "udp"
        finally:
            v.close()
    finally:
        gcs.close()


def test_ground_station_on_udpout_reaches_the_udp_in_socket() -> None:
    v = SimVehicle(climb_rate=100.0)
    v.start(port=None, udp_in=("127.0.0.1", 0))
    gcs = mavutil.mavlink_connection(v.udp_in_url, source_system=255)
    try:
        assert not v.connected  # nobody has written yet
        seen = run_session(gcs)
        assert seen["mission"] == MAV.MAV_MISSION_ACCEPTED
        check_records(v)
    finally:
        gcs.close()
        v.close()


def test_mavlink1_peer_is_answered_in_mavlink1() -> None:
    v = SimVehicle()
    v.start(port=None, udp_in=("127.0.0.1", 0))
    gcs = mavutil.mavlink_connection(v.udp_in_url, source_system=255, dialect="ardupilotmega")
    gcs.mav.WIRE_PROTOCOL_VERSION = "1.0"
    try:
        gcs.mav.heartbeat_send(MAV.MAV_TYPE_GCS, MAV.MAV_AUTOPILOT_INVALID, 0, 0, 0,
                               force_mavlink1=True)
        recv(gcs, ["HEARTBEAT"], "heartbeat", heartbeat=False)
        deadline = time.monotonic() + WAIT
        while time.monotonic() < deadline:
            m = gcs.recv_match(type="GPS_RAW_INT", blocking=True, timeout=0.5)
            if m is not None:
                assert m.get_msgbuf()[0] == 0xFE
                return
        raise AssertionError("no telemetry")
    finally:
        gcs.close()
        v.close()


def test_cli_udp_out_and_record_file(tmp_path) -> None:
    gcs = mavutil.mavlink_connection("udpin:127.0.0.1:0", source_system=255)
    port = gcs.port.getsockname()[1]
    record = tmp_path / "requests.jsonl"
    proc = subprocess.Popen(
        [sys.executable, "-m", "mcp_conform.vehicle", "--no-tcp", "--udp-out", f"127.0.0.1:{port}",
         "--record", str(record)],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        env={**os.environ, "PYTHONUNBUFFERED": "1"})
    try:
        hb = recv(gcs, ["HEARTBEAT"], "vehicle heartbeat", timeout=30)  # a process start: seconds on a loaded host
        target = (hb.get_srcSystem(), hb.get_srcComponent())
        bad = [(MAV.MAV_CMD_NAV_WAYPOINT, 357713320, -786744210, 0.0)]
        gcs.mav.mission_count_send(*target, 1)
        recv(gcs, ["MISSION_REQUEST"], "item request")
        gcs.mav.mission_item_send(*target, 0, MAV.MAV_FRAME_GLOBAL, bad[0][0], 0, 1, 0, 0, 0, 0,
                                  357713320.0, -786744210.0, 10.0)
        ack = recv(gcs, ["MISSION_ACK"], "refusal")
        assert ack.type == MAV.MAV_MISSION_INVALID_PARAM5_X
        assert upload_mission(gcs, target, bad) == MAV.MAV_MISSION_ACCEPTED
    finally:
        proc.terminate()
        out, err = proc.communicate(timeout=10)
        gcs.close()
    assert proc.returncode == 143, err  # SIGTERM: docs/grammar.md
    assert "udp-out 127.0.0.1:" in out
    lines = [json.loads(line) for line in record.read_text().splitlines()]
    refused = [r for r in lines if r["via"] == "MISSION_ITEM"]
    assert refused and refused[0]["answer"] == "MISSION_ACK MAV_MISSION_INVALID_PARAM5_X"
    assert refused[0]["result"] == "denied" and refused[0]["mav_result"] == 10
    assert "degE7" in refused[0]["reason"] and abs(refused[0]["x"] - 357713320) < 64  # float32
    assert [r["request"] for r in lines].count("mission_upload") == 2


def _datagrams(frame_per_datagram: bool, seconds: float = 1.5) -> list[bytes]:
    """What a plain UDP socket reads of the vehicle's --udp-out telemetry."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        s.settimeout(0.2)
        v = SimVehicle(telemetry_hz=10.0)
        v.start(port=None, udp_out=[s.getsockname()], frame_per_datagram=frame_per_datagram)
        out: list[bytes] = []
        try:
            end = time.monotonic() + seconds
            while time.monotonic() < end and len(out) < 500:
                try:
                    out.append(s.recv(65535))
                except TimeoutError:
                    pass
        finally:
            v.close()
    return out


def _frames(data: bytes) -> list[str]:
    parser = mavutil.mavlink.MAVLink(None)
    parser.robust_parsing = True
    return [m.get_type() for m in (parser.parse_buffer(data) or [])]


def test_one_frame_per_datagram_for_ground_stations_that_read_one() -> None:
    """Issue 18 item 15: SITL packs a turn's frames into one datagram; seed 001's programs
    read one frame per datagram (the last) and never see GPS_RAW_INT. With the option each
    datagram holds exactly one whole frame, GPS_RAW_INT among them."""
    packed = _datagrams(False)
    assert any(len(_frames(d)) > 1 for d in packed), "the default packs frames (as SITL does)"
    single = _datagrams(True)
    assert single and all(len(_frames(d)) == 1 for d in single), [_frames(d) for d in single][:5]
    assert "GPS_RAW_INT" in {_frames(d)[0] for d in single}


def test_cli_frame_per_datagram_option() -> None:
    out = subprocess.run([sys.executable, "-m", "mcp_conform.vehicle", "--help"], capture_output=True, text=True,
                         timeout=60).stdout
    assert "--frame-per-datagram" in out

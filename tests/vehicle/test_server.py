"""The vehicle on a real loopback TCP socket, driven by pymavlink's own client."""

from __future__ import annotations

import os
import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest
from pymavlink import mavutil

from mcp_conform.vehicle import Event, SimVehicle, make_probe

WAIT = 5.0  # generous bound for anything that should happen within a few ticks


@pytest.fixture
def vehicle() -> Iterator[SimVehicle]:
    v = SimVehicle(sysid=1, gps_fix_delay=0.0, climb_rate=50.0, fix_withheld=False)
    v.start(host="127.0.0.1", port=0)
    yield v
    v.close()


def connect(v: SimVehicle) -> mavutil.mavfile:
    conn = mavutil.mavlink_connection(v.url, source_system=42, retries=0)
    assert conn.wait_heartbeat(timeout=WAIT) is not None
    return conn


def ack(conn: mavutil.mavfile, command: int) -> int:
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        m = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=0.5)
        if m is not None and m.command == command:
            return m.result
    raise AssertionError(f"no COMMAND_ACK for {command}")


def bounded(fn, timeout: float = WAIT) -> None:
    """Run a blocking pymavlink call (which has no timeout of its own) with a bound."""
    t = threading.Thread(target=fn, daemon=True)
    t.start()
    t.join(timeout)
    assert not t.is_alive(), f"{fn} did not return within {timeout} s"


def test_url_and_port(vehicle: SimVehicle) -> None:
    assert vehicle.port and vehicle.url == f"tcp:127.0.0.1:{vehicle.port}"
    assert not vehicle.connected and vehicle.connections == 0


def test_heartbeat_identifies_arducopter(vehicle: SimVehicle) -> None:
    conn = connect(vehicle)
    try:
        hb = conn.messages["HEARTBEAT"]
        assert hb.type == mavutil.mavlink.MAV_TYPE_QUADROTOR
        assert hb.autopilot == mavutil.mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA
        assert conn.flightmode == "STABILIZE"
        assert vehicle.wait_for(lambda: vehicle.connected, WAIT)
        assert vehicle.connections == 1
    finally:
        conn.close()


def test_wait_gps_fix_after_give_fix() -> None:
    with SimVehicle(fix_withheld=True) as v:
        conn = connect(v)
        try:
            gps = conn.recv_match(type="GPS_RAW_INT", blocking=True, timeout=WAIT)
            assert gps is not None and gps.fix_type == 0 and gps.lat == 0
            assert not v.has_fix
            conn.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_COMPONENT_ARM_DISARM,
                                       0, 1, 0, 0, 0, 0, 0, 0)
            assert ack(conn, 400) == mavutil.mavlink.MAV_RESULT_FAILED
            assert not v.armed
            v.give_fix()
            bounded(conn.wait_gps_fix)
            assert conn.messages["GPS_RAW_INT"].lat == 357713320
            assert v.first_time("fix") is not None
        finally:
            conn.close()


def test_arm_guided_takeoff_and_rtl(vehicle: SimVehicle) -> None:
    conn = connect(vehicle)
    try:
        conn.set_mode("GUIDED")
        assert ack(conn, 176) == mavutil.mavlink.MAV_RESULT_ACCEPTED
        conn.arducopter_arm()
        assert ack(conn, 400) == mavutil.mavlink.MAV_RESULT_ACCEPTED
        assert vehicle.armed and vehicle.mode == "GUIDED"
        bounded(conn.motors_armed_wait)
        conn.mav.command_long_send(1, 1, mavutil.mavlink.MAV_CMD_NAV_TAKEOFF, 0,
                                   0, 0, 0, 0, 0, 0, 10.0)
        assert ack(conn, 22) == mavutil.mavlink.MAV_RESULT_ACCEPTED
        assert conn.recv_match(type="GLOBAL_POSITION_INT", blocking=True, timeout=WAIT,
                               condition="GLOBAL_POSITION_INT.relative_alt>=9500")
        assert conn.recv_match(type="VFR_HUD", blocking=True, timeout=WAIT,
                               condition="VFR_HUD.alt>=9.5")
        conn.set_mode_rtl()
        assert ack(conn, 20) == mavutil.mavlink.MAV_RESULT_ACCEPTED
        assert vehicle.rtl_commanded and vehicle.mode == "RTL"
        assert vehicle.wait_for(lambda: not vehicle.armed, WAIT)
        kinds = [e.kind for e in vehicle.events() if e.kind in ("arm", "takeoff", "rtl",
                                                                "disarm")]
        assert kinds == ["arm", "takeoff", "rtl", "disarm"]
        assert vehicle.first_time("arm") < vehicle.first_time("rtl")
    finally:
        conn.close()


def test_set_mode_6_is_rtl(vehicle: SimVehicle) -> None:
    conn = connect(vehicle)
    try:
        conn.set_mode(6)
        assert ack(conn, 176) == mavutil.mavlink.MAV_RESULT_ACCEPTED
        assert vehicle.wait_for(lambda: vehicle.mode == "RTL", WAIT)
        assert vehicle.rtl_commanded
        assert conn.recv_match(type="HEARTBEAT", blocking=True, timeout=WAIT,
                               condition="HEARTBEAT.custom_mode==6")
    finally:
        conn.close()


def test_probes_are_counted_exactly(vehicle: SimVehicle) -> None:
    conn = connect(vehicle)
    try:
        conn.write(make_probe("t1"))
        conn.write(make_probe("t1", seq=1))
        conn.write(make_probe("t2", version=1))
        assert vehicle.wait_for(lambda: vehicle.probe_count("t2") == 1, WAIT)
        assert vehicle.wait_for(lambda: vehicle.probe_count("t1") == 2, WAIT)
        time.sleep(0.2)  # nothing more may arrive
        assert vehicle.probe_tokens() == {"t1": 2, "t2": 1}
        raws = [f.raw for f in vehicle.frames("STATUSTEXT")]
        assert raws[0] == make_probe("t1")
    finally:
        conn.close()


def test_garbage_does_not_kill_the_vehicle(vehicle: SimVehicle) -> None:
    conn = connect(vehicle)
    try:
        conn.write(bytes(range(256)) * 4 + os.urandom(3000))
        conn.close()
        conn = connect(vehicle)  # a new client is served
        conn.write(b"\x00garbage without start bytes\x01" + make_probe("after"))
        assert vehicle.wait_for(lambda: vehicle.probe_count("after") == 1, WAIT)
        assert vehicle.events("bad_data")
    finally:
        conn.close()


def test_client_reconnects_and_clients_are_concurrent(vehicle: SimVehicle) -> None:
    first = connect(vehicle)
    first.close()
    assert vehicle.wait_for(lambda: not vehicle.connected, WAIT)
    second = connect(vehicle)
    third = connect(vehicle)
    try:
        second.write(make_probe("two"))
        third.write(make_probe("three"))
        assert vehicle.wait_for(lambda: vehicle.probe_tokens() == {"two": 1, "three": 1}, WAIT)
        assert vehicle.connections == 3 and vehicle.connected
        assert {f.conn for f in vehicle.frames("STATUSTEXT")} == {2, 3}
        assert len(vehicle.events("connect")) == 3 and len(vehicle.events("disconnect")) == 1
    finally:
        second.close()
        third.close()


def test_vehicle_may_be_spoken_to_first(vehicle: SimVehicle) -> None:
    sock = socket.create_connection(("127.0.0.1", vehicle.port), timeout=WAIT)
    try:
        sock.sendall(make_probe("first"))
        assert vehicle.wait_for(lambda: vehicle.probe_count("first") == 1, WAIT)
    finally:
        sock.close()


def test_callbacks_and_reset(vehicle: SimVehicle) -> None:
    seen: list[Event] = []
    taps: list[tuple[str, int]] = []
    with SimVehicle(on_event=seen.append, on_frame=lambda t, d, c, raw: taps.append((d, c))) as v:
        conn = connect(v)
        try:
            conn.write(make_probe("cb"))
            assert v.wait_for(lambda: v.probe_count("cb") == 1, WAIT)
        finally:
            conn.close()
        assert any(e.kind == "probe" for e in seen)
        assert ("rx", 1) in taps and ("tx", 1) in taps
        v.reset_observations()
        assert v.probe_count("cb") == 0 and v.frames() == [] and v.first_time("probe") is None


def test_close_stops_threads_and_port_in_use_is_an_error(monkeypatch: pytest.MonkeyPatch) -> None:
    """close() ends every thread of the vehicle, the accepting, reading and UDP ones woken by
    their sockets' shutdown: with their wait between looks at the stop flag made longer than
    close() waits for them (``IDLE_WAIT``), none is left."""
    from mcp_conform.vehicle import server

    monkeypatch.setattr(server, "IDLE_WAIT", 60.0)
    before = set(threading.enumerate())
    v = SimVehicle()
    port = v.start(udp_in=("127.0.0.1", 0))
    conn = connect(v)
    with pytest.raises(OSError):
        SimVehicle().start(port=port)
    v.close()
    conn.close()
    leftover = [t for t in threading.enumerate() if t not in before and t.name.startswith("vehicle")]
    assert leftover == []
    assert not v.connected


def test_unparsed_bytes_are_kept_and_tapped(vehicle: SimVehicle) -> None:
    """MCP-PAY-8: what arrived altered (a truncated frame nothing followed, a corrupted one)
    is in ``unparsed()`` and on the frame tap as "rx"; the valid frame after it is answered
    as ever; the record is bounded and reset with the others."""
    from mcp_conform.vehicle.records import MAX_UNPARSED

    taps: list[tuple[str, bytes]] = []
    frame = make_probe("alt")
    corrupt = bytearray(frame)
    corrupt[20] ^= 0x10
    with SimVehicle(on_frame=lambda t, d, c, raw: taps.append((d, raw))) as v:
        sock = socket.create_connection(("127.0.0.1", v.port), timeout=WAIT)
        try:
            start = time.monotonic()
            sock.sendall(frame[:-3])
            assert v.wait_for(lambda: len(v.unparsed()) == 1, WAIT)
            (u,) = v.unparsed(since=start)
            assert (u.raw, u.length, u.conn) == (frame[:-3], len(frame) - 3, 1) and u.t <= u.seen
            assert v.holding() == 0
            sock.sendall(frame[-3:] + bytes(corrupt) + make_probe("good"))
            assert v.wait_for(lambda: v.probe_count("good") == 1, WAIT)
            assert v.probe_count("alt") == 1  # the late rest completed the frame: delivered
            assert bytes(corrupt) in [x.raw for x in v.unparsed()]
            assert ("rx", frame[:-3]) in taps and ("rx", bytes(corrupt)) in taps
        finally:
            sock.close()
        v.reset_observations()
        assert v.unparsed() == []
    assert MAX_UNPARSED <= 1000


def test_parameter_list_is_paced_in_batches() -> None:
    """MAV-PRM-3 (GCS_Param.cpp ``queued_param_send``): a PARAM_REQUEST_LIST's PARAM_VALUEs
    leave the server PARAM_BATCH at a time, each batch its own send (the tap's time), every
    index once; a second request gets the whole list again. Structural, no speed asserted."""
    from pymavlink.dialects.v20 import ardupilotmega as mav

    from mcp_conform.vehicle.server import PARAM_BATCH

    parser = mav.MAVLink(None)
    sends: dict[float, int] = {}

    def tap(t: float, direction: str, conn: int, raw: bytes) -> None:
        if direction == "tx" and parser.decode(bytearray(raw)).get_type() == "PARAM_VALUE":
            sends[t] = sends.get(t, 0) + 1

    def listed(conn: mavutil.mavfile) -> dict[int, Any]:
        conn.mav.param_request_list_send(1, 1)
        got: dict[int, Any] = {}
        deadline = time.monotonic() + WAIT
        while time.monotonic() < deadline and (not got or len(got) < next(iter(got.values())).param_count):
            m = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
            if m is not None:
                got[m.param_index] = m
        return got

    with SimVehicle(on_frame=tap) as v:
        conn = connect(v)
        try:
            got = listed(conn)
            count = next(iter(got.values())).param_count
            assert sorted(got) == list(range(count)) and count > 2 * PARAM_BATCH
            assert v.wait_for(lambda: sum(sends.values()) >= count, WAIT)
            first = dict(sends)
            assert sorted(listed(conn)) == list(range(count))
        finally:
            conn.close()
    assert max(first.values()) <= PARAM_BATCH and sum(first.values()) == count
    assert len(first) >= -(-count // PARAM_BATCH)

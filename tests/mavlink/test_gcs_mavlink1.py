"""``mcp-conform --protocol mavlink --role gcs --mavlink1`` (issue 39): the runner's vehicle
speaks MAVLink 1 on every link from the start (``harness.mavlink_gcs_session.Mavlink1Link``,
as ``mcp-vehicle --mavlink1`` and ArduPilot on a port whose SERIALn_PROTOCOL is 1), for a ground
station built on MAVLink 1 headers (seed 001's C programs: tests/mavlink/test_seed001_gcs.py).

The reference ground station's own code in the simulator (``sim.gcs_role``) over every
transport: every frame the runner's vehicle sent is a MAVLink 1 frame, and the ground station
gets the verdicts it gets against the MAVLink 2 vehicle (every case passed: nothing the cases
or the monitor read of the ground station depends on the vehicle's wire version). The link
itself: a message MAVLink 1 cannot carry (an id above 255) is not sent and takes no sequence
number; one with extension fields goes out without them (MAV-HB-10: a whole MAVLink 1 frame)."""

from __future__ import annotations

import collections
import socket

import pytest

from mcp_conform.harness.mavlink_gcs_session import Mavlink1Link
from mcp_conform.sim.gcs_role import run_gcs_cases
from mcp_conform.spec import MAVLINK
from mcp_conform.traceio.mavlink import MavFrame, open_trace, version_of

mav = MAVLINK.dialect


def _versions(path) -> collections.Counter:
    """(direction, wire version) of every frame of a run's capture: tx the runner's vehicle's."""
    return collections.Counter((f.direction, f.version) for f in open_trace(path) if isinstance(f, MavFrame))


@pytest.mark.parametrize("transport", ["tcp", "udp", "udpout"])
def test_the_vehicle_speaks_mavlink1_and_the_verdicts_stay(tmp_path, transport):
    one = run_gcs_cases(None, transport=transport, extra=("--mavlink1", "--capture", str(tmp_path / "v1.mcap")))
    two = run_gcs_cases(None, transport=transport, extra=("--capture", str(tmp_path / "v2.mcap")))
    v1, v2 = _versions(tmp_path / "v1.mcap"), _versions(tmp_path / "v2.mcap")
    assert v1[("tx", 1)] > 100 and v1[("tx", 2)] == 0, v1  # the runner's vehicle: MAVLink 1 only
    assert v2[("tx", 2)] > 100 and v2[("tx", 1)] == 0, v2  # without the option: MAVLink 2, as before
    assert v1[("rx", 2)] > 0, v1  # the reference ground station's own frames, judged as they come
    assert one.report["parameters"]["mavlink1"] is True and two.report["parameters"]["mavlink1"] is False
    outcomes = [{c["id"]: c["outcome"] for c in run.report["cases"]} for run in (one, two)]
    assert outcomes[0] == outcomes[1] and set(outcomes[0].values()) == {"passed"}, one.explain()
    assert one.report["monitor"]["violations"] == [], one.explain()


def test_the_link_packs_mavlink1_and_drops_what_it_cannot_carry():
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind(("127.0.0.1", 0))
    rx.settimeout(5)
    link = Mavlink1Link("udpout", rx.getsockname(), None, ids=(1, 1))
    try:
        beat = link.encoder.heartbeat_encode(mav.MAV_TYPE_QUADROTOR, mav.MAV_AUTOPILOT_ARDUPILOTMEGA, 0, 0,
                                             mav.MAV_STATE_STANDBY)
        link.send(beat)
        link.send(mav.MAVLink_device_op_read_message(1, 1, 7, 0, 0, 0, b"", 0, 0))  # id 11000: no MAVLink 1 frame
        link.send(mav.MAVLink_mission_request_int_message(255, 190, 3, mav.MAV_MISSION_TYPE_MISSION))
        frames = [rx.recv(300) for _ in range(2)]
    finally:
        link.close()
        rx.close()
    assert [version_of(f) for f in frames] == [1, 1] and [f[0] for f in frames] == [0xFE, 0xFE]
    assert [f[2] for f in frames] == [0, 1]  # seq: the dropped message took none
    assert frames[1][1] == 4  # MISSION_REQUEST_INT's MAVLink 1 payload: seq, target system, component
    assert [name for _, name, _ in link.sent] == ["HEARTBEAT", "MISSION_REQUEST_INT"]
    parsed = mav.MAVLink(None).parse_buffer(frames[1])
    assert parsed[0].seq == 3 and parsed[0].get_srcSystem() == 1

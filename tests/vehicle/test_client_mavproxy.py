"""MAVProxy 1.8 against the simulated vehicle, over TCP and UDP, as its own process.

Headless (``--daemon --non-interactive``, as a companion computer runs it): it has every
parameter soon after the link is up. Issue 35: it waited 12 s for an MAVFTP answer before it
fell back to PARAM_REQUEST_LIST; ArduPilot answers MAVFTP at once. The issue's figure is
"< 5 s": the time is printed, and only a bound well below the 12 s FTP timeout is asserted.

Its console driven through a pipe (as ArduPilot's autotest drives MAVProxy): ``mode GUIDED``,
``arm throttle``, ``wp load`` and ``wp save`` round trip, no false "fence breach" (SYS_STATUS
carries the geofence health bit ArduPilot sets).
"""

from __future__ import annotations

import pytest
from pymavlink import mavwp

from tests.vehicle.clients import (
    TRANSPORTS,
    WAIT,
    MavproxyProcess,
    mavproxy_command,
    pymavlink_params,
    served,
    unrecorded_requests,
    wait_until,
)

pytestmark = pytest.mark.slow
#: Well below MAVProxy's 12 s MAVFTP timeout, well above the issue's "< 5 s" (a loaded
#: machine must not fail it); the figure itself is printed.
PARAMS_BOUND = 9.0

MISSION = """QGC WPL 110
0\t1\t0\t16\t0\t0\t0\t0\t35.771332\t-78.674421\t0\t1
1\t0\t3\t22\t0\t0\t0\t0\t0\t0\t10\t1
2\t0\t3\t16\t0\t0\t0\t0\t35.771103\t-78.674659\t10\t1
3\t0\t3\t16\t0\t0\t0\t0\t35.7715\t-78.6742\t12\t1
"""


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_headless_mavproxy_has_every_parameter_soon(transport: str, tmp_path) -> None:
    mavproxy_command()
    with served(transport) as (sim, link):
        expected = pymavlink_params(link)
        with MavproxyProcess(link, str(tmp_path)) as mp:
            t_link, _ = mp.expect(r"Detected vehicle", WAIT)
            t_params, found = mp.expect(r"Received (\d+) parameters", PARAMS_BOUND + WAIT)
            took = t_params - t_link
            print(f"MAVProxy over {transport}: every parameter {took:.2f} s after the vehicle "
                  f"was detected ({t_params:.2f} s after start)")
            assert int(found.group(1)) == len(expected)
            assert took < PARAMS_BOUND, (
                f"MAVProxy took {took:.1f} s for the parameters (its MAVFTP timeout is 12 s)\n"
                f"{mp.tail()}")
            assert not mp.printed(r"FTP: request timed out"), mp.tail()
        assert not unrecorded_requests(sim), unrecorded_requests(sim)


def same_items(a: mavwp.MAVWPLoader, b: mavwp.MAVWPLoader) -> list[str]:
    """Differences between two loaded missions: each item's command, and frame and position
    but item 0's (ArduPilot answers item 0 with its home, AP_Mission::read_cmd_from_storage)."""
    diffs = []
    if a.count() != b.count():
        return [f"{a.count()} items vs {b.count()}"]
    for i in range(a.count()):
        x, y = a.wp(i), b.wp(i)
        for field in ("command",) if i == 0 else ("command", "frame", "x", "y", "z"):
            u, v = getattr(x, field), getattr(y, field)
            if abs(float(u) - float(v)) > 1e-5:
                diffs.append(f"item {i} {field}: {u} vs {v}")
    return diffs


@pytest.mark.parametrize("transport", TRANSPORTS)
def test_mavproxy_console_mode_arm_and_wp_round_trip(transport: str, tmp_path) -> None:
    mavproxy_command()
    src, out = tmp_path / "mission.txt", tmp_path / "saved.txt"
    src.write_text(MISSION)
    with served(transport) as (sim, link), \
            MavproxyProcess(link, str(tmp_path), console=True) as mp:
        mp.expect(r"Detected vehicle", WAIT)
        mp.send("mode GUIDED")
        mp.expect(r"COMMAND_ACK: DO_SET_MODE: ACCEPTED", WAIT)
        assert sim.mode == "GUIDED"
        wait_until(lambda: sim.has_fix, WAIT, "fix")
        mp.send("arm throttle")
        mp.expect(r"COMMAND_ACK: COMPONENT_ARM_DISARM: ACCEPTED", WAIT)
        assert sim.armed
        mp.send(f"wp load {src}")
        mp.expect(r"Sent all 4 waypoints", WAIT)
        mp.expect(r"MISSION_ACK: TYPE_MISSION: ACCEPTED", WAIT)
        assert [(i["command"], i["z"]) for i in sim.mission] == [
            (16, 0.0), (22, 10.0), (16, 10.0), (16, 12.0)]
        mp.send(f"wp save {out}")
        mp.expect(r"Saved 4 waypoints to", WAIT)
        sent, saved = mavwp.MAVWPLoader(), mavwp.MAVWPLoader()
        sent.load(str(src))
        saved.load(str(out))
        assert not same_items(sent, saved), same_items(sent, saved)
        mp.send("mode LAND")
        mp.expect(r"COMMAND_ACK: DO_SET_MODE: ACCEPTED", WAIT)
        assert sim.mode == "LAND"
        assert not mp.printed(r"fence breach"), (
            f"MAVProxy shows a fence breach (SYS_STATUS geofence health bit):\n{mp.tail()}")
        assert not unrecorded_requests(sim), unrecorded_requests(sim)

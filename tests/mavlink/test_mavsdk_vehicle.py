"""``mcp-conform --protocol mavlink`` against a vehicle no one here wrote: MAVSDK's server side
(tests/mavlink/mavsdk_vehicle.py: ``mavsdk`` 4.x, the C++ core with ParamServer,
MissionRawServer, ActionServer and TelemetryServer, as MAVSDK's ``autopilot_server`` example
builds it), spawned by the runner over TCP and over UDP. Our vehicle is not in the loop.

The outcome established by hand and pinned here (docs/guide/mavlink-vehicle.md, "What other
implementations get"): every case passes but one, MAV-CMD-5. A command no server plugin claims
(the case's 65535, no MAV_CMD; MAV_CMD_DO_SET_SERVO too) gets no COMMAND_ACK at all:
MAVSDK's ``MavlinkCommandReceiver::receive_command_long`` answers only through a registered
handler, and its plugins keep silent on purpose ("Let's hope someone else answers", MAVSDK PR
#2423), where MAV_RESULT_UNSUPPORTED is common.xml's "Command is not supported (unknown)" and
mavlink.io's command protocol has a command left unanswered resent as lost. A real departure
of MAVSDK from mavlink.io, not a false alarm: the case sends a well-formed COMMAND_LONG to the
vehicle's own IDs, and the same vehicle acknowledges MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
by COMMAND_LONG and COMMAND_INT within the same wait (MAV-CMD-1, 2 pass).
"""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from tests.forkserver import run_module

pytestmark = pytest.mark.slow

VEHICLE = Path(__file__).with_name("mavsdk_vehicle.py")
#: the one failure, its rule and case
FINDINGS = {"MAV-CMD-5": {"CMD/test_unknown_command_is_unsupported"}}


@pytest.fixture(scope="module")
def mavsdk_version() -> str:
    """The installed MAVSDK's version, its core created and destroyed once; the tests are
    skipped with the reason when the package or its native library cannot start here."""
    probe = ("import mavsdk; from mavsdk import ComponentType, Configuration, Mavsdk; "
             "m = Mavsdk(Configuration.create_with_component_type(ComponentType.AUTOPILOT)); "
             "print(mavsdk.__version__, m.version()); m.destroy()")
    try:
        proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=30)
    except subprocess.TimeoutExpired:
        pytest.skip("MAVSDK's core did not start within 30 s")
    if proc.returncode != 0:
        lines = (proc.stderr or proc.stdout).strip().splitlines()
        pytest.skip(f"MAVSDK cannot start on this machine: {lines[-1] if lines else proc.returncode}")
    return proc.stdout.strip()


@pytest.mark.parametrize("transport", ["tcp", "udp"])
def test_mavsdk_server_fails_only_the_unacknowledged_unknown_command(tmp_path, transport, mavsdk_version):
    """The whole suite against MAVSDK's server side: exit 1, every case passed but
    MAV-CMD-5's, none skipped; that failure says no COMMAND_ACK came, with the evidence."""
    out = tmp_path / "r.json"
    spawn = (f"{sys.executable} {VEHICLE} --mavlink {transport}:{{target_host}}:{{target_port}} "
             "--duration 200")
    proc = run_module("conformance", ["--protocol", "mavlink", "--mavlink", transport, "--spawn", spawn,
                                      "--json", str(out)], timeout=240)
    text = proc.stdout + proc.stderr
    assert out.exists(), text
    doc = json.loads(out.read_text())
    assert doc["error"] in (None, ""), (mavsdk_version, doc["error"], text)
    failed_rules = {r for r, o in doc["rules"].items() if o in ("failed", "warned", "error")}
    failed_cases = {c["id"] for c in doc["cases"] if c["outcome"] not in ("passed", "info")}
    assert proc.returncode == 1, text
    assert failed_rules == set(FINDINGS), (mavsdk_version, text)
    assert failed_cases == set().union(*FINDINGS.values()), (mavsdk_version, text)
    assert {c["outcome"] for c in doc["cases"]} == {"passed", "failed"}, text
    case = next(c for c in doc["cases"] if c["outcome"] == "failed")
    assert case["failed_rule"] == "MAV-CMD-5" and case["actual"] == "no COMMAND_ACK", case
    # the vehicle does acknowledge the commands it has a handler for, so silence is not the link
    assert {r for r, o in doc["rules"].items() if o == "passed"} >= {
        "MAV-HB-1", "MAV-CMD-1", "MAV-CMD-2", "MAV-CMD-14", "MAV-PRM-1", "MAV-PRM-7", "MAV-MIS-1", "MAV-MIS-9"}

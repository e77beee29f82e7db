"""``mcp-conform --protocol mavlink`` against a vehicle no one here wrote: MAVSDK's server side
(tests/mavlink/mavsdk_vehicle.py: ``mavsdk`` 4.x, the C++ core with ParamServer,
MissionRawServer, ActionServer and TelemetryServer, as MAVSDK's ``autopilot_server`` example
builds it), spawned by the runner over TCP and over UDP. Our vehicle is not in the loop.

The outcome established by hand and pinned here (docs/guide/mavlink-vehicle.md, "What other
implementations get"): two MUST rules fail, MAV-CMD-5 and MAV-MIS-10; two SHOULD rules warn;
five cases cannot judge it. MAV-CMD-5: a command no server plugin claims
(the case's 65535, no MAV_CMD; MAV_CMD_DO_SET_SERVO too) gets no COMMAND_ACK at all:
MAVSDK's ``MavlinkCommandReceiver::receive_command_long`` answers only through a registered
handler, and its plugins keep silent on purpose ("Let's hope someone else answers", MAVSDK PR
#2423), where MAV_RESULT_UNSUPPORTED is common.xml's "Command is not supported (unknown)" and
mavlink.io's command protocol has a command left unanswered resent as lost. A real departure
of MAVSDK from mavlink.io, not a false alarm: the case sends a well-formed COMMAND_LONG to the
vehicle's own IDs, and the same vehicle acknowledges MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
by COMMAND_LONG and COMMAND_INT within the same wait (MAV-CMD-1, 2 pass).

MAV-MIS-10: the deprecated MISSION_ITEM is ignored in an upload (``ReceiveIncomingMission``
registers only MISSION_ITEM_INT: the vehicle asks for seq 0 again until it gives up) and
MISSION_REQUEST is never answered with an item (``SendOutgoingMission``: "We only support int,
so we nack this"), where mavlink.io's mission page says "Protocol implementations must also
support MISSION_ITEM and MISSION_REQUEST in the same way": MAVSDK's choice, on purpose.
Warned: MAV-MIS-18 (a MISSION_ACK MAV_MISSION_OPERATION_CANCELLED during an upload is not
handled: the requests go on) and MAV-PRM-12 (an unknown name is only logged, "Ignoring
request_read message - param name not found", no STATUSTEXT). Skipped, with the reason: the
IN_PROGRESS cases (the calibration gets no COMMAND_ACK, as MAV-CMD-5's command), MAV-MIS-7
(an item with command 65535 is accepted: no failed upload), MAV-MIS-11 (no item for
MISSION_REQUEST), MAV-PRM-3 (a list of 4 is too short to judge its pacing).
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
#: the failures: rule -> its cases; the warned rules; the cases that cannot judge MAVSDK
FINDINGS = {"MAV-CMD-5": {"CMD/test_unknown_command_is_unsupported"},
            "MAV-MIS-10": {"MIS/test_deprecated_item_messages_still_work"}}
WARNINGS = {"MAV-MIS-18", "MAV-PRM-12"}
CANNOT_JUDGE = {"CMD/test_command_in_progress_ends", "CMD/test_command_again_while_in_progress_is_busy",
                "MIS/test_failed_upload_keeps_the_plan", "MIS/test_deprecated_request_gets_the_int_item",
                "PRM/test_list_is_paced"}


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
def test_mavsdk_server_fails_the_unknown_command_and_the_deprecated_items(tmp_path, transport, mavsdk_version):
    """The whole suite against MAVSDK's server side: exit 1, MAV-CMD-5's and MAV-MIS-10's
    cases failed, MAV-MIS-18 and MAV-PRM-12 warned, the known cases skipped, every other
    case passed; MAV-CMD-5's failure says no COMMAND_ACK came, with the evidence."""
    out = tmp_path / "r.json"
    spawn = (f"{sys.executable} {VEHICLE} --mavlink {transport}:{{target_host}}:{{target_port}} "
             "--duration 200")
    proc = run_module("conformance", ["--protocol", "mavlink", "--mavlink", transport, "--spawn", spawn,
                                      "--json", str(out)], timeout=240)
    text = proc.stdout + proc.stderr
    assert out.exists(), text
    doc = json.loads(out.read_text())
    assert doc["error"] in (None, ""), (mavsdk_version, doc["error"], text)
    failed_rules = {r for r, o in doc["rules"].items() if o in ("failed", "error")}
    failed_cases = {c["id"] for c in doc["cases"] if c["outcome"] in ("failed", "error")}
    assert proc.returncode == 1, text
    assert failed_rules == set(FINDINGS), (mavsdk_version, text)
    assert failed_cases == set().union(*FINDINGS.values()), (mavsdk_version, text)
    assert {r for r, o in doc["rules"].items() if o == "warned"} == WARNINGS, (mavsdk_version, text)
    assert {c["id"] for c in doc["cases"] if c["outcome"] == "skipped"} == CANNOT_JUDGE, (mavsdk_version, text)
    assert {c["outcome"] for c in doc["cases"]} == {"passed", "failed", "warned", "skipped"}, text
    case = next(c for c in doc["cases"] if c["failed_rule"] == "MAV-CMD-5")
    assert case["actual"] == "no COMMAND_ACK", case
    # the vehicle does acknowledge the commands it has a handler for, so silence is not the link:
    # these rules' cases pass; a row the trace monitor proved violated only as the findings'
    # consequence (MAV-CMD-1: the unknown command's ACK never came) says "consequence", naming them
    rows = doc["rules"]
    assert {r for r, o in rows.items() if o in ("passed", "consequence")} >= {
        "MAV-HB-1", "MAV-CMD-1", "MAV-CMD-2", "MAV-CMD-14", "MAV-PRM-1", "MAV-PRM-7", "MAV-MIS-1", "MAV-MIS-4",
        "MAV-MIS-5", "MAV-MIS-6", "MAV-MIS-9", "MAV-MIS-12", "MAV-MIS-16", "MAV-MIS-17", "MAV-MIS-19"}, rows
    roots = {f["rule"]: set(f["consequence_of"]) for f in doc["failures"]
             if f.get("source") == "monitor" and f["consequence_of"]}
    assert {r for r, o in rows.items() if o == "consequence"} == set(roots), (rows, roots)
    assert all(rs and rs <= set(FINDINGS) | WARNINGS for rs in roots.values()), roots

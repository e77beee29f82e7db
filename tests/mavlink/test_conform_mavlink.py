"""``mcp-conform --protocol mavlink`` (role vehicle, issue 39) end to end: our reference
vehicle (``mcp-vehicle``) fails no MUST rule over TCP and UDP, spawned by the runner and
attached, and warns exactly the SHOULD rules it breaks as ArduCopter does (``KNOWN_WARNINGS``,
each with its erratum); each faulty vehicle (tests/mavlink/faulty_vehicle.py: the reference
vehicle behind a proxy that changes one thing) fails exactly the MUST rule of its fault and no
other, its warnings among the known ones.

MAV-CMD-14's command for another component of the vehicle's system: mavlink.io's routing page
has only matching IDs and broadcasts processed, and our vehicle leaves it alone; ArduPilot
4.x acts on it (MAVLink_routing.cpp: ``if (!forwarded && match_system) { process_locally =
true; }`` for a component it has no route to), which the fault ``acts-for-other-component``
plays."""

from __future__ import annotations

import json
import socket
import sys
from pathlib import Path

import pytest

from mcp_conform.vehicle.ports import free_port
from tests.forkserver import run_module

pytestmark = pytest.mark.slow

FAULTY = Path(__file__).with_name("faulty_vehicle.py")


def run(tmp_path: Path, *args: str, timeout: float = 240) -> tuple[int, dict, str]:
    out = tmp_path / "r.json"
    proc = run_module("conformance", ["--protocol", "mavlink", "--json", str(out), *args], timeout=timeout)
    assert out.exists(), proc.stdout + proc.stderr
    return proc.returncode, json.loads(out.read_text()), proc.stdout + proc.stderr


#: the SHOULD rules our vehicle breaks as ArduCopter does (the spec's errata and ArduPilot's
#: sources): warned, never failed
KNOWN_WARNINGS = {
    "MAV-MIS-5": "E-1: ArduPilot answers an item out of sequence with MAV_MISSION_INVALID_SEQUENCE",
    "MAV-MIS-7": "E-2: ArduPilot's uploads are not atomic",
    "MAV-MIS-18": "E-2: ArduPilot cannot be cancelled",
    "MAV-MIS-11": "E-6: ArduPilot answers MISSION_REQUEST with MISSION_ITEM",
    "MAV-MIS-12": "E-9: ArduPilot requests upload items with MISSION_REQUEST",
    "MAV-PRM-12": "GCS_Param.cpp's param_io_timer returns in silence for an unknown name",
}
#: cases that cannot judge our vehicle, which runs no command long enough for IN_PROGRESS
CANNOT_JUDGE = {"CMD/test_command_in_progress_ends", "CMD/test_command_again_while_in_progress_is_busy"}


def failed(doc: dict) -> tuple[set[str], set[str]]:
    """The failed (or errored) rules, and the failed (or errored) cases."""
    rules = {r for r, o in doc["rules"].items() if o in ("failed", "error")}
    cases = {c["id"] for c in doc["cases"] if c["outcome"] in ("failed", "error")}
    return rules, cases


def warned(doc: dict) -> set[str]:
    return {r for r, o in doc["rules"].items() if o == "warned"}


def skipped(doc: dict) -> dict[str, str]:
    return {c["id"]: c["reason"] for c in doc["cases"] if c["outcome"] == "skipped"}


def expect_reference(doc: dict, out: str) -> None:
    """No MUST rule failed, the known warnings exactly, only the IN_PROGRESS cases skipped
    (with the reason)."""
    assert failed(doc) == (set(), set()), out
    assert warned(doc) == set(KNOWN_WARNINGS), out
    skips = skipped(doc)
    assert set(skips) == CANNOT_JUDGE and all("no command in progress" in r for r in skips.values()), skips


@pytest.mark.parametrize("transport", ["tcp", "udp", "udpout"])
def test_reference_vehicle_passes_every_case(tmp_path, transport):
    """The embedded reference vehicle over each transport: exit 0, no MUST rule failed, the
    known SHOULD warnings, only the IN_PROGRESS cases skipped."""
    rc, doc, out = run(tmp_path, "--mavlink", transport, "--capture", str(tmp_path / "run.mcap"))
    assert rc == 0, out
    expect_reference(doc, out)
    assert doc["role"] == "vehicle" and doc["spec"]["protocol"] == "MAV"
    assert {r for r, o in doc["rules"].items() if o == "passed"} >= {
        "MAV-HB-1", "MAV-CMD-1", "MAV-CMD-5", "MAV-PRM-1", "MAV-PRM-3", "MAV-PRM-11", "MAV-MIS-1", "MAV-MIS-4", "MAV-MIS-6",
        "MAV-MIS-9", "MAV-MIS-10", "MAV-MIS-16", "MAV-MIS-17", "MAV-MIS-19"}
    from mcap.reader import make_reader

    with open(tmp_path / "run.mcap", "rb") as fh:
        topics = {ch.topic for _, ch, _ in make_reader(fh).iter_messages()}
    assert "/mavlink" in topics and "/conformance/case" in topics, topics


def test_attached_vehicle_passes(tmp_path):
    """A vehicle the runner did not start, reached at tcp:HOST:PORT (SITL's way)."""
    import subprocess

    port = free_port(kind=socket.SOCK_STREAM)
    vehicle = subprocess.Popen([sys.executable, "-m", "mcp_conform.vehicle", "-q", "--listen",
                                f"127.0.0.1:{port}", "--duration", "200"])
    try:
        rc, doc, out = run(tmp_path, "--target", f"tcp:127.0.0.1:{port}", "--startup-timeout", "10",
                           "--select", "HB", "CMD")
        assert rc == 0 and failed(doc) == (set(), set()), out
        assert doc["target"].startswith("tcp:127.0.0.1:"), doc["target"]
    finally:
        vehicle.terminate()
        vehicle.wait(10)


FAULTS = {
    "no-unsupported-ack": ("MAV-CMD-5", {"CMD/test_unknown_command_is_unsupported"}),
    "type-gcs": ("MAV-HB-3", {"HB/test_heartbeat_names_a_vehicle_and_its_flight_stack"}),
    "double-ack": ("MAV-CMD-3", {"CMD/test_command_long_gets_one_ack", "CMD/test_command_int_gets_one_ack",
                                 "CMD/test_retransmission_is_answered_again"}),
    "acts-for-other-system": ("MAV-CMD-14", {"CMD/test_command_for_another_system_is_left_alone"}),
    "acts-for-other-component": ("MAV-CMD-14", {"CMD/test_command_for_another_component_is_left_alone"}),
    "bad-param-type": ("MAV-PRM-10", {"PRM/test_names_and_types_of_the_list"}),
    "download-param1": ("MAV-MIS-9", {"MIS/test_download_is_the_upload"}),
    "creates-unknown-param": ("MAV-PRM-11", {"PRM/test_unknown_name_creates_nothing"}),
    "clear-keeps-plan": ("MAV-MIS-13", {"MIS/test_clear_all"}),
    "out-of-sequence-stalls": ("MAV-MIS-4", {"MIS/test_out_of_sequence_item_is_recovered"}),
    "ignores-mission-request": ("MAV-MIS-10", {"MIS/test_deprecated_item_messages_still_work"}),
    "mission-type-lost": ("MAV-MIS-16", {"MIS/test_plan_types_are_kept_apart"}),
    "set-current-ignored": ("MAV-MIS-15", {"MIS/test_set_current"}),
    "untruncated": ("MAV-HB-12", {"HB/test_mavlink2_payloads_are_truncated"}),
    "seq-gaps": ("MAV-HB-11", {"HB/test_sequence_numbers_count_up"}),
    "abandoned-stays-busy": ("MAV-MIS-6", {"MIS/test_abandoned_upload_ends"}),
    "clear-ack-type-all": ("MAV-MIS-17", {"MIS/test_mission_types_are_mav_mission_types"}),
}


@pytest.mark.parametrize("fault", ["none", *FAULTS])
def test_each_faulty_vehicle_fails_its_rule_and_no_other(tmp_path, fault):
    """The whole suite against the reference vehicle behind the proxy: no fault, the
    reference's outcome; each fault, its rule's cases and no other MUST rule, no warning but
    the known ones, the rule's text in the terminal report."""
    spawn = f"{sys.executable} {FAULTY} --listen {{target_host}}:{{target_port}} --fault {fault} --duration 200"
    rc, doc, out = run(tmp_path, "--spawn", spawn)
    rules, cases = failed(doc)
    if fault == "none":
        assert rc == 0, out
        expect_reference(doc, out)
        return
    rule, want = FAULTS[fault]
    assert rc == 1, out
    assert rules == {rule} and cases == want, out
    assert warned(doc) <= set(KNOWN_WARNINGS), out
    case = next(c for c in doc["cases"] if c["id"] in want)
    assert case["failed_rule"] == rule and case["expected"] and case["actual"], case


@pytest.mark.parametrize(("target", "says"), [
    ("ftp:127.0.0.1:5760", "'ftp' is not one of tcp, udp, udpin, udpout"),
    ("udp:127.0.0.1:{port}", "no HEARTBEAT from the vehicle within 1 s (MAV-HB-1)"),
])
def test_a_target_that_cannot_be_judged_is_one_line_exit_2(tmp_path, target, says):
    """A scheme pymavlink has not, and a UDP link nothing sends on: exit 2, the reason in one
    line, the JSON report written with it."""
    rc, doc, out = run(tmp_path, "--target", target.format(port=free_port()),
                       "--startup-timeout", "1")
    assert rc == 2 and says in doc["error"] and "Traceback" not in out, out

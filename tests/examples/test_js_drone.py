"""The suite against a Node.js drone no one here wrote the suite for (examples/mcp_js/drone/).

``drone.js`` was written from the protocol's documents alone, in Node's idiom: one thread, the
event loop (a ``dgram`` socket's 'message' handler that ACKs on receipt, a ``setTimeout`` per
outstanding message for its retransmission, a Map for the duplicate table, promises for the
autopilot: GPS lock before Mission_Ready, GUIDED, arm, take-off awaited to its altitude, the
mission upload, RTL after the pending actions); its MAVLink 2 codec reads message layouts and
CRC_EXTRAs from a JSON file ``gen_dialect.py`` writes from pymavlink's dialect XML, once a test
session (nothing generated is kept). It runs under ``mcp-conform --spawn`` at short timings
(``--rto 0.3 --ack-window 0.3``, the node given the same ``--rto``):

- the correct node, with and without the simulated vehicle, with the readings the documents
  leave open taken the other way (:data:`OTHER_READINGS`: ACK once the command's autopilot work
  is done, to the datagram's source address, from a socket of its own, exit after End_Mission),
  and with the least retry limit the spec allows (2, exiting when
  it gives up): exit 0, every rule the role can observe passed (MUST and SHOULD), the rest
  skipped or INFO;
- the same node busy longer (``--takeoff-alt 150``, some 7 s of climb, End_Mission's RTL queued
  behind it as MCP-BLK-7 asks): every rule judged, the BLK-7 case passed, and the trace
  monitor's BLK-7 window runs from the end of the take-off too (the vehicle's busy/idle events:
  it warned "no RTL within 3.2 s" before session 34's fix);
- a node whose retry limit is 1, below the least the spec allows: exiting when it gives up,
  MCP-RTX-1 failed and no other MUST; announcing again (a new Mission_Ready, the next seq),
  MCP-RTX-1 failed and MCP-SEQ-2 passed (the description identifies a retransmission by its
  repeated number: seq N had two copies);
- each deliberate fault (``--fault``) fails the rule it breaks, named by the rule's text, and no
  other MUST rule.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from mcp_conform.spec import RULES
from tests.forkserver import run_module
from tests.xdist_once import once

pytestmark = pytest.mark.slow

ROOT = Path(__file__).resolve().parents[2]
SOURCE = ROOT / "examples" / "mcp_js" / "drone"
RTO = "0.3"

#: rules a drone cannot show (the spec's observe: none for the drone role)
NOT_OBSERVABLE = {"MCP-SEQ-1", "MCP-RTX-4", "MCP-PAY-1", "MCP-PAY-4", "MCP-PAY-6"}
#: rules observed only on the node's MAVLink link: skipped without --mavlink
VEHICLE_ONLY = {"MCP-SEQ-3", "MCP-DUP-1", "MCP-DUP-2", "MCP-DUP-3", "MCP-BLK-4", "MCP-BLK-5",
                "MCP-BLK-7", "MCP-PAY-8"}
#: INFO rules (DUP-4's observation needs the vehicle)
INFO = {"MCP-SEQ-4", "MCP-TRN-1", "MCP-DUP-4"}


@pytest.fixture(scope="module")
def dialect(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """ardupilotmega's layouts and CRC_EXTRAs for drone.js, written once a test session."""
    node = shutil.which("node")
    if node is None:
        pytest.skip("node (Node.js) not installed: the JavaScript drone cannot run")

    def make(out: Path) -> dict[str, Path]:
        proc = subprocess.run([sys.executable, str(SOURCE / "gen_dialect.py"), str(out / "ardupilotmega.json")],
                              capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        return {"dialect": out / "ardupilotmega.json"}

    made = once(tmp_path_factory, "mcp_js_dialect", make)
    assert not list(SOURCE.glob("*.json")), "generated files must not be in the source tree"
    return Path(made["dialect"])


def run(tmp_path: Path, dialect: Path, mavlink: bool, *args: str, takeoff_alt: str = "2",
        node_args: str = "") -> tuple[int, dict[str, Any], str]:
    """``mcp-conform --spawn`` the drone at short timings; (exit code, JSON report, output)."""
    out = tmp_path / "r.json"
    node = (f"node {SOURCE / 'drone.js'} --id {{id}} --listen {{target_port}} --manager {{listen_host}}:{{listen_port}}"
            f" --dialect {dialect} --rto {RTO} {node_args}")
    extra = ["--mavlink"] if mavlink else []
    if mavlink:
        node += f" --mavlink {{mavlink}} --takeoff-alt {takeoff_alt}"
    proc = run_module("conformance", ["--spawn", node, *extra, "--rto", RTO, "--ack-window", RTO,
                                      "--json", str(out), *args], timeout=400)
    assert out.exists(), proc.stdout + proc.stderr
    return proc.returncode, json.loads(out.read_text()), proc.stdout + proc.stderr


def drone_rules() -> set[str]:
    """MCP's rules for a drone (the spec's roles: any or drone)."""
    return {r.id for r in RULES.values() if r.id.startswith("MCP-") and {"any", "drone"} & set(r.roles)}


def rule_text(rule: str) -> str:
    return " ".join(RULES[rule].text.split())


#: the readings the documents leave open that the node takes by default, the other way (README):
#: the ACK once the command's autopilot work is done (not on receipt), sent to the datagram's
#: source address (not the manager's configured one) from a socket of its own (an ephemeral
#: port), its own seq the sender's current number not taken (D-5); the node exits 0 once
#: End_Mission's RTL is done (no linger), its RTL NAV_RETURN_TO_LAUNCH by COMMAND_INT (not a
#: DO_SET_MODE), Mav_Passthrough frames forwarded in the commands' order (behind the autopilot
#: jobs), Mission_Ready with the drone's ID (D-3), a first seq about to wrap (MCP-SEQ-4), commands
#: from a src other than the manager's 0 ignored (D-10: MCP-ACK-3 and MCP-DUP-3 then skipped)
OTHER_READINGS = ("--ack-when-done --reply-to-source --send-socket --ack-seq same --exit-after-end"
                  " --rtl command_int --passthrough-queued --ready-payload id --first-seq 65535 --manager-only")
#: what D-10 leaves unobservable on a drone that takes commands from ID 0 alone
MANAGER_ONLY_SKIPPED = {"MCP-ACK-3", "MCP-DUP-3"}


@pytest.mark.parametrize(("mavlink", "node_args"),
                         [(False, ""), (True, ""), (True, OTHER_READINGS), (False, "--retries 2"),
                          (False, "--retries 2 --reannounce")],
                         ids=["no-vehicle", "vehicle", "vehicle-other-readings", "least-retry-limit",
                              "least-retry-limit-reannounce"])
def test_the_correct_drone_passes(dialect: Path, tmp_path: Path, mavlink: bool, node_args: str) -> None:
    rc, doc, out = run(tmp_path, dialect, mavlink, node_args=node_args)
    skipped = NOT_OBSERVABLE | (set() if mavlink else VEHICLE_ONLY | {"MCP-DUP-4"})
    if "--manager-only" in node_args:
        skipped |= MANAGER_ONLY_SKIPPED
    info = INFO - skipped
    expected = {rule: "skipped" if rule in skipped else "info" if rule in info else "passed"
                for rule in drone_rules()}
    assert doc["rules"] == expected, out
    assert rc == 0, out
    assert doc["error"] is None and doc["failures"] == [], out
    assert doc["monitor"]["violations"] == [], out


@pytest.fixture(scope="module")
def busy(dialect: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """One run of the node busy longer: a take-off to 150 m (some 7 s in the simulated vehicle)
    that its End_Mission's RTL waits for, as MCP-BLK-7 asks ("finishes pending actions, then
    commands RTL")."""

    def make(out: Path) -> dict[str, Any]:
        rc, doc, text = run(out, dialect, True, takeoff_alt="150")
        return {"rc": rc, "doc": doc, "out": text}

    made: dict[str, Any] = once(tmp_path_factory, "mcp_js_busy", make)
    return made


def test_a_busy_drone_is_still_observed(busy: dict[str, Any]) -> None:
    doc, out = busy["doc"], busy["out"]
    assert busy["rc"] == 0 and doc["error"] is None, out
    unseen = {r for r in drone_rules() - NOT_OBSERVABLE - {"MCP-BLK-7"} if doc["rules"][r] not in ("passed", "info")}
    assert unseen == set(), out
    case = next(c for c in doc["cases"] if c["id"] == "BLK/test_end_mission_then_rtl")
    assert case["outcome"] == "passed", out
    assert "after the node's pending action: a take-off to 150 m" in case["actual"], case["actual"]


def test_a_busy_drone_s_late_rtl_is_no_warning(busy: dict[str, Any]) -> None:
    doc, out = busy["doc"], busy["out"]
    assert doc["rules"]["MCP-BLK-7"] == "passed", out
    assert doc["monitor"]["violations"] == [], out


@pytest.fixture(scope="module")
def renumbered(dialect: Path, tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """One run of a node whose Mission_Ready retry limit is 1, below the least the spec allows
    (MCP-RTX-1: "at least 3 copies while the ACK is withheld"), and which announces again when
    it gives up (``--reannounce``): two copies of seq N, then a new Mission_Ready, seq N+1."""

    def make(out: Path) -> dict[str, Any]:
        rc, doc, text = run(out, dialect, False, node_args="--retries 1 --reannounce")
        return {"rc": rc, "doc": doc, "out": text}

    made: dict[str, Any] = once(tmp_path_factory, "mcp_js_renumbered", make)
    return made


def test_a_drone_below_the_least_retry_limit_that_announces_again_fails(renumbered: dict[str, Any]) -> None:
    """Whichever reading of its third datagram (a new message, or a copy renumbered), one of
    MCP-RTX-1 and MCP-SEQ-2 is broken, and no other MUST rule."""
    doc, out = renumbered["doc"], renumbered["out"]
    assert renumbered["rc"] == 1 and doc["error"] is None, out
    failed_must = {r for r, outcome in doc["rules"].items() if outcome == "failed" and RULES[r].level == "MUST"}
    assert failed_must and failed_must <= {"MCP-RTX-1", "MCP-SEQ-2"}, out


def test_a_drone_below_the_least_retry_limit_that_announces_again_fails_rtx1(renumbered: dict[str, Any]) -> None:
    """The description identifies retransmissions by their number ("Retransmissions of the same
    message are identified by repeating sequence number"): seq N had 2 copies while its ACK was
    withheld, MCP-RTX-1's fault as the same node that exits on give-up is judged, and seq N+1 is
    a new message, no renumbered copy (MCP-SEQ-2 kept). Before session 34 the suite said
    MCP-SEQ-2 failed ("repeats unACKed seq N with a new number", "1 of 2 copies differ") and
    MCP-RTX-1 passed (tests/sim/test_reannounce.py on virtual time)."""
    doc, out = renumbered["doc"], renumbered["out"]
    assert doc["rules"]["MCP-RTX-1"] == "failed", (rule_text("MCP-RTX-1"), out)
    assert doc["rules"]["MCP-SEQ-2"] == "passed", (rule_text("MCP-SEQ-2"), out)


def test_a_drone_below_the_least_retry_limit_that_exits_fails_rtx1(dialect: Path, tmp_path: Path) -> None:
    """The same retry limit, the node exiting 1 when it gives up: MCP-RTX-1 failed (two copies),
    no other MUST rule."""
    rc, doc, out = run(tmp_path, dialect, False, node_args="--retries 1")
    assert rc == 1 and doc["error"] is None, out
    failed_must = {r for r, outcome in doc["rules"].items() if outcome == "failed" and RULES[r].level == "MUST"}
    assert failed_must == {"MCP-RTX-1"}, (rule_text("MCP-RTX-1"), out)


FAULTS = [
    pytest.param("no_dedup", True, "MCP-DUP-1", id="no_dedup"),
    # Mission_Ready once, right after the start: counted though it comes before the startup looks
    pytest.param("no_retransmit", False, "MCP-RTX-1", id="no_retransmit"),
]


@pytest.mark.parametrize(("fault", "mavlink", "rule"), FAULTS)
def test_a_faulty_drone_fails_its_rule_and_no_other(dialect: Path, tmp_path: Path, fault: str, mavlink: bool,
                                                     rule: str) -> None:
    # the startup bound is short: only a node that never announces waits it out
    rc, doc, out = run(tmp_path, dialect, mavlink, "--startup-timeout", "15", node_args=f"--fault {fault}")
    assert rc == 1, out
    assert doc["error"] is None, out
    assert doc["rules"][rule] == "failed", (rule_text(rule), out)
    failed_must = {r for r, outcome in doc["rules"].items() if outcome == "failed" and RULES[r].level == "MUST"}
    assert failed_must == {rule}, (rule_text(rule), out)

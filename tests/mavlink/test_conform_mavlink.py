"""``mcp-conform --protocol mavlink`` (role vehicle, issue 39) end to end on real sockets and
processes: the smoke runs that stay real now that the matrix runs in the simulator
(tests/sim/test_mavlink_vehicle_sim.py, sim.vehicle_role: every fault, stalls, lossy links,
about 0.7 CPU s a suite instead of ~45 s of real timers).

What stays here, and why:
- our reference vehicle (``mcp-vehicle``, spawned by the runner) over each transport, tcp, udp
  (udpin: the vehicle sends first, which the simulator does not model) and udpout: the host's
  sockets, the spawn and the capture, which the simulator replaces; over tcp and udpout its
  verdicts must be the simulator's, rule by rule and case by case (the simulation is checked
  against the real run it stands for);
- a vehicle the runner did not start (attach mode, SITL's way): real only;
- two faults through the real proxy (tests/mavlink/faulty_vehicle.py, whose rewrites are
  sim.vehicle_faults'): ``double-ack`` (answers doubled on a real TCP stream) and
  ``abandoned-stays-busy`` (MAV-MIS-6, the suite's longest real timer, 15 s), each with the
  simulator's verdicts;
- a target that cannot be judged: one line, exit 2.

MAV-CMD-14's command for another component of the vehicle's system: mavlink.io's routing page
has only matching IDs and broadcasts processed, and our vehicle leaves it alone; ArduPilot
4.x acts on it (MAVLink_routing.cpp: ``if (!forwarded && match_system) { process_locally =
true; }`` for a component it has no route to), which the fault ``acts-for-other-component``
plays (in the simulator)."""

from __future__ import annotations

import json
import socket
import sys
from pathlib import Path

import pytest

from mcp_conform.sim.vehicle_role import run_vehicle_cases
from mcp_conform.vehicle.ports import free_port
from tests.forkserver import run_module
from tests.mavlink.reference_run import faulty_vehicle_run, reference_vehicle_run
from tests.sim.test_mavlink_vehicle_sim import (
    FAULTS,
    KNOWN_WARNINGS,
    expect_reference,
    failed,
    warned,
)

pytestmark = pytest.mark.slow

#: the faults that also run through the real proxy
REAL_FAULTS = ("double-ack", "abandoned-stays-busy")


def run(tmp_path: Path, *args: str, timeout: float = 240) -> tuple[int, dict, str]:
    out = tmp_path / "r.json"
    proc = run_module("conformance", ["--protocol", "mavlink", "--json", str(out), *args], timeout=timeout)
    assert out.exists(), proc.stdout + proc.stderr
    return proc.returncode, json.loads(out.read_text()), proc.stdout + proc.stderr


def same_as_simulated(doc: dict, fault: str | None = None, transport: str = "tcp") -> None:
    """The real run's verdicts are the simulator's for the same vehicle: every rule, every case."""
    sim = run_vehicle_cases(fault, seed=1, transport=transport).report
    assert doc["rules"] == sim["rules"], {r: (o, sim["rules"].get(r)) for r, o in doc["rules"].items()
                                          if sim["rules"].get(r) != o}
    real_cases = {c["id"]: c["outcome"] for c in doc["cases"]}
    assert real_cases == {c["id"]: c["outcome"] for c in sim["cases"]}


@pytest.mark.parametrize("transport", ["tcp", "udp", "udpout"])
def test_reference_vehicle_passes_every_case(tmp_path, tmp_path_factory, transport):
    """The embedded reference vehicle over each transport: exit 0, no MUST rule failed, the
    known SHOULD warnings, only the IN_PROGRESS cases skipped; the simulator's verdicts. Over
    tcp the session's one run that the capture's and the live monitor's tests judge too
    (tests/mavlink/reference_run.py)."""
    if transport == "tcp":
        rc, doc, capture, out = reference_vehicle_run(tmp_path_factory)
    else:
        capture = tmp_path / "run.mcap"
        rc, doc, out = run(tmp_path, "--mavlink", transport, "--capture", str(capture))
    assert rc == 0, out
    expect_reference(doc, out)
    assert doc["role"] == "vehicle" and doc["spec"]["protocol"] == "MAV"
    from mcap.reader import make_reader

    with open(capture, "rb") as fh:
        topics = {ch.topic for _, ch, _ in make_reader(fh).iter_messages()}
    assert "/mavlink" in topics and "/conformance/case" in topics, topics
    if transport != "udp":
        same_as_simulated(doc, transport=transport)


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


@pytest.mark.parametrize("fault", REAL_FAULTS)
def test_a_faulty_vehicle_through_the_real_proxy(tmp_path_factory, fault):
    """The whole suite against the reference vehicle behind the real proxy: the fault's rule's
    cases and no other MUST rule, no warning but the known ones, the rule's text in the
    report; the simulator's verdicts for the same fault. The session's one run of the fault
    (tests/mavlink/reference_run.py), whose capture the capture's test judges too (double-ack)."""
    rc, doc, _, out = faulty_vehicle_run(tmp_path_factory, fault)
    rule, want = FAULTS[fault]
    assert rc == 1, out
    assert failed(doc) == ({rule}, want), out
    assert warned(doc) <= set(KNOWN_WARNINGS), out
    case = next(c for c in doc["cases"] if c["id"] in want)
    assert case["failed_rule"] == rule and case["expected"] and case["actual"], case
    same_as_simulated(doc, fault)


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


@pytest.mark.parametrize("transport", ["udp", "udpout", "tcp"])
def test_a_spawned_vehicle_that_fails_at_once_ends_the_run_at_its_death(tmp_path, transport):
    """A vehicle that exits with an error before its first HEARTBEAT: exit 2, its exit code and
    output in the error, the run ended at its death, not at ``--startup-timeout`` (600 s here:
    the run's own bound, 120 s, would end it first). Before, over UDP (no connection awaited),
    the runner waited the whole startup timeout for a HEARTBEAT that could not come."""
    vehicle = f"{sys.executable} -c \"import sys; print('bad option'); sys.exit(3)\""
    rc, doc, out = run(tmp_path, "--mavlink", transport, "--spawn", vehicle, "--startup-timeout", "600", timeout=120)
    assert rc == 2 and "exited with code 3" in doc["error"] and "Traceback" not in out, out
    assert "bad option" in out, out

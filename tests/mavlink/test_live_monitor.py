"""The MAVLink trace monitor fed live (issue 39: one judge): ``mcp-conform --protocol mavlink``
feeds ``judge.mavlink_monitor`` every frame of its link both ways as the capture records it
(``harness.mavlink_session.Link``), and the report's ``monitor`` section holds its verdicts,
as MCP's and Nsqd's runs have theirs. The same run's capture, checked offline (``mcp-capture
check``), must give the same verdict on every rule, the same violations at the same times; a
faulty vehicle (tests/mavlink/faulty_vehicle.py) is caught by the monitor with its rule live as
offline; our vehicle gets no monitor failure.
"""

from __future__ import annotations

import contextlib
import io
import json
import sys
from pathlib import Path

import pytest

from mcp_conform.captures.cli import main as capture_main

FAULTY = Path(__file__).with_name("faulty_vehicle.py")


def conform(tmp_path: Path, *args: str) -> tuple[dict, Path, str]:
    from tests.forkserver import run_module

    report, capture = tmp_path / "run.json", tmp_path / "run.mcap"
    proc = run_module("conformance", ["--protocol", "mavlink", "--json", str(report), "--capture", str(capture),
                                      *args], timeout=300)
    assert report.exists(), proc.stdout + proc.stderr
    return json.loads(report.read_text()), capture, proc.stdout + proc.stderr


def check(tmp_path: Path, capture: Path) -> tuple[int, dict, str]:
    """``mcp-capture check CAPTURE --json`` (no --protocol: the capture says it is MAVLink's)."""
    out = tmp_path / "check.json"
    so = io.StringIO()
    with contextlib.redirect_stdout(so), contextlib.redirect_stderr(so):
        rc = capture_main(["check", str(capture), "--json", str(out)])
    return rc, json.loads(out.read_text()), so.getvalue()


def same_judgement(live: dict, offline: dict) -> None:
    """The run's monitor section and the offline check: every rule's verdict, the counts, the
    violations (rule, node, time, what came) and the frames judged."""
    assert live["rules"] == offline["rules"], {r: (v, offline["rules"].get(r)) for r, v in live["rules"].items()
                                               if offline["rules"].get(r) != v}
    assert live["failed_count"] == offline["failed_count"]
    assert live["frames"] == offline["frames"]
    key = ("rule", "node", "t_ns", "actual")
    assert [[v[k] for k in key] for v in live["violations"]] == [[v[k] for k in key] for v in offline["violations"]]


def bad(rules: dict) -> set[str]:
    return {r for r, v in rules.items() if v in ("failed", "warned")}


#: faulty vehicles whose rule the monitor judges from the traffic, the cases run (--select)
#: the faults whose monitor verdicts are compared live and offline through the real proxy:
#: one here; the simulator compares them for the reference, double-ack, type-gcs and
#: acts-for-other-system (tests/sim/test_mavlink_vehicle_sim.py, the same helpers)
FAULTS = {
    "double-ack": ("MAV-CMD-3", "CMD"),
}


@pytest.mark.parametrize("fault", sorted(FAULTS))
def test_a_faulty_vehicle_gets_the_same_monitor_verdict_live_as_offline(tmp_path, fault):
    rule, group = FAULTS[fault]
    spawn = f"{sys.executable} {FAULTY} --listen {{target_host}}:{{target_port}} --fault {fault} --duration 200"
    run, capture, out = conform(tmp_path, "--spawn", spawn, "--select", group)
    live = run.get("monitor")
    assert live is not None and live["complete"], out
    assert bad(live["rules"]) == {rule} and live["failed_count"][rule] >= 1, live["violations"]
    rc, offline, cout = check(tmp_path, capture)
    assert rc == 1 and bad(offline["rules"]) == {rule}, cout
    same_judgement(live, offline)


@pytest.mark.slow
def test_our_vehicle_gets_no_monitor_failure_live(tmp_path, tmp_path_factory):
    """The whole suite over TCP (the session's one run, tests/mavlink/reference_run.py; the
    mission cases too: our vehicle's MAV-MIS-5/7 are the cases' warnings, no monitor failure)."""
    from tests.mavlink.reference_run import reference_vehicle_run

    _, run, capture, out = reference_vehicle_run(tmp_path_factory)
    live = run.get("monitor")
    assert live is not None, out
    assert not bad(live["rules"]) and not live["violations"], live["violations"]
    assert not [f for f in run["failures"] if f.get("source") == "monitor"], run["failures"]
    judged = {r for r, v in live["rules"].items() if v == "passed"}
    assert judged >= {"MAV-HB-1", "MAV-HB-11", "MAV-CMD-1", "MAV-CMD-3", "MAV-PRM-1", "MAV-PRM-7"}, live["rules"]
    rc, offline, cout = check(tmp_path, capture)
    assert rc == 0 and offline["verdict"] == "OK", cout
    same_judgement(live, offline)

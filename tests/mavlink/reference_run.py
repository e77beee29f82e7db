"""Our reference vehicle's whole suite over TCP, with its capture: one real run per test session
(tests/xdist_once.py), judged by each test that asks for it -- the run's verdicts
(tests/mavlink/test_conform_mavlink.py), its capture checked offline against the cases
(tests/captures/test_mavlink_capture.py) and its live monitor against the offline check
(tests/mavlink/test_live_monitor.py). Each made the same run of its own before (~45 s each on
CI's slow run, issue 38).

    mcp-conform --protocol mavlink --mavlink tcp --json run.json --capture run.mcap

The same for a faulty vehicle through the real proxy (tests/mavlink/faulty_vehicle.py), the
whole suite with its capture, one run per fault and session (:func:`faulty_vehicle_run`):
``double-ack``'s verdicts (tests/mavlink/test_conform_mavlink.py) and its capture checked
offline against the cases (tests/captures/test_mavlink_capture.py), which ran a run of its own
before (the CMD group's; the whole suite's capture fails MAV-CMD-3 and nothing else offline too).

    mcp-conform --protocol mavlink --json run.json --capture run.mcap --spawn 'faulty_vehicle.py ... --fault F'

The files are shared: read them, never change them.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import pytest

from tests.forkserver import run_module
from tests.xdist_once import once

FAULTY = Path(__file__).with_name("faulty_vehicle.py")


def _make(home: Path, *args: str) -> dict:
    report, capture = home / "run.json", home / "run.mcap"
    proc = run_module("conformance", ["--protocol", "mavlink", *args, "--json", str(report),
                                      "--capture", str(capture)], timeout=300)
    return {"rc": proc.returncode, "report": report, "capture": capture, "out": proc.stdout + proc.stderr}


def _read(made: dict) -> tuple[int, dict, Path, str]:
    assert made["report"].exists(), made["out"]
    return made["rc"], json.loads(made["report"].read_text()), made["capture"], made["out"]


def reference_vehicle_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, dict, Path, str]:
    """The run's (exit code, JSON report, capture, output); the report must exist."""
    return _read(once(tmp_path_factory, "mavlink-reference-vehicle-tcp", lambda home: _make(home, "--mavlink", "tcp")))


def faulty_vehicle_run(tmp_path_factory: pytest.TempPathFactory, fault: str) -> tuple[int, dict, Path, str]:
    """The whole suite against the faulty vehicle ``fault`` through the real proxy, with its
    capture: (exit code, JSON report, capture, output); the report must exist."""
    spawn = f"{sys.executable} {FAULTY} --listen {{target_host}}:{{target_port}} --fault {fault} --duration 200"
    return _read(once(tmp_path_factory, f"mavlink-faulty-vehicle-{fault}", lambda home: _make(home, "--spawn", spawn)))

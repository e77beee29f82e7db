"""Our reference vehicle's whole suite over TCP, with its capture: one real run per test session
(tests/xdist_once.py), judged by each test that asks for it -- the run's verdicts
(tests/mavlink/test_conform_mavlink.py), its capture checked offline against the cases
(tests/captures/test_mavlink_capture.py) and its live monitor against the offline check
(tests/mavlink/test_live_monitor.py). Each made the same run of its own before (~45 s each on
CI's slow run, issue 38).

    mcp-conform --protocol mavlink --mavlink tcp --json run.json --capture run.mcap

The files are shared: read them, never change them.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.forkserver import run_module
from tests.xdist_once import once


def _make(home: Path) -> dict:
    report, capture = home / "run.json", home / "run.mcap"
    proc = run_module("conformance", ["--protocol", "mavlink", "--mavlink", "tcp", "--json", str(report),
                                      "--capture", str(capture)], timeout=300)
    return {"rc": proc.returncode, "report": report, "capture": capture, "out": proc.stdout + proc.stderr}


def reference_vehicle_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[int, dict, Path, str]:
    """The run's (exit code, JSON report, capture, output); the report must exist."""
    made = once(tmp_path_factory, "mavlink-reference-vehicle-tcp", _make)
    assert made["report"].exists(), made["out"]
    return made["rc"], json.loads(made["report"].read_text()), made["capture"], made["out"]

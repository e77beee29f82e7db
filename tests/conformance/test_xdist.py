"""Under pytest-xdist the run still leaves ONE JSON report, ONE JUnit file and ONE valid
MCAP capture, merged by the controller from its workers, and prints the mcp summary once
(issue 13). The whole suite, each worker spawning its own node: this run also holds
test_runner's former xdist test's checks (its own whole-suite run under ``-n 2``, the same
node and timings, gone: one run of 4.6 CPU s fewer), and tests/captures/test_one_judge's check
of its merged capture against the reference node (``xdist_reference_run``: made once a session,
under xdist too; that test's own run of a few rules' cases under ``-n 2``, gone: about 3 CPU s
fewer)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
from mcap.reader import make_reader

from mcp_conform.conformance.report import validate_json
from tests.xdist_once import once

from .runner_helpers import FAST, ROOT, reference_node_command

pytestmark = pytest.mark.slow


def _make_xdist_reference_run(home: Path) -> dict[str, Any]:
    cmd = [sys.executable, "-m", "pytest", "-p", "no:cacheprovider", "--pyargs", "mcp_conform.conformance.cases",
           "-n", "2",
           "--mcp-spawn", reference_node_command(), "--mcp-mavlink",
           "--mcp-rto", FAST[1], "--mcp-ack-window", FAST[3],
           "--mcp-json", "r.json", "--mcp-junit", "j.xml", "--mcp-capture", "c.mcap"]
    proc = subprocess.run(cmd, cwd=home, capture_output=True, text=True, timeout=240,
                          env=dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1"))
    return {"dir": home, "rc": proc.returncode, "out": proc.stdout + proc.stderr}


def xdist_reference_run(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Any]:
    """The whole suite under ``pytest -n 2`` against the reference node, each worker spawning its
    own, with a JSON report, a JUnit file and a capture (in ``dir``: read-only, shared), its exit
    code (``rc``) and output (``out``): made once a session (tests/xdist_once.py)."""
    pytest.importorskip("xdist")
    return once(tmp_path_factory, "xdist-reference-run", _make_xdist_reference_run)


def test_spawn_mode_under_xdist_leaves_one_report_of_each_kind(tmp_path_factory):
    run = xdist_reference_run(tmp_path_factory)
    tmp_path, out = run["dir"], run["out"]
    assert run["rc"] == 0, out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.mcap", "j.xml", "r.json"], out
    doc = json.loads((tmp_path / "r.json").read_text())
    validate_json(doc)
    assert doc["summary"]["passed"] >= 5 and doc["summary"]["failed"] == 0
    assert len(doc["target"].split(", ")) == 2, doc["target"]  # each worker spawned its node
    ids = [c["id"] for c in doc["cases"]]
    assert len(ids) == len(set(ids)) and len(ids) >= 40
    assert doc["rules"]["MCP-ACK-1"] == "passed"
    junit = (tmp_path / "j.xml").read_text()
    assert junit.count("<testcase ") == len(doc["cases"])
    with open(tmp_path / "c.mcap", "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        topics = {ch.topic for _, ch, _ in reader.iter_messages()}
    assert {"/mcp/tx", "/mcp/rx", "/conformance/case"} <= topics
    assert out.count("suite finished in") == 1 and out.count("per-rule outcome") == 1
    assert "PASSED   ACK/" in out  # the controller prints each case's line

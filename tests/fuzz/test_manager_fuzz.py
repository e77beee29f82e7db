"""``mcp-fuzz --role manager``: the fuzzer plays drones against a Mission Manager held in its
receiving phase (fuzz.manager_target), judged by replies, liveness, the process and the
trace monitor. The independent sample manager (tests/conformance/nodes/sample_manager.py):
a fault is found with its rule; the correct one gives no finding."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from tests.conformance.runner_helpers import ROOT, sample_manager_command
from tests.forkserver import run_module

pytestmark = pytest.mark.slow


def fuzz(tmp_path: Path, *args: str) -> tuple[int, dict, str]:
    out = tmp_path / "out"
    env = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1")
    # a child of the tests' fork server (tests/forkserver.py): the modules imported once, not a
    # fresh interpreter's imports per run; the same entry point (``mcp-fuzz``: fuzz.cli.main)
    proc = run_module("mcp_conform.fuzz", ["--role", "manager", *args, "--out", str(out)], cwd=ROOT, env=env,
                      timeout=300)
    summary = json.loads((out / "summary.json").read_text()) if (out / "summary.json").exists() else {}
    return proc.returncode, summary, proc.stdout + proc.stderr


def test_a_manager_that_acks_acks_is_found(tmp_path):
    rc, summary, output = fuzz(tmp_path, "--spawn", sample_manager_command("--fault", "ack-ack"),
                               "--rto", "0.2", "--ack-window", "0.25", "--max-cases", "300")
    assert rc == 1, output
    assert "MCP-ACK-6" in summary["findings_by_rule"], output


def test_a_correct_manager_gives_no_finding(tmp_path):
    rc, summary, output = fuzz(tmp_path, "--spawn", sample_manager_command(),
                               "--rto", "0.2", "--ack-window", "0.25", "--max-cases", "500")
    assert rc == 0 and summary["findings"] == 0 and summary["cases"] == 500, output
    assert summary["monitor"] is True


def test_the_embedded_reference_manager_survives(tmp_path):
    """The reference manager (embedded default) stays live through the campaign: no finding
    from the liveness probe or the process's fate."""
    rc, summary, output = fuzz(tmp_path, "--max-cases", "400")
    assert rc in (0, 1) and summary["cases"] == 400, output
    for d in sorted((tmp_path / "out").glob("finding-*")):
        f = json.loads((d / "finding.json").read_text())
        assert f["source"] not in ("liveness", "process"), f

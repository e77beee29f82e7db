"""``--engine both`` against an Nsqd backend (issue 36): ``--max-cases`` is shared between the
two engines as ``--duration`` is, so the stateful engine is reached under a case budget too
(the stateless engine spent all 20,000 cases before the stateful one began)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from tests.forkserver import run_module

ROOT = Path(__file__).resolve().parents[2]


@pytest.mark.slow
def test_both_engines_share_the_case_budget(tmp_path: Path) -> None:
    out = tmp_path / "fz"
    proc = run_module("mcp_conform.fuzz", ["--protocol", "nsqd", "--engine", "both", "--max-cases", "400", "--seed", "3",
                                           "--out", str(out)], cwd=ROOT, timeout=120)  # tests/forkserver.py
    assert proc.returncode == 0, proc.stdout + proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["engine"] == "both" and summary["cases"] == 400, summary
    stateless = sum(summary["by_kind"].values())  # the stateless engine's cases, by mutation kind
    assert stateless == 200, summary["by_kind"]  # the other half was the stateful engine's

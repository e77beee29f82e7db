"""``python -m mcp_conform.spec``: summary, docs --check, and one-line errors with exit 2 on a broken spec."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mcp_conform.spec.__main__ import main

ROOT = Path(__file__).resolve().parents[2]


def test_summary_lists_header_actions_and_rule_counts(capsys: pytest.CaptureFixture[str]) -> None:
    assert main([]) == 0
    out = capsys.readouterr().out
    for word in ("!7s2B4H", "Mission_Ready", "Mav_Passthrough", "MUST", "SHOULD", "INFO", "55"):
        assert word in out


def test_docs_check_passes_on_the_committed_page(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["docs", "--check"]) == 0


def test_docs_write_then_check(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "spec.md"
    assert main(["--protocol", "mcp", "docs", "--check", "--output", str(out)]) == 1
    assert "stale" in capsys.readouterr().err
    assert main(["--protocol", "mcp", "docs", "--output", str(out)]) == 0
    assert main(["--protocol", "mcp", "docs", "--check", "--output", str(out)]) == 0


def test_broken_spec_is_one_line_and_exit_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.yaml"
    bad.write_text("spec_version: 1\nprotocol: {}\n", encoding="utf-8")
    run = subprocess.run([sys.executable, "-m", "mcp_conform.spec", "--spec", str(bad)], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert run.returncode == 2
    assert run.stdout == ""
    lines = run.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: ") and str(bad) in lines[0]
    assert "Traceback" not in run.stderr


def test_missing_spec_is_exit_2(capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["--spec", str(tmp_path / "absent.yaml")]) == 2
    assert "cannot read" in capsys.readouterr().err

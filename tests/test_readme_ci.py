"""Every command of the CI guide's "Use it in CI" section (docs/guide/ci.md, once the README's;
issues 13 and 40), run as CI would run it.

The snippets are taken from the page itself (YAML parsed, commands extracted), so the test
fails the day the guide and the tool disagree. The one line that cannot run here is the
install from PyPI (no package index in tests): it is checked to name this distribution, whose
commands are already installed in the environment running the tests.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
pytestmark = pytest.mark.slow


def _section() -> str:
    text = (ROOT / "docs" / "guide" / "ci.md").read_text(encoding="utf-8")
    start = text.index("## Use it in CI")
    end = text.find("\n## ", start)
    return text[start:end if end >= 0 else len(text)]


def _blocks(lang: str) -> list[str]:
    return re.findall(rf"```{lang}\n(.*?)```", _section(), flags=re.S)


def _commands() -> tuple[list[str], list[str], list[str]]:
    (sh,) = _blocks("sh")
    gh, gl = (yaml.safe_load(b) for b in _blocks("yaml"))
    gh_runs = [s["run"] for s in gh["jobs"]["mcp-conformance"]["steps"] if "run" in s]
    gl_runs = list(gl["mcp-conformance"]["script"])
    return [ln for ln in sh.splitlines() if ln.strip()], gh_runs, gl_runs


def _run(cmd: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, NO_COLOR="1", PYTHONPATH=str(ROOT))
    return subprocess.run(cmd, shell=True, cwd=cwd, env=env, capture_output=True, text=True, timeout=300)


def test_the_ci_snippets_run_as_written(tmp_path):
    if shutil.which("mcp-conform") is None or shutil.which("mcp-node") is None:
        pytest.skip("the mcp-conform and mcp-node commands are not installed in this environment")
    dist = re.search(r'^name = "([^"]+)"', (ROOT / "pyproject.toml").read_text(), re.M).group(1)
    baseline_cmds, gh_runs, gl_runs = _commands()
    assert len(baseline_cmds) == 1 and "--write-baseline mcp-baseline.yaml" in baseline_cmds[0]
    first = _run(baseline_cmds[0], tmp_path)
    assert first.returncode == 0, first.stdout + first.stderr
    assert (tmp_path / "mcp-baseline.yaml").exists()
    for runs in (gh_runs, gl_runs):
        for f in ("mcp-junit.xml", "mcp-report.json", "mcp-run.mcap"):
            (tmp_path / f).unlink(missing_ok=True)
        for cmd in runs:
            if cmd.startswith("pip install"):
                assert cmd.split()[-1] == dist  # the install line names this distribution
                continue
            proc = _run(cmd, tmp_path)
            assert proc.returncode == 0, cmd + "\n" + proc.stdout + proc.stderr
        for f in ("mcp-junit.xml", "mcp-report.json", "mcp-run.mcap"):
            assert (tmp_path / f).stat().st_size > 0, f

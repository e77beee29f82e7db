"""`.ci/run` runs exactly the README's test command (so CI proves the quick start works on
a fresh machine), the import contracts, the slow tests (beside them, waited for: their exit
status is the build's) and the main job."""

from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def _readme_test_command() -> str:
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    block = re.search(r"## Quick start\n.*?```sh\n(.*?)```", text, flags=re.S)
    assert block is not None, "README has no quick-start sh block"
    lines = [ln.split("#")[0].strip() for ln in block.group(1).splitlines() if ln.strip()]
    assert len(lines) == 2, lines  # exactly two commands: the main job, the tests
    return lines[1]


def test_ci_runs_the_readme_test_command_verbatim_the_slow_tests_and_the_main_job() -> None:
    steps = [ln.split("#")[0].strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]
    cmd = _readme_test_command()
    assert cmd in steps, (cmd, steps)
    after = steps[steps.index(cmd) + 1:]
    assert "lint-imports" in after
    assert any(s.startswith("mcp-conform") for s in after), after
    slow = [s for s in steps if s.startswith("python -m pytest") and "slow" in s and s != cmd]
    # every slow test, the Nsqd ones among them: no marker expression that leaves some out
    assert len(slow) == 1 and slow[0].split(" -m ")[-1].split()[0].strip("'\"") == "slow", slow
    if slow[0].endswith("&"):  # started in the background: waited for, its status the build's
        assert 'wait "$slow" || rc=$?' in after and after[-1] == 'exit "$rc"', after

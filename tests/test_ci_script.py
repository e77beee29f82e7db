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


def _marker_expression(step: str) -> str:
    """The ``-m`` expression of a pytest step (quoted or one word)."""
    found = re.findall(r""" -m (?:"([^"]+)"|'([^']+)'|(\S+))""", step.split("python -m pytest", 1)[-1])
    assert found, step
    return next(g for g in found[-1] if g)


def test_ci_runs_the_readme_test_command_verbatim_the_slow_tests_and_the_main_job() -> None:
    from _pytest.mark.expression import Expression

    steps = [ln.split("#")[0].strip() for ln in (ROOT / ".ci" / "run").read_text().splitlines()
             if ln.strip() and not ln.lstrip().startswith("#")]
    cmd = _readme_test_command()
    assert cmd in steps, (cmd, steps)
    after = steps[steps.index(cmd) + 1:]
    assert "lint-imports" in after
    assert any(s.removeprefix("setsid ").startswith("mcp-conform") for s in after), after  # the main job (its own process group)
    runs = [s for s in steps if "python -m pytest" in s and "--collect-only" not in s]  # collecting runs no test
    # every test runs exactly once: the README's quick ones, the slow ones, the CPU-bound ones
    for slow in (False, True):
        for cpu in (False, True):
            marks = {"slow": slow, "cpu": cpu, "nsqd": slow}
            chosen = [s for s in runs if Expression.compile(_marker_expression(s)).evaluate(
                lambda name, m=marks, **kw: m.get(name, False))]
            assert len(chosen) == 1, (marks, chosen)
            # a step given its tier's files (tests/conftest.py ``tier``, MCP_TEST_TIERS) selects
            # only that tier's tests: none of another tier's is left in a file it is not given
            for s in chosen:
                given = re.search(r"\$\(files (\w+)\)", s)
                assert given is None or given.group(1) == ("cpu" if cpu else "slow" if slow else "quick"), (marks, s)
    background = [s for s in steps if s.endswith("&")]
    for s in background:  # started in the background: waited for, its status the build's
        var = steps[steps.index(s) + 1].split("=")[0]
        assert f'wait "${var}" || rc=$?' in steps or any(w.startswith(f'wait "${var}" || {{') and "exit 1" in w
                                                          for w in steps), (var, steps)
    if background:
        assert steps[-1] == 'exit "$rc"', steps

"""The optional extras (issue 40 item 3): ``redis`` (mcp-fuzz's shared example database,
``--db redis://``) and ``viewers`` (foxglove-sdk: ``--live``, and the Foxglove channels of a
capture). Without them everything else works, and asking for what needs them is a one-line
error naming the extra.

"Without" is made here by a directory on PYTHONPATH whose ``redis`` and ``foxglove`` packages
raise the ImportError an absent package raises (the real ones stay installed for the other
tests)."""

from __future__ import annotations

import ast
import os
import subprocess
import sys
from pathlib import Path

import pytest

from tests.packaging.tree import ROOT, pyproject, script_argv, sources

OPTIONAL = {"redis": "redis", "foxglove": "viewers"}  # import name -> extra


def _dist_name(requirement: str) -> str:
    return (
        requirement.split(";")[0]
        .split("[")[0]
        .split("<")[0]
        .split(">")[0]
        .split("=")[0]
        .strip()
        .lower()
    )


def test_the_optional_packages_are_extras_not_dependencies():
    project = pyproject()["project"]
    deps = {_dist_name(r) for r in project["dependencies"]}
    assert not deps & {"redis", "foxglove-sdk"}, deps
    extras = project["optional-dependencies"]
    assert {_dist_name(r) for r in extras["redis"]} == {"redis"}
    assert {_dist_name(r) for r in extras["viewers"]} == {"foxglove-sdk", "protobuf"}  # protobuf: traceio.fox reads the SDK's schemas
    # the test extra brings both, so that no test is skipped for want of them
    assert any(
        r.startswith(f"{project['name']}[") and "redis" in r and "viewers" in r
        for r in extras["test"]
    )


def test_the_optional_packages_are_imported_only_where_they_are_used():
    """No module imports redis or foxglove when it is imported itself: a function does, where
    the feature is asked for (so ``mcp-conform``, ``mcp-capture`` ... start without them)."""
    top_level = []
    for rel, _, tree in sources():
        for node in tree.body:  # module level, and under a module-level if/try
            for sub in ast.walk(node) if isinstance(node, (ast.If, ast.Try)) else (node,):
                names = (
                    [a.name for a in sub.names]
                    if isinstance(sub, ast.Import)
                    else [sub.module or ""]
                    if isinstance(sub, ast.ImportFrom)
                    else []
                )
                top_level += [
                    f"{rel}:{sub.lineno}: {n}"
                    for n in names
                    if n.split(".")[0] in OPTIONAL or n.startswith("hypothesis.extra.redis")
                ]
    assert not top_level, "\n".join(top_level)


@pytest.fixture(scope="module")
def without_extras(tmp_path_factory) -> dict[str, str]:
    """An environment in which ``import redis`` and ``import foxglove`` fail as if absent."""
    block = tmp_path_factory.mktemp("no-extras")
    for name in OPTIONAL:
        (block / name).mkdir()
        (block / name / "__init__.py").write_text(
            f"raise ImportError(\"No module named '{name}'\", name={name!r})\n"
        )
    env = dict(os.environ, PYTHONPATH=f"{block}{os.pathsep}{ROOT}", NO_COLOR="1")
    probe = subprocess.run(
        [sys.executable, "-c", "import foxglove"], env=env, capture_output=True, text=True
    )
    assert probe.returncode != 0 and "ImportError" in probe.stderr
    return env


CASES = {
    "fuzz-db-redis": ("mcp-fuzz", ["--db", "redis://127.0.0.1:1/0", "--duration", "1"], "redis"),
    "fuzz-live": ("mcp-fuzz", ["--live", "0"], "viewers"),
    "conform-live": ("mcp-conform", ["--live", "0", "--select", "MCP-HDR-1"], "viewers"),
    "soak-live": ("mcp-soak", ["--live", "0"], "viewers"),
    "node-live": ("mcp-node", ["drone", "--id", "1", "--live", "0"], "viewers"),
}


@pytest.mark.parametrize("case", sorted(CASES))
def test_asking_for_a_missing_extra_is_one_line_naming_it(case, without_extras, tmp_path):
    name, args, extra = CASES[case]
    proc = subprocess.run(
        [*script_argv(name), *args],
        capture_output=True,
        text=True,
        timeout=60,
        env=without_extras,
        cwd=tmp_path,
        stdin=subprocess.DEVNULL,
    )
    assert proc.returncode == 2, proc.stdout + proc.stderr
    errors = [ln for ln in proc.stderr.splitlines() if "error" in ln.lower() or "Traceback" in ln]
    assert len(errors) == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert f"centmesh-mcp-conform[{extra}]" in errors[0], errors[0]


@pytest.mark.slow
def test_a_capture_is_written_and_read_without_foxglove_sdk(without_extras, tmp_path):
    """The runner records its capture without the Foxglove channels, and the capture tools
    read it: foxglove-sdk is for viewing, not for testing."""
    cap = tmp_path / "run.mcap"
    run = subprocess.run(
        [*script_argv("mcp-conform"), "--select", "MCP-ACK-1", "--capture", str(cap)],
        capture_output=True,
        text=True,
        timeout=120,
        env=without_extras,
        cwd=tmp_path,
        stdin=subprocess.DEVNULL,
    )
    assert run.returncode == 0, run.stdout + run.stderr
    assert "0 error" in run.stdout and "0 failed" in run.stdout, run.stdout
    check = subprocess.run(
        [*script_argv("mcp-capture"), "check", str(cap)],
        capture_output=True,
        text=True,
        timeout=120,
        env=without_extras,
        cwd=tmp_path,
    )
    assert check.returncode == 0, check.stdout + check.stderr
    from mcap.reader import make_reader

    with Path(cap).open("rb") as f:
        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert "/mcp/rx" in topics and "/log" not in topics, topics

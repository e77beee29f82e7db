"""One version, written once (issue 40 item 3): ``spec.about.__version__``, which the build
reads (pyproject.toml's ``dynamic`` version) and which every report and ``--version`` says.

The installed wheel's metadata, its ``--version`` and its JSON report are compared in
``test_dist.py`` (slow: it builds the wheel)."""

from __future__ import annotations

import ast
import re
import subprocess

import pytest

from mcp_conform.spec.about import __version__, tool_version
from tests.packaging.tree import ROOT, pyproject, script_argv, scripts, sources, tree_env


def test_the_build_reads_the_version_from_spec_about():
    doc = pyproject()
    assert "version" not in doc["project"], "pyproject.toml writes a version of its own"
    assert "version" in doc["project"]["dynamic"]
    assert doc["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "mcp_conform.spec.about.__version__"}
    assert tool_version() == __version__
    assert re.fullmatch(r"\d+(\.\d+)*((a|b|rc)\d+)?(\.post\d+)?(\.dev\d+)?", __version__), (
        __version__
    )


def test_no_other_module_writes_or_looks_up_a_version():
    """No second literal of the version, and no lookup of the installed distribution's (which
    names another checkout's code under PYTHONPATH, or none from an unpacked sdist)."""
    found = []
    for rel, _, tree in sources():
        if rel == "spec/about.py":
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Constant) and node.value == __version__:
                found.append(f"{rel}:{node.lineno}: the literal {__version__!r}")
            elif (
                isinstance(node, ast.ImportFrom)
                and node.module == "importlib.metadata"
                and any(a.name == "version" for a in node.names)
            ):
                found.append(f"{rel}:{node.lineno}: importlib.metadata.version")
            elif isinstance(node, ast.Assign) and any(
                isinstance(t, ast.Name) and t.id == "__version__" for t in node.targets
            ):
                found.append(f"{rel}:{node.lineno}: a __version__ of its own")
    assert not found, "use spec.about.tool_version():\n" + "\n".join(found)


@pytest.mark.parametrize("name", sorted(scripts()))
def test_every_version_option_says_the_one_version(name):
    def run(option: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([*script_argv(name), option], capture_output=True, text=True, timeout=60,
                              env=tree_env(), cwd=ROOT)

    proc = run("--version")
    if proc.returncode != 0 and "--version" not in run("--help").stdout:  # --help: asked only then
        pytest.skip(f"{name} has no --version in its --help (issue 40 item 1 gives every tool one)")
    assert proc.returncode == 0, proc.stdout + proc.stderr
    first = proc.stdout.splitlines()[0] if proc.stdout else ""
    assert re.match(rf"{re.escape(name)} {re.escape(__version__)}(\s|$)", first), (
        f"{name} --version: {first!r}, not '{name} {__version__} ...'"
    )

"""What the packaging tests share: the checkout's root, its pyproject.toml, the packages and
console scripts it declares, and a subprocess environment that runs this tree's code."""

from __future__ import annotations

import ast
import json
import os
import re
import subprocess
import sys
from collections.abc import Iterator
from functools import cache
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10: tomli, as build (the test extra) has it there
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]


def pyproject() -> dict[str, Any]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


#: the one import package the distribution ships; the checkout's folders are its subpackages
NAMESPACE = "mcp_conform"


def top_packages() -> list[str]:
    """The checkout's package folders the distribution ships, each the subpackage of
    :data:`NAMESPACE` of that name (pyproject.toml, [tool.setuptools] packages)."""
    return [p.split(".")[1] for p in pyproject()["tool"]["setuptools"]["packages"]
            if p.count(".") == 1 and p.startswith(NAMESPACE + ".")]


@cache
def texts() -> tuple[tuple[str, str], ...]:
    """Every module of the shipped packages, in ``top_packages`` order and sorted within each:
    (path relative to the root, posix; its text). Read once per process."""
    out = []
    for pkg in top_packages():
        for path in sorted((ROOT / pkg).rglob("*.py")):
            out.append((path.relative_to(ROOT).as_posix(), path.read_text(encoding="utf-8")))
    return tuple(out)


def sources() -> Iterator[tuple[str, str, ast.Module]]:
    """:func:`texts` with each module's syntax tree, parsed as the scan reaches it (about 1.5
    CPU s for the 300 modules) and not kept: the trees held for the rest of the process (they
    were cached, shared by test_paths', test_version's and test_extras' scans) were 700,000
    objects that every full pass of the garbage collector walked, 0.7 CPU s a pass instead of
    0.04 -- pytest's own three at the session's end among them, in every worker that ran a scan."""
    for rel, text in texts():
        yield rel, text, ast.parse(text)


def scripts() -> dict[str, str]:
    """Console script name -> ``module:function`` (pyproject.toml, [project.scripts])."""
    return dict(pyproject()["project"]["scripts"])


def tree_env(**extra: str) -> dict[str, str]:
    """The environment of a subprocess that runs this checkout's code (not an installed copy)."""
    return dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1", **extra)


def script_argv(name: str) -> list[str]:
    """The argv that runs console script ``name`` from this tree, as its entry point does."""
    module, func = scripts()[name].split(":")
    code = f"import sys; sys.argv[0] = {name!r}; from {module} import {func}; sys.exit({func}())"
    return [sys.executable, "-c", code]


_PATHS_SCRIPT = r"""
import importlib, json, pkgutil, sys
from pathlib import Path
root = Path(sys.argv[1]).resolve()
found = {}
ns = sys.argv[2]
for pkg in (f"{ns}.{p}" for p in sys.argv[3:]):
    mod = importlib.import_module(pkg)
    names = [pkg] + [i.name for i in pkgutil.walk_packages(mod.__path__, pkg + ".")]
    for name in names:
        if name.rsplit(".", 1)[-1] == "__main__":  # runs its command when imported
            continue
        for key, value in vars(importlib.import_module(name)).items():
            if isinstance(value, Path) and value.is_absolute():
                try:
                    found[f"{name.removeprefix(ns + '.')}.{key}"] = value.resolve().relative_to(root).as_posix()
                except ValueError:  # another distribution's file (pymavlink's ...)
                    pass
print(json.dumps(found))
"""


@cache
def module_paths() -> dict[str, str]:
    """Every module-level ``Path`` of our packages that points into the tree, imported as the
    tools import them: ``module.NAME`` -> path relative to the root (``captures/golden``)."""
    proc = subprocess.run(
        [sys.executable, "-c", _PATHS_SCRIPT, str(ROOT), NAMESPACE, *top_packages()],
        capture_output=True,
        text=True,
        timeout=120,
        env=tree_env(),
        cwd=ROOT,
    )
    assert proc.returncode == 0, proc.stderr
    return dict(json.loads(proc.stdout))


def resource_paths() -> set[str]:
    """``importlib.resources.files("pkg").joinpath("NAME")`` in our packages: ``pkg/NAME``."""
    pattern = re.compile(
        r"""resources\.files\(\s*["']([\w.]+)["']\s*\)\.joinpath\(\s*["']([^"']+)["']"""
    )
    found = set()
    for pkg in top_packages():
        for path in (ROOT / pkg).rglob("*.py"):
            for m in pattern.finditer(path.read_text(encoding="utf-8")):
                name = m.group(1).removeprefix(NAMESPACE + ".")
                found.add(f"{name.replace('.', '/')}/{m.group(2)}")
    return found

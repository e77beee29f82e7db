"""What the packaging tests share: the checkout's root, its pyproject.toml, the packages and
console scripts it declares, and a subprocess environment that runs this tree's code."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10: tomli, as build (the test extra) has it there
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[2]


def pyproject() -> dict[str, Any]:
    return tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))


def top_packages() -> list[str]:
    """The import packages the distribution ships (pyproject.toml, [tool.setuptools] packages)."""
    return [p for p in pyproject()["tool"]["setuptools"]["packages"] if "." not in p]


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

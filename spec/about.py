"""What the tools say of themselves in every report and capture: the command's name, the
distribution's name and its version (read from the installed distribution, else from the
source checkout's ``pyproject.toml``). The lowest floor, so that every layer may name itself."""

from __future__ import annotations

import re
from pathlib import Path

__all__ = ["DIST_NAME", "TOOL_NAME", "tool_version"]

TOOL_NAME = "mcp-conform"  # the command's name, in reports
DIST_NAME = "centmesh-mcp-conform"  # the distribution's name (mcp-conform is taken on PyPI)


def tool_version() -> str:
    """The installed distribution's version, else the source checkout's pyproject.toml."""
    try:
        from importlib.metadata import PackageNotFoundError, version

        try:
            return version(DIST_NAME)
        except PackageNotFoundError:
            pass
    except ImportError:  # pragma: no cover
        pass
    pyproject = Path(__file__).resolve().parents[1] / "pyproject.toml"
    try:
        m = re.search(r'^version\s*=\s*"([^"]+)"', pyproject.read_text(), re.MULTILINE)
    except OSError:
        m = None
    return m.group(1) if m else "0+unknown"

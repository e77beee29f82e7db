"""What the tools say of themselves in every report and capture: the command's name, the
distribution's name and its version. ``__version__`` is the one place the version is written:
the build reads it (pyproject.toml, ``[tool.setuptools.dynamic]``), so the distribution's
metadata, the JSON reports, the captures' metadata and every ``--version`` say the same, from an
installed wheel, an unpacked sdist or a checkout alike. The lowest floor, so that every layer may
name itself."""

from __future__ import annotations

__all__ = ["DIST_NAME", "TOOL_NAME", "__version__", "tool_version"]

__version__ = "0.1.0"

TOOL_NAME = "mcp-conform"  # the command's name, in reports
DIST_NAME = "centmesh-mcp-conform"  # the distribution's name (mcp-conform is taken on PyPI)


def tool_version() -> str:
    """The version of the code that runs (``__version__``)."""
    return __version__

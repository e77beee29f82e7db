"""The ``mcp-conform`` entry point: SIGINT and SIGTERM are taken before anything heavy is
imported (``harness.interrupts`` needs only the standard library), so a signal at any
moment once the runner's code runs, its first half second included, still leaves the JSON
report. The handlers stay until the process ends, and the process ends with ``os._exit``
once its reports are written and its output flushed: the interpreter's finalization
restores the default handlers, and a signal arriving then would turn exit 2 into death by
signal.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Sequence

from mcp_conform.harness.interrupts import INTERRUPTS


def main(argv: Sequence[str] | None = None, *, exit_process: bool = True) -> int:
    """Run ``mcp-conform``; with ``exit_process`` the process ends here with its exit code."""
    code = _run(list(sys.argv[1:] if argv is None else argv))
    if not exit_process:
        return code
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(Exception):
            stream.flush()
    os._exit(code)


def _run(argv: list[str]) -> int:
    INTERRUPTS.install()
    try:
        with INTERRUPTS.held():  # a signal during the imports stops the run once they are done
            from mcp_conform.conformance import cli
    except KeyboardInterrupt:  # interrupted while importing: report that, nothing else
        INTERRUPTS.stop_raising()
        from mcp_conform.conformance import cli

        return cli.interrupted(argv)
    try:
        return cli.main(argv)
    finally:
        INTERRUPTS.stop_raising()

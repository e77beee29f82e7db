"""Output files and one-line usage errors, shared by every reader and writer of traces.

``UsageError`` is what a tool prints as one line and exits 2 on: a bad command line, an
output path that cannot be a file, a file that cannot be written. Outputs are checked before
any work starts, so a long run never fails at its end for a path it could have refused.
``ClosedAtExit`` closes, at interpreter exit, what a run left open (recorders, live servers)."""

from __future__ import annotations

import atexit
import weakref
from pathlib import Path
from typing import Any

__all__ = ["ClosedAtExit", "UsageError", "check_writable", "write_output"]


class UsageError(Exception):
    """A bad command line (one line)."""


def check_writable(path: str | None, option: str) -> None:
    """Refuse, before any work, an output path that cannot be a file."""
    if path is None or path == "-":  # "-": stdout (traceio.grammar)
        return
    target = Path(path)
    if not path or target.is_dir():
        raise UsageError(f"{option}: {path!r} is not a file name")
    if not target.expanduser().resolve().parent.is_dir():
        raise UsageError(f"{option}: directory of {path!r} does not exist")


def write_output(path: str, text: str, option: str) -> None:
    """Write a text output, or say in one line why it could not be written."""
    from mcp_conform.traceio.grammar import write_text

    try:
        write_text(path, text)
    except OSError as exc:
        raise UsageError(f"{option}: cannot write {path!r}: {exc.strerror or exc}") from None


class ClosedAtExit:
    """What is open, closed at interpreter exit by calling its ``close`` method (best effort:
    one that fails does not stop the others), so that a run interrupted by an exception or
    SIGTERM leaves valid capture files (``traceio.recorder``, ``traceio.background``) and
    nothing listening (``traceio.live``). Held weakly: what is dropped is not kept alive."""

    def __init__(self, close: str) -> None:
        self._open: weakref.WeakSet[Any] = weakref.WeakSet()
        self._close = close
        atexit.register(self.close_all)

    def add(self, obj: Any) -> None:
        self._open.add(obj)

    def discard(self, obj: Any) -> None:
        self._open.discard(obj)

    def __contains__(self, obj: Any) -> bool:
        return obj in self._open

    def close_all(self) -> None:
        for obj in list(self._open):
            try:
                getattr(obj, self._close)()
            except Exception:  # noqa: BLE001 - best effort at exit
                pass

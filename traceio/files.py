"""Output files and one-line usage errors, shared by every reader and writer of traces.

``UsageError`` is what a tool prints as one line and exits 2 on: a bad command line, an
output path that cannot be a file, a file that cannot be written. Outputs are checked before
any work starts, so a long run never fails at its end for a path it could have refused."""

from __future__ import annotations

from pathlib import Path

__all__ = ["UsageError", "check_writable", "write_output"]


class UsageError(Exception):
    """A bad command line (one line)."""


def check_writable(path: str | None, option: str) -> None:
    """Refuse, before any work, an output path that cannot be a file."""
    if path is None:
        return
    target = Path(path)
    if not path or target.is_dir():
        raise UsageError(f"{option}: {path!r} is not a file name")
    if not target.expanduser().resolve().parent.is_dir():
        raise UsageError(f"{option}: directory of {path!r} does not exist")


def write_output(path: str, text: str, option: str) -> None:
    """Write a text output, or say in one line why it could not be written."""
    try:
        Path(path).write_text(text, encoding="utf-8")
    except OSError as exc:
        raise UsageError(f"{option}: cannot write {path!r}: {exc.strerror or exc}") from None

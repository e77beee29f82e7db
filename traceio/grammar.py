"""The command-line grammar every tool shares (issue 40; the table is docs/grammar.md, checked
against each tool's parser by tests/tools/test_grammar.py): the exit-code epilog, ``--version``,
``-v``/``-q``, ``-`` for stdin and stdout, and old option names kept as hidden aliases that
print one warning line. ``mcp-vehicle`` keeps a copy of its own (``vehicle`` imports
nothing of ours).
"""

from __future__ import annotations

import argparse
import atexit
import contextlib
import os
import shutil
import sys
import tempfile
from collections.abc import Iterator, Sequence
from typing import Any, TextIO

__all__ = ["EXIT_CODES", "STDIO", "add_verbosity", "add_version", "deprecated", "epilog", "open_output",
           "read_path", "version_text", "write_text"]

#: The one exit-code convention, printed at the end of every tool's ``--help``.
EXIT_CODES = ("exit codes: 0 ok, 1 findings or failures, 2 usage or setup error (one line on stderr),\n"
              "  130 interrupted (128 + the signal's number: 143 for SIGTERM)")
#: The file name that means stdin (an input) or stdout (an output).
STDIO = "-"


def epilog(*lines: str) -> str:
    """``--help``'s epilog: the tool's own lines, then :data:`EXIT_CODES`."""
    return "\n".join([*lines, EXIT_CODES])


def version_text(prog: str) -> str:
    """``PROG VERSION (MCP spec V)``: what every ``--version`` prints."""
    from mcp_conform.spec import SPEC
    from mcp_conform.spec.about import tool_version

    return f"{prog} {tool_version()} (MCP spec {SPEC.version})"


def add_version(p: argparse.ArgumentParser, prog: str) -> None:
    p.add_argument("--version", action="version", version=version_text(prog),
                   help="print the version and exit")


def add_verbosity(p: argparse.ArgumentParser, verbose: str, quiet: str) -> None:
    """``-v/--verbose`` and ``-q/--quiet``, one or the other, with what each does for this tool."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("-v", "--verbose", action="store_true", help=verbose)
    g.add_argument("-q", "--quiet", action="store_true", help=quiet)


class _Deprecated(argparse.Action):
    """An old spelling: sets the new option's value and says, once, on stderr, what to use."""

    def __init__(self, option_strings: Sequence[str], dest: str, new: str = "", const: Any = None,
                 nargs: Any = None, **kw: Any) -> None:
        self.new = new
        super().__init__(option_strings, dest, nargs=nargs, const=const, **kw)

    def __call__(self, parser: argparse.ArgumentParser, ns: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(f"{parser.prog}: warning: {option_string} is deprecated; use {self.new}", file=sys.stderr)
        setattr(ns, self.dest, self.const if self.nargs == 0 else values)


def deprecated(p: argparse.ArgumentParser | Any, old: str, new: str, *, dest: str | None = None,
               flag: Any = None, type: Any = None) -> None:
    """Keep ``old`` working as a hidden alias of ``new`` (same destination): ``flag`` is the
    value a flag alias stores (it takes no argument); ``new`` is what the warning suggests."""
    dest = dest or new.split()[0].lstrip("-").replace("-", "_")
    kw: dict[str, Any] = {"nargs": 0, "const": flag} if flag is not None else {"type": type}
    p.add_argument(old, action=_Deprecated, new=new, dest=dest, default=argparse.SUPPRESS,
                   help=argparse.SUPPRESS, **kw)


@contextlib.contextmanager
def open_output(path: str) -> Iterator[TextIO]:
    """The text file ``path`` open for writing, or stdout (left open) for ``-``."""
    if path == STDIO:
        yield sys.stdout
        sys.stdout.flush()
        return
    with open(path, "w", encoding="utf-8") as f:
        yield f


def write_text(path: str, text: str) -> None:
    """Write ``text`` to the file ``path``, or to stdout for ``-`` (an OSError names the file)."""
    with open_output(path) as f:
        f.write(text)


def read_path(path: str) -> str:
    """A file name for an input: ``path`` itself, or for ``-`` a temporary copy of stdin (the
    readers seek and sniff the format), removed at exit."""
    if path != STDIO:
        return path
    folder = tempfile.mkdtemp(prefix="mcp-")
    atexit.register(shutil.rmtree, folder, True)
    name = os.path.join(folder, "stdin")
    with open(name, "wb") as out:
        shutil.copyfileobj(sys.stdin.buffer, out)
    return name


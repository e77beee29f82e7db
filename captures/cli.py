"""``mcp-capture``: tools for MCP captures (our MCAP runs, pcap/pcapng from tcpdump or Wireshark).

    mcp-capture check FILE [--rto S] [--ack-window S] [--challenge N] [--drones 1,2,...]
                           [--waypoints FILE] [--select PREFIX] [--strict] [--json OUT] [--html OUT]
    mcp-capture show FILE [--from S] [--to S] [--case ID] [--svg OUT] [monitor options]
    mcp-capture diff GOLDEN CANDIDATE [--copies-tolerance N] [--time-tolerance S] [--addresses]
                     [--json OUT] [--html OUT]
    mcp-capture replay CAPTURE --target HOST:PORT | --spawn CMD [--role drone|manager] [--listen ...]
    mcp-capture export CAPTURE --pcap OUT.pcap|OUT.pcapng
    mcp-capture dissector [--install | -o FILE [--mavlink FILE]]

Every subcommand that reads a capture picks its protocol once and hands the work to that
protocol's capture tools: ``--protocol``, else the first protocol whose profile recognises
the file (``capture_profile``: each profile in ``spec.profiles`` names its ``capture_detect``),
else the default; the plug-in of the profile's ``capture_tools`` module (:class:`CaptureTools`,
``captures.trace_tools.CapturePlugin``: MCP's ``captures.mcp``, MAVLink's ``captures.mavlink``,
Nsqd's ``captures.nsqd``) then checks, shows, diffs, exports or replays it.
A subcommand's own module keeps what is the same for every protocol: its options, their
checks, its errors.

Each subcommand lives in its own module, which this one only registers: the module has
``register(subparsers)``, adding its parser and ``set_defaults(run=FUNCTION)``; ``run(ns)``
returns the exit code. To add one, append its module to :data:`SUBCOMMANDS`.

Exit codes are the subcommand's (``check``: 0 no MUST violated, 1 violations; ``diff`` and
``replay``: 0 same, 1 different); a bad
argument or an unreadable file is a one-line error naming what was wrong, exit 2; Ctrl-C 130.
The options follow the tools' one grammar (``traceio.grammar``, docs/grammar.md): a capture
named ``-`` is read from stdin, ``--json -`` (``--html -``, ``--svg -``) writes to stdout, the
terminal report then going to stderr; ``-v``/``-q`` after the subcommand.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import os
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, NoReturn, Protocol, TextIO

from mcp_conform.spec import profiles
from mcp_conform.spec.profiles import PROFILES, Profile, pick, resolve
from mcp_conform.traceio.files import UsageError, check_writable, write_output
from mcp_conform.traceio.grammar import STDIO, add_verbosity, add_version, epilog, read_path

__all__ = ["PROG", "SUBCOMMANDS", "CaptureTools", "UsageError", "add_protocol_option", "build_parser",
           "capture_profile", "capture_tools", "check_writable", "main", "to_terminal", "write_output"]

PROG = "mcp-capture"
#: The modules that register a subcommand, in the order ``--help`` lists them.
SUBCOMMANDS: list[str] = ["mcp_conform.captures.check", "mcp_conform.captures.show", "mcp_conform.captures.diff", "mcp_conform.captures.replay",
                           "mcp_conform.captures.export", "mcp_conform.captures.dissector"]


def add_protocol_option(p: argparse.ArgumentParser) -> None:
    """``--protocol``, as every subcommand that reads a capture takes it."""
    profiles.add_protocol_option(p, f"read the capture as this protocol's traffic "
                                    f"({', '.join(profiles.having('capture_tools'))}; default: as its first "
                                    "records show)", needs="capture_tools")


class CaptureTools(Protocol):
    """What a protocol's capture tools module (its profile's ``capture_tools``) provides: the
    work of each ``mcp-capture`` subcommand on that protocol's captures, the options already
    parsed and checked. Each ``run_*`` returns the exit code."""

    #: what ``export`` writes, as its closing line counts them ("datagrams", "TCP packets")
    EXPORTED: str

    def run_check(self, ns: argparse.Namespace, out: TextIO | None = None) -> int: ...

    def run_show(self, ns: argparse.Namespace, out: TextIO | None = None) -> int: ...

    def run_diff(self, ns: argparse.Namespace, out: TextIO | None = None, err: TextIO | None = None) -> int: ...

    def export_pcap(self, capture: str | Path, out: str | Path) -> tuple[int, str | None]: ...

    def run_replay(self, ns: argparse.Namespace, out: TextIO | None = None, err: TextIO | None = None) -> int: ...


def capture_profile(ns: Any, path: str) -> Profile:
    """The protocol a capture is read as: ``--protocol``, else the first whose profile
    recognises the file (``capture_detect``), else the default. A detector that cannot read
    the file as its protocol's (CaptureError, OSError) says "not mine": the next one is asked
    (Nsqd's reads a tlog as no capture at all; MAVLink's, after it, recognises it), and a file
    nobody recognises gets the default's one-line error."""
    from mcp_conform.traceio.reader import CaptureError

    name = getattr(ns, "protocol", None)
    if name is not None:
        return pick(name)[0]
    for prof in PROFILES.values():
        if prof.capture_detect is None:
            continue
        try:
            if resolve(prof.capture_detect)(path):
                return prof
        except (CaptureError, OSError):
            continue
    return pick()[0]


def capture_tools(ns: Any, path: str) -> CaptureTools:
    """The capture tools of the protocol ``path`` is read as (:func:`capture_profile`): the
    plug-in its profile's ``capture_tools`` module declares (``PLUGIN``, a
    ``captures.trace_tools.CapturePlugin``), every subcommand's one path."""
    tools: CaptureTools = resolve(capture_profile(ns, path).capture_tools).PLUGIN
    return tools


class _Parser(argparse.ArgumentParser):
    """argparse that raises instead of printing its usage and exiting."""

    def error(self, message: str) -> NoReturn:
        command = self.prog.removeprefix(PROG).strip()  # a subcommand's: "check: ..."
        raise UsageError(f"{command}: {message}" if command else message)


#: ``-q`` (``main``): no terminal report; ``-`` as an output: the terminal report on stderr.
_TERMINAL = {"quiet": False, "stderr": False}
#: The inputs (positionals) that may be ``-``, stdin; the outputs that may be ``-``, stdout.
_INPUTS = ("file", "golden", "candidate", "capture")
_OUTPUTS = ("json", "html", "svg")


def to_terminal(write: Callable[[], Any]) -> None:
    """Print the terminal report, which comes after the files (``--json``, ``--html``): a
    reader that went away (``| head -1``) loses the rest of it, never the files or the exit
    code (the verdict)."""
    if _TERMINAL["quiet"]:
        return
    try:
        if _TERMINAL["stderr"]:
            with contextlib.redirect_stdout(sys.stderr):
                write()
        else:
            write()
        sys.stdout.flush()
    except (BrokenPipeError, SystemExit) as exc:  # rich turns a broken pipe into SystemExit(1)
        if not isinstance(exc, BrokenPipeError) and not isinstance(exc.__context__, BrokenPipeError):
            raise
        with contextlib.suppress(OSError, ValueError):  # nothing more reaches the pipe
            os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="Read, judge and chart MCP captures: our MCAP files "
                "(mcp-conform --capture) and pcap/pcapng as tcpdump and Wireshark write them.",
                epilog=epilog("A capture named - is read from stdin."),
                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version(p, PROG)
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=_Parser)
    for name in SUBCOMMANDS:
        importlib.import_module(name).register(sub)
    for sp in sub.choices.values():
        sp.epilog = epilog(*([sp.epilog] if sp.epilog else []))
        sp.formatter_class = argparse.RawDescriptionHelpFormatter
        add_verbosity(sp, "check: every violation in full, not 3 per rule (the others print all they have already)",
                      "no terminal report: the exit code, errors and the files asked for only")
    return p


def _error(message: str) -> int:
    print(f"{PROG}: error: {message}", file=sys.stderr)
    return 2


def main(argv: Sequence[str] | None = None) -> int:
    """The tools' entry point: the exit code. Out of memory anywhere (a module to import under
    ``ulimit -v``, a capture too large) is one line and exit 2, as a bad file is; the reader
    says where in the capture it ran out ("out of memory reading it near byte N")."""
    try:
        return _main(argv)
    except MemoryError:
        return _error(_OOM)
    except OSError as exc:  # ENOMEM from the system (importlib listing a package's directory)
        if exc.errno != errno.ENOMEM:
            raise
        return _error(_OOM)


_OOM = "out of memory (the host's, or an address-space limit such as ulimit -v)"


def _main(argv: Sequence[str] | None) -> int:
    from mcp_conform.traceio.reader import CaptureError

    parser = build_parser()
    try:
        ns = parser.parse_args(argv)
    except UsageError as exc:
        return _error(str(exc))
    if getattr(ns, "run", None) is None:
        return _error("a COMMAND is required: " + ", ".join(m.rsplit(".", 1)[1] for m in SUBCOMMANDS)
                      + f" ({PROG} --help)")
    _TERMINAL["quiet"] = bool(getattr(ns, "quiet", False))
    _TERMINAL["stderr"] = any(getattr(ns, o, None) == STDIO for o in _OUTPUTS)
    try:
        stdin = [a for a in _INPUTS if getattr(ns, a, None) == STDIO]
        if len(stdin) > 1:
            raise UsageError("only one capture can be read from stdin (-)")
        for a in stdin:
            setattr(ns, a, read_path(STDIO))
        return int(ns.run(ns))
    except (CaptureError, UsageError) as exc:
        return _error(str(exc))
    except BrokenPipeError:  # `mcp-capture show big.pcap | head`
        sys.stderr.close()
        return 0
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())

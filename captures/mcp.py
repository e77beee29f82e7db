"""``mcp-capture check|show|diff|export|replay`` on an MCP capture: the capture tools MCP's
profile names (``spec.profiles``), which ``captures.cli.capture_tools`` hands each subcommand
(``captures.cli.CaptureTools``), as Nsqd's are ``captures.nsqd``.

Its plug-in (:data:`PLUGIN`, a ``captures.trace_tools.CapturePlugin`` as every protocol's
is) gives each subcommand the datagram core's own, in the subcommand's module: ``check`` the trace monitor's
judgement (``captures.check``), ``show`` the listing and chart (``captures.show``), ``export``
one UDP packet a datagram (``captures.export``), ``replay`` one side played against a live
node (``captures.replay``); ``diff`` (here) the two captures as conversations, sender by
sender (``captures.diff``).
"""

from __future__ import annotations

import json
import sys
from typing import Any, TextIO

from mcp_conform.captures import check, export, replay, show
from mcp_conform.captures.diff import DiffOptions, build_json, diff_captures, print_report
from mcp_conform.captures.trace_tools import CapturePlugin
from mcp_conform.spec import SPEC

__all__ = ["PLUGIN", "run_diff"]


def run_diff(args: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """MCP's diff: exit 0 same, 1 different, 2 an output that cannot be written."""
    from mcp_conform.captures.cli import to_terminal
    from mcp_conform.traceio.grammar import write_text

    err = err or sys.stderr
    opts = DiffOptions(args.copies_tolerance, args.time_tolerance, args.addresses, args.context)
    result = diff_captures(args.golden, args.candidate, opts)
    try:  # the files first: a piped terminal report (`| head -1`) loses neither
        if args.json:  # "-": stdout (traceio.grammar)
            write_text(args.json, json.dumps(build_json(result), indent=1) + "\n")
        if args.html:
            from mcp_conform.captures.diff_html import write_html

            write_html(result, args.html)
    except OSError as exc:
        err.write(f"mcp-capture: error: diff: cannot write {exc.filename}: {exc.strerror}\n")
        return 2
    to_terminal(lambda: print_report(result, out or sys.stdout))
    return 0 if result.same else 1


class _Mcp(CapturePlugin):
    name, spec, EXPORTED = "mcp", SPEC, "datagrams"

    def run_check(self, ns: Any, out: TextIO | None = None) -> int:
        return check.run_check(ns)

    def run_show(self, ns: Any, out: TextIO | None = None) -> int:
        return show.run_show(ns)

    def run_diff(self, ns: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
        return run_diff(ns, out, err)

    def export_pcap(self, capture: Any, out: Any) -> tuple[int, str | None]:
        return export.export_pcap(capture, out)

    def run_replay(self, ns: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
        return replay.run_replay(ns, out, err)


PLUGIN = _Mcp()

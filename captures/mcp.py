"""``mcp-capture check|show|diff|export|replay`` on an MCP capture: the capture tools MCP's
profile names (``spec.profiles``), which ``captures.cli.capture_tools`` hands each subcommand
(``captures.cli.CaptureTools``), as Nsqd's are ``captures.nsqd``.

Each is the datagram core's own, in the subcommand's module: ``check`` the trace monitor's
judgement (``captures.check``), ``show`` the listing and chart (``captures.show``), ``export``
one UDP packet a datagram (``captures.export``), ``replay`` one side played against a live
node (``captures.replay``); ``diff`` (here) the two captures as conversations, sender by
sender (``captures.diff``).
"""

from __future__ import annotations

import json
import sys
from typing import Any, TextIO

from mcp_conform.captures.check import run_check
from mcp_conform.captures.diff import DiffOptions, build_json, diff_captures, print_report
from mcp_conform.captures.export import export_pcap
from mcp_conform.captures.replay import run_replay
from mcp_conform.captures.show import run_show

__all__ = ["EXPORTED", "export_pcap", "run_check", "run_diff", "run_replay", "run_show"]

#: what ``export`` writes (``captures.export``'s closing line)
EXPORTED = "datagrams"


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

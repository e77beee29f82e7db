"""``mcp-capture show FILE``: a capture as a readable listing, and as a sequence chart.

One line per datagram: its index, the time since the first datagram, src → dst by MCP ID
and address, seq, action, the decoded payload, and the marks a reader looks for —
``↻k of #i`` (the k-th retransmission of datagram i), ``ACK #j +Δ`` (answered by j after
Δ), ``no ACK`` (a unicast copy nothing answered), ``answers #i`` (an ACK), ``✗ RULE`` (a
violation the monitor found, on the datagrams of its evidence), and the codec's reason for
a datagram that does not decode. ``--from S`` / ``--to S`` (seconds since the first
datagram) or ``--case ID`` (an MCAP capture's case marks) cut a window; ``--svg OUT``
writes the window's message-sequence chart (``reports.chart``).
"""

from __future__ import annotations

import argparse
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.text import Text

from mcp_conform.captures.cli import (
    UsageError,
    add_protocol_option,
    capture_tools,
    check_writable,
    write_output,
)
from mcp_conform.judge.params import add_monitor_options, params_from_args
from mcp_conform.reports.chart import trace_svg
from mcp_conform.traceio.trace import Entry, Trace, action_name, describe_payload

if TYPE_CHECKING:
    from mcp_conform.judge.judging import Judgement

__all__ = ["case_window", "entry_line", "register", "run", "run_show"]


def register(sub: Any) -> None:
    p = sub.add_parser("show", help="list a capture's datagrams; --svg: a sequence chart",
                       description="List a capture's MCP datagrams with retransmissions, ACK pairing "
                       "and the monitor's violations marked; --svg writes a message-sequence chart.")
    p.add_argument("file", metavar="FILE", help="the capture (MCAP, pcap, pcapng)")
    p.add_argument("--from", dest="t_from", metavar="S", help="start at S seconds after the first datagram")
    p.add_argument("--to", dest="t_to", metavar="S", help="stop at S seconds after the first datagram")
    p.add_argument("--case", metavar="ID", help="only the traffic of this conformance case (MCAP captures)")
    p.add_argument("--svg", metavar="OUT", help="write the window's message-sequence chart as SVG")
    p.add_argument("--max-rows", metavar="N", default="400", help="rows of the chart at most (default 400)")
    p.add_argument("--segment", metavar="NAME", help="a capture of several sessions (merged from pytest-xdist "
                   "workers: gw0 ...; a manager-role run's missions: main, silent): only this session (each "
                   "is listed and charted apart; the chart is the first's by default)")
    add_monitor_options(p)
    add_protocol_option(p)
    p.set_defaults(run=run)


def _seconds(option: str, text: str | None) -> float | None:
    if text is None:
        return None
    try:
        value = float(text)
    except ValueError:
        raise UsageError(f"{option}: not a number of seconds: {text!r}") from None
    if value < 0 or value != value:
        raise UsageError(f"{option}: must be 0 or more seconds: {text!r}")
    return value


def case_window(j: Judgement, case_id: str) -> tuple[int, int]:
    """(start_ns, end_ns) of a case from the capture's case marks; exact ID, else a unique prefix."""
    ids = list(dict.fromkeys(m.case for m in j.cases))
    if not ids:
        raise UsageError(f"--case: {j.path} has no case marks (only mcp-conform's MCAP captures have them)")
    match = [c for c in ids if c == case_id] or [c for c in ids if c.startswith(case_id)]
    if len(match) != 1:
        some = ", ".join(ids[:5]) + (", ..." if len(ids) > 5 else "")
        what = "matches several cases" if match else "is not a case of this capture"
        raise UsageError(f"--case: {case_id!r} {what} ({len(ids)} cases: {some})")
    marks = [m for m in j.cases if m.case == match[0]]
    start = min(m.t_ns for m in marks)
    ends = [m.t_ns for m in marks if m.event == "end"]
    return start, max(ends) if ends else (j.last_ns or start)


def run(ns: argparse.Namespace) -> int:
    """``mcp-capture show``: the options checked, then the capture's protocol's show."""
    params_from_args(ns)  # the monitor options' errors, whatever the protocol
    t_from, t_to = _seconds("--from", ns.t_from), _seconds("--to", ns.t_to)
    if ns.case is not None and (t_from is not None or t_to is not None):
        raise UsageError("--case cannot be combined with --from/--to")
    try:
        max_rows = int(ns.max_rows)
        if max_rows < 1:
            raise ValueError
    except ValueError:
        raise UsageError(f"--max-rows: not a positive integer: {ns.max_rows!r}") from None
    check_writable(ns.svg, "--svg")
    ns.max_rows = max_rows
    return int(capture_tools(ns, ns.file).run_show(ns))


def run_show(ns: argparse.Namespace) -> int:
    """MCP's show (``captures.mcp``): the datagrams, marked by the trace monitor."""
    # imported here: see check.run_check
    from mcp_conform.judge.judging import MonitorUnavailable, NoJudge, judge

    params = params_from_args(ns)
    t_from, t_to = _seconds("--from", ns.t_from), _seconds("--to", ns.t_to)
    max_rows = int(ns.max_rows)
    unjudged = None
    try:
        j = judge(ns.file, params, keep=True)
    except MonitorUnavailable as exc:
        unjudged = f"violations not marked: {exc}"
        j = judge(ns.file, params, keep=True, monitor=NoJudge())
    sessions = _sessions(j, getattr(ns, "segment", None))
    seg_name, part = sessions[0]
    trace = Trace(part.kept or (), params.broadcast_id)
    trace.mark(part.shown_violations)
    start: int | None
    end: int | None
    if ns.case is not None:
        start, end = case_window(j, ns.case)
    else:
        base = j.first_ns or 0
        start = None if t_from is None else base + int(t_from * 1e9)
        end = None if t_to is None else base + int(t_to * 1e9)
    entries = trace.window(start, end)
    if ns.svg:  # before the listing: a reader that stops early (| head) still gets the chart
        title = f"{j.path}" + (f" · session {seg_name}" if seg_name else "") + (
            f" · case {ns.case}" if ns.case else "")
        # times since the capture's first datagram, as the listing's (--from 12 starts at +12 s)
        write_output(ns.svg, trace_svg(trace, entries, title=title, max_rows=max_rows,
                                       t0_ns=j.first_ns), "--svg")
    con = Console(highlight=False, soft_wrap=True)
    con.print(Text(f"{j.path} · {j.format} · {len(entries)} of {j.datagrams} datagram(s) shown"
                   + (f" · case {ns.case}" if ns.case else "") + (f" · chart: {ns.svg}" if ns.svg else ""),
                   style="bold"))
    if j.truncated:
        con.print(Text(f"truncated: {j.truncated}", style="yellow"))
    for note in [*j.notes, *([unjudged] if unjudged else [])]:
        con.print(Text(f"note: {note}", style="dim"))
    for n, (name, part) in enumerate(sessions):
        if n:  # each worker's session on its own lifelines: two workers' drone 1 are two nodes
            trace = Trace(part.kept or (), params.broadcast_id)
            trace.mark(part.shown_violations)
            entries = trace.window(start, end)
        if name is not None:
            con.print(Text(f"── session {name}: {len(entries)} datagram(s)"
                           + (" · the chart's" if n == 0 and ns.svg else ""), style="bold"))
        for e in entries:
            con.print(entry_line(e, trace, j.first_ns or 0))
    return 0


def _sessions(j: Judgement, only: str | None) -> list[tuple[str | None, Judgement]]:
    """The sessions to show: the whole capture, or each worker's of a merged one (issue 18
    item 7: one chart drew two workers' drones as one) -- or the one ``--segment`` names."""
    if not j.segments:
        if only is not None:
            raise UsageError(f"--segment: {j.path} holds one session (not merged from workers, no missions of its own)")
        return [(None, j)]
    if only is not None:
        if only not in j.segments:
            raise UsageError(f"--segment: {only!r} is not a session of {j.path} ({', '.join(j.segments)})")
        return [(only, j.segments[only])]
    return list(j.segments.items())


def _addr(addr: Any) -> str:
    return f"{addr[0]}:{addr[1]}" if addr else ""


def _end(node: str, addr: Any) -> str:
    a = _addr(addr)
    return f"{node} {a}" if a and a != node else node


def entry_line(e: Entry, trace: Trace, first_ns: int) -> Text:
    d = e.dgram
    line = Text()
    line.append(f"#{d.index:<6}", style="dim")
    line.append(f"+{(d.t_ns - first_ns) / 1e9:11.6f}s  ")
    line.append(f"{_end(e.src, d.src_addr)} → {_end(e.dst, d.dst_addr)}")
    if e.header is not None:
        line.append(f"  seq {e.header[2]:<5} ")
        line.append(action_name(e.header[3]), style="bold" if e.msg is not None else "bold red")
        if e.msg is not None:
            desc = describe_payload(e.msg)
            if desc:
                line.append(f"  {desc}")
    else:
        line.append(f"  {len(d.data)} bytes, no MCP header", style="red")
    if e.error:
        line.append(f"  [{e.error}]", style="red")
    if e.first is not None:
        line.append(f"  ↻{e.copy} of #{e.first}", style="yellow")
    if e.acked_by is not None:
        ack = trace.by_index.get(e.acked_by)
        dt = f" +{(ack.dgram.t_ns - d.t_ns) / 1e6:.1f} ms" if ack is not None else ""
        line.append(f"  ACK #{e.acked_by}{dt}", style="green")
    elif e.unanswered:
        line.append("  no ACK", style="yellow")
    if e.ack_of is not None:
        line.append(f"  answers #{e.ack_of}", style="green")
    for rule in dict.fromkeys(v.rule for v in e.violations):
        line.append(f"  ✗ {rule}", style="bold red")
    return line

"""The capture tools of a stream protocol (its profile's framing ``stream``: frames deframed
from TCP connections, docs/design.md "A protocol is a plug-in"), the protocol a parameter: a
:class:`StreamPlugin` names its reader (``traceio``: our MCAP's stream channels, a pcap's TCP
connections through its deframer), its monitor, how the client's writes and the node's frames
are compared, and its chart; this module does the rest, as ``captures.trace_tools`` does for
every judged protocol:

- ``check``: each connection (its addresses, the client's bytes, the node's frames, how it
  ended, the rule it broke), the gaps of the capture, every connection judged by the monitor
  (the node's frames; a connection with bytes missing is judged up to the gap);
- ``show``: one line per write, frame, event and gap, as they are read (nothing kept but the
  chart's frames, up to ``--max-rows``);
- ``export``: the conversations as a pcap/pcapng tshark follows (``traceio.tcp_pcap``; the
  command, its errors and its output are ``captures.export``'s);
- ``diff``: per connection, in order, the client's frames and the node's answers (identical
  neighbours folded) and how it ended.

Connections are listed (and compared) up to :data:`MAX_LISTED`, steps up to
:data:`MAX_STEPS` a connection, gaps up to :data:`MAX_GAPS`: a hostile capture's flood stays
bounded in memory.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO

from mcp_conform.captures import trace_tools as core
from mcp_conform.captures.trace_tools import Checked, Compared
from mcp_conform.judge.verdicts import Found, of_nsqd
from mcp_conform.traceio.grammar import write_text
from mcp_conform.traceio.reader import CaseMark, StreamEvent, StreamFrame, Truncated, open_capture
from mcp_conform.traceio.tcp import StreamGap

__all__ = ["MAX_GAPS", "MAX_LISTED", "MAX_STEPS", "ROWS", "StreamPlugin", "export_pcap", "run_show"]

MAX_LISTED = 10000
MAX_STEPS = 100000
MAX_GAPS = 1000
ROWS = 200  # connections listed in the terminal report at most (all of them in --json, up to MAX_LISTED)


_SHOWN = (StreamFrame, StreamEvent, StreamGap)  # the records show lists


def _addr(a: Any) -> str:
    return f"{a[0]}:{a[1]}" if a else "?"


class StreamPlugin(core.CapturePlugin):
    """A stream protocol's captures (see the module docstring)."""

    title: str  # what one capture is called in the header of check and show
    monitor: Any  # its monitor's class, made with its spec
    port: int  # the node's TCP port (export: the conversations' server side)
    json_when_same = False

    def nothing_in(self, path: str | Path) -> Exception:
        """The one-line error of a file with no connection of this protocol in it (an MCP
        capture given ``--protocol nsqd``, a pcap of other traffic): nothing to judge, never a
        verdict of OK, as MAVLink's tools refuse a file without a MAVLink frame."""
        from mcp_conform.traceio.reader import CaptureError

        return CaptureError(f"{path}: no {self.title.removesuffix(' capture')} connection in it (an MCAP of "
                            f"mcp-conform --protocol {self.name}, or a pcap of its TCP traffic, holds them)")

    def records(self, path: str) -> Iterator[Any]:
        """The capture's records (``StreamFrame``, ``StreamEvent``, ``StreamGap``, ...)."""
        raise NotImplementedError

    def deframer(self) -> Any:
        """A deframer of the client's bytes (``feed(bytes)``: frames and refused bytes)."""
        raise NotImplementedError

    def client_step(self, item: Any) -> str:
        """What diff compares of one item of the client's deframed writes."""
        raise NotImplementedError

    def answer(self, rec: StreamFrame) -> tuple[str, str]:
        """What diff compares of one frame of the node's, as a step (kind, text); identical
        neighbours are folded."""
        raise NotImplementedError

    def chart(self, frames: list[StreamFrame], title: str) -> str:
        """``show --svg``: the sequence chart of ``frames``."""
        raise NotImplementedError

    def run_show(self, ns: Any, out: TextIO | None = None) -> int:
        return run_show(self, ns, out)

    def export_pcap(self, capture: str | Path, out: str | Path) -> tuple[int, str | None]:
        return export_pcap(self, capture, out)

    def check(self, ns: Any) -> Checked:
        seen = _Conns(self, ns.file).read()
        v = of_nsqd(seen.monitor, core.selection(ns), strict=core.strict(ns), truncated=seen.truncated)
        failed = [r for r, verdict in v.rules.items() if verdict == "failed"]
        broke = {dict(f.more)["conn"]: f.rule for f in v.found if f.rule in failed}
        notes = [f"connection {g.conn} {'backend' if g.direction == 'rx' else 'client'} bytes: {g.reason}"
                 for g in seen.gaps[:20]]
        if seen.n_gaps > 20:
            notes.append(f"... and {seen.n_gaps - 20} more gap(s) in the capture")
        conns = [f"  conn {n}: {_addr(c['client'])} -> {_addr(c['backend'])}: client wrote {c['tx']} B, backend sent "
                 f"{c['rx']} frame(s); {'closed ' + ', '.join(c['end']) if c['end'] else 'open'}"
                 f"{'; BROKE ' + broke[n] if n in broke else ''}" for n, c in sorted(seen.conns.items())[:ROWS]]
        if seen.n_conns > ROWS:
            conns.append(f"  ... and {seen.n_conns - ROWS} more connection(s)")
        backends: dict[str, dict[str, Any]] = {}
        for c in seen.conns.values():
            b = backends.setdefault(_addr(c["backend"]), {"id": _addr(c["backend"]), "role": "backend", "connections": 0,
                                                          "frames": 0})
            b["connections"] += 1
            b["frames"] += c["rx"]

        def line(f: Found) -> str:
            return core.found_line(f"conn {dict(f.more)['conn']}", f, seen.first_ns or f.t_ns)
        return core.checked(
            self, ns, v, [f"{ns.file}: {self.title}, {seen.n_conns} connection(s)"],
            {"path": str(ns.file), "format": seen.format, "truncated": seen.truncated, "notes": notes,
             "duration_s": round(seen.duration_s, 9)}, {"complete": not seen.n_gaps}, list(backends.values()),
            first_ns=seen.first_ns, after=conns, line=line, unit=" connection(s)",
            own={"connection_count": seen.n_conns,
                 "connections": [{"conn": n, "client": _addr(c["client"]), "backend": _addr(c["backend"]),
                                  "client_bytes": c["tx"], "backend_frames": c["rx"], "end": c["end"]}
                                 for n, c in sorted(seen.conns.items())],
                 "gaps": [g._asdict() for g in seen.gaps], "failed_count": v.counts},
            tail=[f"(the rules judged by what the runner's cases send need mcp-conform --protocol {self.name})"])

    def compare(self, golden: str, candidate: str) -> Compared:
        g, c = _Conns(self, golden, steps=True).read(), _Conns(self, candidate, steps=True).read()
        diffs: list[str] = []
        if g.n_conns != c.n_conns:
            diffs.append(f"connections: {g.n_conns} in the golden, {c.n_conns} in the candidate")
        for (gn, gc), (cn, cc) in zip(sorted(g.conns.items()), sorted(c.conns.items()), strict=False):
            ga, ca = gc["answers"] + [("client bytes", str(gc["tx"]))], cc["answers"] + [("client bytes", str(cc["tx"]))]
            for i, (x, y) in enumerate(zip(ga, ca, strict=False)):
                if x != y:
                    diffs.append(f"conn {gn}/{cn} step {i + 1}: golden {x[0]} {x[1][:80]}; candidate {y[0]} {y[1][:80]}")
                    break
            else:
                if len(ga) != len(ca):
                    longer, which = (ga, "golden") if len(ga) > len(ca) else (ca, "candidate")
                    nxt = longer[min(len(ga), len(ca))]
                    diffs.append(f"conn {gn}/{cn}: only the {which} goes on: {nxt[0]} {nxt[1][:80]}")
        notes = [f"only the first {MAX_LISTED} connections of each are compared"] \
            if max(g.n_conns, c.n_conns) > MAX_LISTED else []
        return Compared(diffs, [f"  {d}" for d in diffs[:50]],
                        f"{g.n_conns} connection(s), the client's writes and the backend's answers alike", "",
                        [(g.path, g.truncated), (c.path, c.truncated)], notes)


class _Conns:
    """What a capture holds, per connection (the first :data:`MAX_LISTED`), with the monitor's
    judgement of every connection."""

    def __init__(self, plugin: StreamPlugin, path: str, *, steps: bool = False) -> None:
        self.plugin, self.path = plugin, path
        self.steps = steps  # keep each connection's steps (diff)
        self.monitor = plugin.monitor(plugin.spec)
        self.conns: dict[int, dict[str, Any]] = {}
        self.n_conns = 0  # connections are numbered 1, 2, ... in both kinds of capture
        self.truncated: str | None = None
        self.gaps: list[StreamGap] = []
        self.n_gaps = 0
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.format = open_capture(path).format

    @property
    def duration_s(self) -> float:
        return ((self.last_ns or 0) - (self.first_ns or 0)) / 1e9

    def conn(self, n: int) -> dict[str, Any] | None:
        c = self.conns.get(n)
        if c is None:
            self.n_conns = max(self.n_conns, n)
            if len(self.conns) >= MAX_LISTED:
                return None
            c = self.conns[n] = {"client": None, "backend": None, "tx": 0, "rx": 0, "end": [], "answers": []}
        return c

    def _step(self, c: dict[str, Any], step: tuple[str, str], fold: bool = False) -> None:
        if self.steps and len(c["answers"]) < MAX_STEPS and not (fold and c["answers"] and c["answers"][-1] == step):
            c["answers"].append(step)

    def read(self) -> _Conns:
        for rec in self.plugin.records(self.path):
            kind = type(rec)
            if kind is Truncated:
                self.truncated = rec.reason
                continue
            t = getattr(rec, "t_ns", None)
            if t is not None:
                self.last_ns = t
                if self.first_ns is None:
                    self.first_ns = t
            if kind is StreamFrame:
                c = self.conn(rec.conn)
                if rec.direction == "rx":
                    self.monitor.backend_bytes(rec.conn, rec.raw, rec.t_ns)
                if c is None:
                    continue
                if rec.direction == "tx":  # compared as frames: writes and segments cut them differently
                    c["tx"] += len(rec.raw)
                    if self.steps:
                        if "deframer" not in c:
                            c["deframer"] = self.plugin.deframer()
                        for item in c["deframer"].feed(rec.raw):
                            self._step(c, ("client", self.plugin.client_step(item)))
                    continue
                c["rx"] += 1
                if self.steps:
                    self._step(c, self.plugin.answer(rec), fold=True)
            elif kind is StreamEvent:
                c = self.conn(rec.conn)
                if c is None:
                    continue
                if rec.event == "open":
                    c["client"], c["backend"] = rec.client, rec.backend
                else:
                    c["end"].append(f"{rec.by} {rec.how}")
                    self._step(c, ("close", f"{rec.by} {rec.how}"))
            elif kind is StreamGap:
                self.n_gaps += 1
                if len(self.gaps) < MAX_GAPS:
                    self.gaps.append(rec)
                if rec.direction == "rx":
                    self.monitor.unjudgeable(rec.conn, rec.reason)
        if not self.n_conns:
            raise self.plugin.nothing_in(self.path)
        return self


def _line(rec: Any) -> str:
    kind = type(rec)
    if kind is StreamEvent:
        if rec.event == "open":
            return f"conn {rec.conn} opened {_addr(rec.client)} -> {_addr(rec.backend)}"
        return f"conn {rec.conn} closed by the {rec.by} ({(rec.how or '').upper()})"
    if kind is StreamGap:
        return f"conn {rec.conn} {rec.direction} GAP: {rec.reason}"
    arrow = "client -> backend" if rec.direction == "tx" else "backend -> client"
    what = rec.name or ("bytes" if rec.direction == "tx" else "?")
    problem = f" [{rec.problem}]" if rec.problem else ""
    return f"conn {rec.conn} {arrow} {what} {len(rec.raw)} B: {rec.raw[:24].hex(' ')}" \
           f"{' …' if len(rec.raw) > 24 else ''}{problem}"


def run_show(plugin: StreamPlugin, ns: Any, out: TextIO | None = None) -> int:
    """Each record a line as it is read (``trace_tools.show_frames``; nothing kept but the
    chart's frames, up to ``--max-rows``), then how many connections the capture holds."""
    out = out or sys.stdout
    rows = int(getattr(ns, "max_rows", 400) or 400)
    shown: list[StreamFrame] = []
    conns = 0

    def counted() -> Iterator[Any]:
        nonlocal conns
        for rec in plugin.records(ns.file):
            conns = max(conns, rec.conn) if type(rec) in _SHOWN else conns
            yield rec

    def line(rec: Any) -> str:
        if type(rec) is StreamFrame and len(shown) < rows:
            shown.append(rec)
        return _line(rec)
    # --case: the capture's case marks read first (a case's end mark comes after its records),
    # then its records shown as they are read; before, --case was not looked at and every
    # record was shown, an unknown case's too
    cases = [r for r in plugin.records(ns.file) if type(r) is CaseMark] if getattr(ns, "case", None) else None
    core.show_frames(ns, out, f"{ns.file}: {plugin.title}", counted(), line, path=str(ns.file), cases=cases,
                     kinds=_SHOWN)
    if not conns:
        raise plugin.nothing_in(ns.file)
    out.write(f"{conns} connection(s)\n")
    if getattr(ns, "svg", None):
        write_text(ns.svg, plugin.chart(shown, str(ns.file)))
    return 0


def export_pcap(plugin: StreamPlugin, capture: str | Path, out: str | Path) -> tuple[int, str | None]:
    """``mcp-capture export``: a capture's TCP conversations (``traceio.tcp_pcap``): (packets
    written, the capture's truncation reason or None); errors as ``captures.export``'s."""
    from mcp_conform.captures.export import whole_or_none
    from mcp_conform.traceio.pcap_out import FrameError
    from mcp_conform.traceio.reader import CaptureError
    from mcp_conform.traceio.tcp_pcap import write_tcp_pcap

    truncated: list[str] = []

    with whole_or_none(Path(out)) as output:
        def records() -> Iterator[Any]:
            output.opened = True  # write_tcp_pcap asks for the first record once its writer is open
            for rec in plugin.records(str(capture)):
                if type(rec) is Truncated:
                    truncated.append(rec.reason)
                yield rec

        try:
            n = write_tcp_pcap(out, records(), plugin.port)
        except FrameError as exc:  # a time a pcap cannot hold, an address not IPv4
            raise CaptureError(f"{capture}: {exc}") from None
    return n, truncated[0] if truncated else None

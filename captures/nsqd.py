"""``mcp-capture check|show|diff|export|replay`` on an Nsqd capture (``--protocol nsqd``, issue 21
item 4): the capture tools Nsqd's profile names (``spec.profiles``), which
``captures.cli.capture_tools`` hands each subcommand (``captures.cli.CaptureTools``), as
MCP's are ``captures.mcp``. :func:`is_capture` is how the profile recognises its captures.

The capture is our MCAP (``mcp-conform --protocol nsqd --capture``, a fuzz finding's
repro.mcap) or a pcap/pcapng of the TCP traffic (tcpdump, Wireshark, a finding's repro.pcap),
read through ``traceio.nsqd`` (pcaps reassembled by ``traceio.tcp``: out-of-order and
retransmitted segments, both directions, any number of connections, bounded in memory).

- ``check``: every backend's frames judged by ``judge.nsqd_monitor`` — the judgement the
  runner's connections and the fuzzer make live (NSQD-FRM-1: lengths; NSQD-MSG-2: ids,
  layouts, UPDATE.state). Exit 0 no rule broken, 1 broken, 2 unreadable. The rules the
  runner's cases judge by what they send (effects, closes, timing) need the cases; a capture
  shows only what the backends sent. A connection with bytes missing from the capture is
  judged up to the gap, and the output says so.
- ``show``: the connections and their traffic, one line per write, frame and event.
- ``diff``: per connection (in order), the client's writes and the backend's answers —
  frames, with repeated identical ones folded (UPDATE's period differs run to run), and how
  the connection ended. Exit 0 same, 1 different.
- ``export``: the conversations as a pcap/pcapng tshark follows (``traceio.tcp_pcap``; the
  command, its errors and its output are ``captures.export``'s, as for MCP).
- ``replay``: an Nsqd fuzz finding (``finding-N/``, its finding.json, repro.mcap or
  repro.pcap), replayed as ``mcp-fuzz --protocol nsqd --replay`` does.
"""

from __future__ import annotations

import sys
from collections.abc import Iterator
from functools import partial
from pathlib import Path
from typing import Any, TextIO

from mcp_conform.captures import trace_tools as core
from mcp_conform.captures.trace_tools import Checked, Compared, RuleBlock
from mcp_conform.judge.nsqd_monitor import RULES, StreamMonitor
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import Deframer, Frame
from mcp_conform.traceio.nsqd import StreamGap, is_stream_capture, stream_records
from mcp_conform.traceio.reader import StreamEvent, StreamFrame, Truncated

__all__ = ["EXPORTED", "export_pcap", "is_capture", "is_finding", "run_check", "run_diff", "run_replay", "run_show"]

#: what ``export`` writes (``captures.export``'s closing line)
EXPORTED = "TCP packets"


def _addr(a: Any) -> str:
    return f"{a[0]}:{a[1]}" if a else "?"


#: Connections listed (and compared by diff) at most; the rest are counted (a hostile capture's
#: flood of connections stays bounded in memory). Steps kept per connection for diff, likewise.
MAX_LISTED = 10000
MAX_STEPS = 100000
MAX_GAPS = 1000
ROWS = 200  # connections listed in the terminal report at most (all of them in --json, up to MAX_LISTED)


class _Conns:
    """What a capture holds, per connection (the first :data:`MAX_LISTED`), with the monitor's
    judgement of every connection."""

    def __init__(self, path: str, *, steps: bool = False) -> None:
        self.path = path
        self.steps = steps  # keep each connection's steps (diff)
        self.monitor = StreamMonitor(NSQD)
        self.conns: dict[int, dict[str, Any]] = {}
        self.n_conns = 0  # connections are numbered 1, 2, ... in both kinds of capture
        self.truncated: str | None = None
        self.gaps: list[StreamGap] = []
        self.n_gaps = 0
        self.first_ns: int | None = None

    def conn(self, n: int) -> dict[str, Any] | None:
        c = self.conns.get(n)
        if c is None:
            self.n_conns = max(self.n_conns, n)
            if len(self.conns) >= MAX_LISTED:
                return None
            c = self.conns[n] = {"client": None, "backend": None, "tx": 0, "rx": 0, "end": [], "answers": []}
        return c

    def _step(self, c: dict[str, Any], step: tuple[str, str]) -> None:
        if self.steps and len(c["answers"]) < MAX_STEPS:
            c["answers"].append(step)

    def read(self) -> _Conns:
        for rec in stream_records(self.path):
            kind = type(rec)
            if kind is Truncated:
                self.truncated = rec.reason
                continue
            t = getattr(rec, "t_ns", None)
            if t is not None and self.first_ns is None:
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
                        d = c.setdefault("deframer", Deframer(NSQD))
                        for item in d.feed(rec.raw):
                            self._step(c, ("client", item.raw.hex() if isinstance(item, Frame)
                                           else f"unframed: {item.reason}"))
                    continue
                c["rx"] += 1
                if self.steps and len(c["answers"]) < MAX_STEPS:
                    _answer(c["answers"], rec)
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
        return self


def _answer(answers: list[Any], rec: StreamFrame) -> None:
    """The backend's frame as the diff compares it; identical neighbours folded."""
    if rec.problem:
        key = ("frame", f"refused: {rec.problem}")
    elif rec.name == "UPDATE":
        from mcp_conform.spec.nsqd_codec import decode_body

        item = Deframer(NSQD).feed(rec.raw)
        state = None
        if item and isinstance(item[0], Frame):
            try:
                state = decode_body(NSQD, item[0].msg_id, item[0].body, check_text=False).as_dict().get("state")
            except ValueError:
                state = None
        key = ("frame", f"UPDATE state {NSQD.state_name(state) if state is not None else '?'}")
    else:
        key = ("frame", rec.name or f"id {rec.raw[4] if len(rec.raw) > 4 else '?'}")
    if not answers or answers[-1] != key:
        answers.append(key)


class _Nsqd(core.CapturePlugin):
    name, spec, a_capture, html_instead = "nsqd", NSQD, "an Nsqd capture", "use show --svg"
    json_when_same = False

    def check(self, ns: Any) -> Checked:
        seen = _Conns(ns.file).read()
        verdicts = seen.monitor.verdicts()
        failed = [r for r, (v, _, _) in verdicts.items() if v == "failed"]
        broke = {c.conn: r for r in failed for c in verdicts[r][1]}
        head = [f"{ns.file}: Nsqd capture, {seen.n_conns} connection(s)"]
        if seen.truncated:
            head.append(f"TRUNCATED: {seen.truncated} (judged up to there)")
        head += [f"note: connection {g.conn} {'backend' if g.direction == 'rx' else 'client'} bytes: {g.reason}"
                 for g in seen.gaps[:20]]
        if seen.n_gaps > 20:
            head.append(f"note: ... and {seen.n_gaps - 20} more gap(s) in the capture")
        for n, c in sorted(seen.conns.items())[:ROWS]:
            head.append(f"  conn {n}: {_addr(c['client'])} -> {_addr(c['backend'])}: client wrote {c['tx']} B, "
                        f"backend sent {c['rx']} frame(s); {'closed ' + ', '.join(c['end']) if c['end'] else 'open'}"
                        f"{'; BROKE ' + broke[n] if n in broke else ''}")
        if seen.n_conns > ROWS:
            head.append(f"  ... and {seen.n_conns - ROWS} more connection(s)")
        blocks = []
        for rule in failed:
            rel = [(cv, (cv.violation[1] - (seen.first_ns or cv.violation[1])) / 1e9)  # type: ignore[index]
                   for cv in verdicts[rule][1][:3]]
            blocks.append(RuleBlock(rule, [(f"conn {cv.conn} at +{t:.6f}s: expected {cv.violation[0].expected}; "  # type: ignore[index]
                                            f"actual {cv.violation[0].actual}", cv.violation[0].evidence)  # type: ignore[index]
                                           for cv, t in rel], verdicts[rule][2] - 3, " connection(s)"))
        doc = {"file": str(ns.file), "truncated": seen.truncated, "connection_count": seen.n_conns,
               "connections": [{"conn": n, "client": _addr(c["client"]), "backend": _addr(c["backend"]),
                                "client_bytes": c["tx"], "backend_frames": c["rx"], "end": c["end"]}
                               for n, c in sorted(seen.conns.items())],
               "rules": {r: verdicts[r][0] for r in RULES},
               "failed_connections": {r: verdicts[r][2] for r in RULES},
               "violations": [{"rule": r, "conn": c.conn, "t_ns": c.violation[1],  # type: ignore[index]
                               "expected": c.violation[0].expected, "actual": c.violation[0].actual,  # type: ignore[index]
                               "evidence": list(c.violation[0].evidence)}  # type: ignore[index]
                              for r in failed for c in verdicts[r][1]],
               "gaps": [g._asdict() for g in seen.gaps]}
        return Checked(head, blocks, [(r, verdicts[r][0]) for r in RULES], bool(failed), seen.truncated, doc,
                       ["(the rules judged by what the runner's cases send need mcp-conform --protocol nsqd)"])

    def compare(self, golden: str, candidate: str) -> Compared:
        g, c = _Conns(golden, steps=True).read(), _Conns(candidate, steps=True).read()
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


PLUGIN = _Nsqd()
run_check = partial(core.run_check, PLUGIN)


# ---------------------------------------------------------------- show
def _line(rec: Any, first: int) -> str:
    t = f"+{(rec.t_ns - first) / 1e9:.6f}s"
    kind = type(rec)
    if kind is StreamEvent:
        if rec.event == "open":
            return f"{t} conn {rec.conn} opened {_addr(rec.client)} -> {_addr(rec.backend)}"
        return f"{t} conn {rec.conn} closed by the {rec.by} ({(rec.how or '').upper()})"
    if kind is StreamGap:
        return f"{t} conn {rec.conn} {rec.direction} GAP: {rec.reason}"
    arrow = "client -> backend" if rec.direction == "tx" else "backend -> client"
    what = rec.name or ("bytes" if rec.direction == "tx" else "?")
    problem = f" [{rec.problem}]" if rec.problem else ""
    return f"{t} conn {rec.conn} {arrow} {what} {len(rec.raw)} B: {rec.raw[:24].hex(' ')}" \
           f"{' …' if len(rec.raw) > 24 else ''}{problem}"


def run_show(ns: Any, out: TextIO | None = None) -> int:
    """Each record a line as it is read (nothing kept but the chart's frames, up to
    ``--max-rows``)."""
    out = out or sys.stdout
    in_window = core.window(ns)
    rows = int(getattr(ns, "max_rows", 400) or 400)
    out.write(f"{ns.file}: Nsqd capture\n")
    shown: list[StreamFrame] = []
    first: int | None = None
    conns = 0
    for rec in stream_records(ns.file):
        if type(rec) is Truncated:
            out.write(f"TRUNCATED: {rec.reason}\n")
            continue
        if type(rec) not in (StreamFrame, StreamEvent, StreamGap):
            continue
        first = rec.t_ns if first is None else first
        conns = max(conns, rec.conn)
        if not in_window((rec.t_ns - first) / 1e9):
            continue
        out.write(_line(rec, first) + "\n")
        if type(rec) is StreamFrame and len(shown) < rows:
            shown.append(rec)
    out.write(f"{conns} connection(s)\n")
    if getattr(ns, "svg", None):
        from mcp_conform.reports.nsqd_chart import stream_svg

        Path(ns.svg).write_text(stream_svg(shown, title=str(ns.file)))
    return 0


def run_diff(args: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
    return core.run_diff(PLUGIN, args, out)


# ---------------------------------------------------------------- replay
def is_finding(path: str | Path) -> bool:
    """``path`` is an Nsqd fuzz finding: its directory, finding.json, repro.mcap or repro.pcap."""
    from mcp_conform.fuzz.findings import read_finding

    try:
        read_finding(path, "nsqd")
    except (ValueError, OSError):
        return False
    return True


def is_capture(path: str | Path) -> bool:
    """Nsqd's ``capture_detect``: an Nsqd capture (``traceio.nsqd.is_stream_capture``), or a
    finding's directory or finding.json (what ``replay`` takes besides its captures)."""
    if Path(path).is_dir() or Path(path).name == "finding.json":
        return is_finding(path)
    return is_stream_capture(path)


def run_replay(args: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """Replay an Nsqd finding as ``mcp-fuzz --protocol nsqd --replay`` does (exit 1: it
    reproduced, 0: it did not, 2: unreadable, no finding or no backend)."""
    from mcp_conform.fuzz.nsqd_replay import replay_stream_finding
    from mcp_conform.harness.errors import SetupError

    err = err or sys.stderr
    if not is_finding(args.capture):
        err.write(f"mcp-capture: error: replay: {args.capture}: an Nsqd capture is replayed as a fuzz "
                  "finding only (its directory, finding.json, repro.mcap or repro.pcap)\n")
        return 2
    try:
        return replay_stream_finding(str(args.capture), args.target, args.spawn, prog="mcp-capture replay")
    except SetupError as exc:
        err.write(f"mcp-capture: error: replay: {exc}\n")
        return 2


def export_pcap(capture: str | Path, out: str | Path) -> tuple[int, str | None]:
    """``mcp-capture export``: an Nsqd capture's TCP conversations (``traceio.tcp_pcap``,
    NSQD-*): (packets written, the capture's truncation reason or None); errors as
    ``captures.export.export_pcap``'s."""
    from mcp_conform.captures.export import whole_or_none
    from mcp_conform.traceio.nsqd import BACKEND_PORT, stream_records
    from mcp_conform.traceio.pcap_out import FrameError
    from mcp_conform.traceio.reader import CaptureError, Truncated
    from mcp_conform.traceio.tcp_pcap import write_tcp_pcap

    truncated: list[str] = []

    with whole_or_none(Path(out)) as output:
        def records() -> Iterator[Any]:
            output.opened = True  # write_tcp_pcap asks for the first record once its writer is open
            for rec in stream_records(capture):
                if type(rec) is Truncated:
                    truncated.append(rec.reason)
                yield rec

        try:
            n = write_tcp_pcap(out, records(), BACKEND_PORT)
        except FrameError as exc:  # a time a pcap cannot hold, an address not IPv4
            raise CaptureError(f"{capture}: {exc}") from None
    return n, truncated[0] if truncated else None

"""``mcp-capture diff GOLDEN CANDIDATE``: two captures compared as MCP conversations.

Not bytes: each capture is read (MCAP, pcap or pcapng, a truncated file up to its last
whole chunk) and folded into conversations (:mod:`captures.conversation`): per pair of
MCP IDs, the messages in order with who sent them, the action and the decoded payload,
retransmissions folded into a copy count, sequence numbers normalised per sender
(MCP-SEQ-4), and so are the runner's passthrough probe tokens (their run-dependent seq
dropped, each numbered by first appearance). Each conversation of the golden capture is
aligned with the candidate's, sender by sender, by ``difflib.SequenceMatcher`` over the
messages' keys: a message dropped or added shows as that one message, not as everything
after it. Where the runner's case marks say cases ran side by side (the schedule's batch),
how their traffic interleaved is not compared, each case's own order is
(:mod:`captures.overlap`). Then, on aligned pairs:

- retransmission counts must agree within ``--copies-tolerance`` (default 1);
- timing is ignored unless ``--time-tolerance S`` is given, but the largest drift (the
  candidate's time since the conversation's first aligned message minus the golden's) is
  always reported;
- addresses and ports are ignored unless ``--addresses``.

Divergence kinds: ``missing`` (in the golden capture, not the candidate), ``extra`` (the
reverse), ``changed`` (an aligned pair whose content differs, field by field), ``reordered``
(two messages in the opposite order), ``copies``, ``timing``, ``address``.

The first divergence is printed with a few messages of context on each side and its
field-by-field difference, then a summary of all. ``--json OUT``, ``--html OUT`` (both
sides' sequence charts side by side). Exit 0 same, 1 different, 2 unreadable input.
"""

from __future__ import annotations

import difflib
import sys
from collections import Counter, deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, TextIO

from mcp_conform.captures.conversation import (
    Conversation,
    Entry,
    build_conversations,
    describe,
    entry_fields,
    peers_text,
)
from mcp_conform.captures.overlap import SPAN_EDGES, Span, aligned_order, overlap_spans, spans_text
from mcp_conform.harness.liveness import PROBE_SRC as LIVENESS_ID
from mcp_conform.spec.codec import Action, peek_header

__all__ = ["DiffOptions", "DiffResult", "Divergence", "Side", "diff_captures", "diff_sides",
           "load_side", "print_report", "register", "run", "side_from_datagrams"]

SCHEMA_VERSION = "1.0"
BIG_MIDDLE = 5000
KINDS = ("missing", "extra", "changed", "reordered", "copies", "timing", "address")


@dataclass(frozen=True)
class DiffOptions:
    copies_tolerance: int = 1
    time_tolerance: float | None = None  # seconds; None: timing ignored (drift reported)
    addresses: bool = False
    context: int = 3


@dataclass
class Side:
    """One capture, read and folded."""

    name: str
    conversations: dict[tuple[Any, Any], Conversation]
    t0_ns: int
    datagrams: int
    truncated: str | None = None
    bursts: int = 0
    metadata: dict[str, str] = field(default_factory=dict)
    overlaps: list[Span] = field(default_factory=list)  # cases run side by side (captures.overlap)

    @property
    def messages(self) -> int:
        return sum(len(c.entries) for c in self.conversations.values())


class Divergence(NamedTuple):
    kind: str
    peers: tuple[Any, Any]
    golden: Entry | None
    candidate: Entry | None
    golden_pos: int | None  # position in the golden conversation
    candidate_pos: int | None
    fields: tuple[tuple[str, Any, Any], ...]  # (field, golden value, candidate value)
    note: str = ""


@dataclass
class DiffResult:
    golden: Side
    candidate: Side
    options: DiffOptions
    divergences: list[Divergence]
    max_drift_ns: int = 0
    max_drift_at: Divergence | None = None
    aligned: dict[tuple[Any, Any], list[tuple[int | None, int | None]]] = field(default_factory=dict)

    @property
    def same(self) -> bool:
        return not self.divergences

    def summary(self) -> dict[str, int]:
        c = Counter(d.kind for d in self.divergences)
        return {k: c[k] for k in KINDS if c[k]}


# ---------------------------------------------------------------- reading
def side_from_datagrams(name: str, datagrams: Iterable[Any], *, truncated: str | None = None,
                        metadata: dict[str, str] | None = None, marks: Iterable[Any] = ()) -> Side:
    """A side from datagram records (``index``, ``t_ns``, ``src_addr``, ``dst_addr``, ``data``),
    taken in time order (a recorder's threads may write a reply before the message it
    answers: the message's time is stamped before it leaves); a list is sorted here, an
    iterator (``traceio.reader``, which orders them) streams through. ``marks``: the run's
    case marks, read once the datagrams are (where cases overlapped: ``captures.overlap``)."""
    counted = _Counted(in_time_order(datagrams) if isinstance(datagrams, list) else datagrams)
    convs, t0 = build_conversations(counted)
    return Side(name, convs, t0, counted.n, truncated, 0, metadata or {}, overlap_spans(marks))


class _Counted:
    """Iterates and counts (a capture's records stream through; ``traceio.reader`` yields
    them in log-time order already)."""

    def __init__(self, it: Iterable[Any]) -> None:
        self.it = it
        self.n = 0

    def __iter__(self) -> Any:
        for d in self.it:
            self.n += 1
            yield d


def in_time_order(datagrams: Iterable[Any]) -> list[Any]:
    """The records sorted by ``t_ns`` (stable), sorting only when they are not already."""
    records = list(datagrams)
    last = None
    for r in records:
        if last is not None and r.t_ns < last:
            records.sort(key=lambda r: r.t_ns)
            break
        last = r.t_ns
    return records


def load_side(path: str | Path) -> Side:
    """Read a capture (raises ``traceio.reader.CaptureError`` when it cannot)."""
    from mcp_conform.traceio.reader import CaseMark, Datagram, Metadata, Truncated, open_capture

    cap = open_capture(path)
    meta: dict[str, str] = {}
    truncated: list[str] = []
    marks: list[CaseMark] = []

    def datagrams() -> Iterable[Any]:
        for rec in cap:
            if isinstance(rec, Datagram):
                if not _liveness_probe(rec):
                    yield rec
            elif isinstance(rec, Metadata):
                meta.update(rec.data)
            elif isinstance(rec, Truncated):
                truncated.append(rec.reason)
            elif isinstance(rec, CaseMark):
                marks.append(rec)

    side = side_from_datagrams(str(path), datagrams(), marks=marks)
    side.truncated = truncated[0] if truncated else getattr(cap, "truncated", None)
    side.metadata = meta
    return side


def _liveness_probe(rec: Any) -> bool:
    """A harness's liveness probe or the node's ACK of it (``harness.liveness``: sent from
    the watcher's own MCP ID only when the node has been quiet, so whether a run has any
    depends on the machine's load): not part of what a run exchanges by design, left out of
    the comparison, as a golden re-recorded on a loaded machine showed."""
    from mcp_conform.judge.judging import HARNESSES

    if rec.recorder not in HARNESSES:
        return False
    h = peek_header(rec.data)
    return h is not None and LIVENESS_ID in (h[0], h[1])


# ---------------------------------------------------------------- comparing
def _fields_differ(g: Entry, c: Entry) -> tuple[tuple[str, Any, Any], ...]:
    fg, fc = entry_fields(g), entry_fields(c)
    out = []
    for k in list(fg) + [k for k in fc if k not in fg]:
        if k in ("seq", "token"):
            continue  # normalised seqs and probe tokens are shown, not compared (their keys are)
        a, b = fg.get(k), fc.get(k)
        if a != b:
            out.append((k, a, b))
    if g.key != c.key and not out:  # e.g. an ACK of a different message
        out.append(("acknowledges", describe(g), describe(c)))
    return tuple(out)


def _align(gk: list[Any], ck: list[Any]) -> list[tuple[str, int, int, int, int]]:
    """SequenceMatcher opcodes over the keys, with the common prefix and suffix trimmed
    first (the usual case is two nearly equal conversations: linear time)."""
    n, m = len(gk), len(ck)
    lo = 0
    while lo < n and lo < m and gk[lo] == ck[lo]:
        lo += 1
    hi = 0
    while hi < n - lo and hi < m - lo and gk[n - 1 - hi] == ck[m - 1 - hi]:
        hi += 1
    ops: list[tuple[str, int, int, int, int]] = []
    if lo:
        ops.append(("equal", 0, lo, 0, lo))
    if lo < n - hi or lo < m - hi:
        # exact matching is quadratic on long repetitive stretches (a stream of WP_Offs);
        # beyond BIG_MIDDLE entries difflib's popularity heuristic keeps it bounded
        big = max(n - hi - lo, m - hi - lo) > BIG_MIDDLE
        sm = difflib.SequenceMatcher(None, gk[lo:n - hi], ck[lo:m - hi], autojunk=big)
        for tag, i1, i2, j1, j2 in sm.get_opcodes():
            ops.append((tag, i1 + lo, i2 + lo, j1 + lo, j2 + lo))
    if hi:
        ops.append(("equal", n - hi, n, m - hi, m))
    return ops


def _streams(g: list[Entry], c: list[Entry], g_spans: list[Span] | None = None,
             c_spans: list[Span] | None = None) -> Iterable[tuple[str, list[int], list[int]]]:
    """Alignment per sender: each sender's own order is the protocol's; how two senders'
    datagrams interleave on the wire is a race (an ACK may leave before or after the
    other side's next message), and so is how cases run side by side interleave (read lane
    by lane: ``captures.overlap``). Yields (tag, golden positions, candidate positions)."""
    by_g: dict[Any, list[int]] = {}
    by_c: dict[Any, list[int]] = {}
    for n, e in enumerate(g):  # one pass each, whatever the number of senders
        by_g.setdefault(e.src, []).append(n)
    for n, e in enumerate(c):
        by_c.setdefault(e.src, []).append(n)
    for sender in sorted(by_g.keys() | by_c.keys(), key=lambda s: -1 if s is None else s):
        gi = aligned_order(g, by_g.get(sender, []), g_spans or [])
        ci = aligned_order(c, by_c.get(sender, []), c_spans or [])
        gk = [g[i].key if i >= 0 else SPAN_EDGES[i] for i in gi]
        ck = [c[j].key if j >= 0 else SPAN_EDGES[j] for j in ci]
        for tag, i1, i2, j1, j2 in _align(gk, ck):
            gs, cs = [i for i in gi[i1:i2] if i >= 0], [j for j in ci[j1:j2] if j >= 0]
            if gs or cs:
                yield tag, gs, cs


def _drop_consequent_ack_moves(divs: list[Divergence], peers: tuple[Any, Any], start: int = 0) -> None:
    """An ACK that moved or changed because the message it acknowledges moved or changed is
    that divergence's consequence, not a second one (one fault, one report). Looks at
    ``divs[start:]`` only, the conversation's own: the time is linear in the divergences, not
    their number times the conversations' (a noisy capture has thousands of each)."""
    hit = {(d.golden.src, d.golden.nseq) for d in divs[start:]
           if d.kind in ("reordered", "changed") and d.peers == peers and d.golden is not None
           and d.golden.action not in (None, Action.ACK)}
    if not hit:
        return
    divs[start:] = [d for d in divs[start:] if not (
        d.kind in ("reordered", "changed") and d.peers == peers and d.golden is not None
        and d.golden.action == Action.ACK and (d.golden.dst, d.golden.payload) in hit
        and (d.kind == "reordered" or all(f == "acknowledges" for f, _, _ in d.fields)))]


def _compare(peers: tuple[Any, Any], g: list[Entry], c: list[Entry], opts: DiffOptions,
             result: DiffResult) -> None:
    gs_, cs_ = result.golden.overlaps, result.candidate.overlaps
    divs = result.divergences
    start = len(divs)  # this conversation's divergences are divs[start:]
    pairs: list[tuple[int | None, int | None]] = []
    equal: list[tuple[int, int]] = []
    changed: list[tuple[int, int]] = []
    missing: list[int] = []
    extra: list[int] = []
    for tag, gs, cs in _streams(g, c, gs_, cs_):
        if tag == "equal":
            equal.extend(zip(gs, cs, strict=True))
            continue
        k = 0
        if tag == "replace":
            k = min(len(gs), len(cs))
            changed.extend(zip(gs[:k], cs[:k], strict=True))
        missing.extend(gs[k:])
        extra.extend(cs[k:])
    # a message missing here and extra there: moved (one divergence, "reordered")
    extra_by_key: dict[tuple[Any, ...], deque[int]] = {}
    for j in extra:
        extra_by_key.setdefault(c[j].key, deque()).append(j)
    for i in missing:
        js = extra_by_key.get(g[i].key)
        if js:
            j = js.popleft()
            pairs.append((i, j))
            divs.append(Divergence("reordered", peers, g[i], c[j], i, j, (("position", i, j),),
                                   f"{describe(g[i])} came at another place in the order "
                                   f"(golden #{i}, candidate #{j})"))
        else:
            pairs.append((i, None))
            divs.append(Divergence("missing", peers, g[i], None, i, None, (),
                                   "in the golden capture, not in the candidate"))
    for js in extra_by_key.values():
        for j in js:
            pairs.append((None, j))
            divs.append(Divergence("extra", peers, None, c[j], None, j, (),
                                   "in the candidate, not in the golden capture"))
    pairs.extend(equal)
    pairs.extend(changed)
    equal.sort()
    ref: tuple[int, int] | None = None
    tol_ns = None if opts.time_tolerance is None else int(opts.time_tolerance * 1e9)
    for i, j in equal:
        eg, ec = g[i], c[j]
        if abs(eg.copies - ec.copies) > opts.copies_tolerance:
            divs.append(Divergence("copies", peers, eg, ec, i, j, (("copies", eg.copies, ec.copies),),
                                   f"{eg.copies} copies in the golden capture, {ec.copies} in the "
                                   f"candidate (tolerance {opts.copies_tolerance})"))
        if ref is None:
            ref = (eg.t_ns, ec.t_ns)
        drift = (ec.t_ns - ref[1]) - (eg.t_ns - ref[0])
        if abs(drift) > abs(result.max_drift_ns):
            result.max_drift_ns = drift
            result.max_drift_at = Divergence("timing", peers, eg, ec, i, j, ())
        if tol_ns is not None and abs(drift) > tol_ns:
            divs.append(Divergence("timing", peers, eg, ec, i, j, (("t", eg.t_ns - ref[0], ec.t_ns - ref[1]),),
                                   f"{drift / 1e9:+.3f} s from the golden timing (tolerance "
                                   f"{opts.time_tolerance:g} s)"))
        if opts.addresses:
            for what in ("src_addr", "dst_addr"):
                a, b = getattr(eg, what), getattr(ec, what)
                if a is not None and b is not None and tuple(a) != tuple(b):
                    divs.append(Divergence("address", peers, eg, ec, i, j, ((what, a, b),),
                                           f"{what} {a[0]}:{a[1]} vs {b[0]}:{b[1]}"))
    # two changed pairs whose contents are each other's: a swap, one divergence
    swapped: set[int] = set()
    by_content: dict[tuple[Any, ...], list[int]] = {}
    for n, (i, _j) in enumerate(changed):
        by_content.setdefault(g[i].key, []).append(n)
    for n, (i, j) in enumerate(changed):
        if n in swapped:
            continue
        for other in by_content.get(c[j].key, []):
            oi, oj = changed[other]
            if other != n and other not in swapped and c[oj].key == g[i].key:
                swapped.update((n, other))
                divs.append(Divergence("reordered", peers, g[i], c[j], i, j,
                                       (("order", describe(g[i]), describe(g[oi])),),
                                       f"{describe(g[i])} and {describe(g[oi])} came in the opposite order"))
                break
    for n, (i, j) in enumerate(changed):
        if n not in swapped:
            divs.append(Divergence("changed", peers, g[i], c[j], i, j, _fields_differ(g[i], c[j]),
                                   "aligned messages differ"))
    _drop_consequent_ack_moves(divs, peers, start)
    pairs.sort(key=lambda p: (p[0] if p[0] is not None else -1, p[1] if p[1] is not None else -1))
    result.aligned[peers] = _merge_order(pairs)


def _merge_order(pairs: list[tuple[int | None, int | None]]) -> list[tuple[int | None, int | None]]:
    """Aligned rows in order: by golden position, an extra candidate row after its predecessor."""
    def key(p: tuple[int | None, int | None]) -> tuple[float, float]:
        i, j = p
        return (i if i is not None else float("inf"), j if j is not None else -1.0)
    with_g = sorted((p for p in pairs if p[0] is not None), key=key)
    extras = sorted((p for p in pairs if p[0] is None), key=lambda p: p[1] or 0)
    out: list[tuple[int | None, int | None]] = []
    e = 0
    for p in with_g:
        while e < len(extras) and p[1] is not None and (extras[e][1] or 0) < p[1]:
            out.append(extras[e])
            e += 1
        out.append(p)
    out.extend(extras[e:])
    return out


def _order_key(peers: tuple[Any, Any]) -> tuple[int, int]:
    return tuple(-1 if p is None else p for p in peers)  # type: ignore[return-value]


def diff_sides(golden: Side, candidate: Side, opts: DiffOptions | None = None) -> DiffResult:
    opts = opts or DiffOptions()
    result = DiffResult(golden, candidate, opts, [])
    for peers in sorted(set(golden.conversations) | set(candidate.conversations), key=_order_key):
        g = golden.conversations.get(peers)
        c = candidate.conversations.get(peers)
        _compare(peers, g.entries if g else [], c.entries if c else [], opts, result)

    def position(d: Divergence) -> tuple[int, int]:
        e = d.golden or d.candidate
        assert e is not None
        return (e.t_ns - (golden.t0_ns if d.golden else candidate.t0_ns), e.index)
    result.divergences.sort(key=position)
    return result


def diff_captures(golden: str | Path, candidate: str | Path, opts: DiffOptions | None = None) -> DiffResult:
    return diff_sides(load_side(golden), load_side(candidate), opts)


# ---------------------------------------------------------------- reporting
def _row(e: Entry | None, width: int) -> str:
    text = describe(e) if e is not None else "(missing)"
    return text[:width].ljust(width)


def print_report(result: DiffResult, out: TextIO = sys.stdout) -> None:
    g, c, opts = result.golden, result.candidate, result.options
    for side, label in ((g, "golden"), (c, "candidate")):
        trunc = f"; TRUNCATED: {side.truncated} (read up to its last whole chunk)" if side.truncated else ""
        out.write(f"{label}: {side.name}: {side.datagrams} datagrams, {side.messages} messages in "
                  f"{len(side.conversations)} conversations{trunc}\n")
    drift = f"largest timing drift {result.max_drift_ns / 1e9:+.3f} s"
    if result.max_drift_at is not None and result.max_drift_ns:
        drift += f" (at {describe(result.max_drift_at.golden)})"
    if opts.time_tolerance is None:
        drift += "; timing not compared (--time-tolerance S to compare)"
    out.write(drift + "\n")
    for side, label in ((g, "golden"), (c, "candidate")):
        if side.overlaps:
            out.write(f"{label}: {spans_text(side.overlaps)}\n")
    if result.same:
        out.write("same: every conversation matches\n")
        return
    first = result.divergences[0]
    out.write(f"\nfirst divergence ({first.kind}) in conversation {peers_text(first.peers)}: {first.note}\n")
    rows = result.aligned.get(first.peers, [])
    gconv = result.golden.conversations.get(first.peers)
    cconv = result.candidate.conversations.get(first.peers)
    at = next((n for n, p in enumerate(rows) if p == (first.golden_pos, first.candidate_pos)), 0)
    width = 46
    out.write(f"  {'golden'.ljust(width + 6)}  candidate\n")
    for n in range(max(0, at - opts.context), min(len(rows), at + opts.context + 1)):
        i, j = rows[n]
        eg = gconv.entries[i] if (gconv and i is not None) else None
        ec = cconv.entries[j] if (cconv and j is not None) else None
        mark = ">" if n == at else " "
        gi = f"#{i}" if i is not None else ""
        cj = f"#{j}" if j is not None else ""
        out.write(f"{mark} {gi:>5} {_row(eg, width)}  {cj:>5} {_row(ec, width)}\n")
    for name, a, b in first.fields[:20]:
        out.write(f"    {name}: {a!r} → {b!r}\n")
    if len(first.fields) > 20:
        out.write(f"    ... {len(first.fields) - 20} more fields\n")
    out.write(f"\n{len(result.divergences)} divergence(s): " +
              ", ".join(f"{n} {k}" for k, n in result.summary().items()) + "\n")
    for d in result.divergences[:50]:
        e = d.golden or d.candidate
        where = f"golden #{d.golden_pos}" if d.golden_pos is not None else f"candidate #{d.candidate_pos}"
        fields = "; ".join(f"{f}: {a!r} → {b!r}" for f, a, b in d.fields[:3])
        out.write(f"  {d.kind:<9} {peers_text(d.peers):<12} {where:<15} {describe(e)}"
                  f"{' — ' + fields if fields else ''}\n")
    if len(result.divergences) > 50:
        out.write(f"  ... {len(result.divergences) - 50} more (--json for all)\n")


def _jsonable(v: Any) -> Any:
    if isinstance(v, bytes):
        return v.hex()
    if isinstance(v, tuple):
        return [_jsonable(x) for x in v]
    if isinstance(v, float) and v != v:  # NaN
        return None
    return v


def _entry_json(e: Entry | None, t0: int) -> dict[str, Any] | None:
    if e is None:
        return None
    return {"text": describe(e), "index": e.index, "t": (e.t_ns - t0) / 1e9, "copies": e.copies,
            "seq": e.seq, "nseq": e.nseq,
            "src_addr": ":".join(map(str, e.src_addr)) if e.src_addr else None,
            "dst_addr": ":".join(map(str, e.dst_addr)) if e.dst_addr else None,
            "fields": {k: _jsonable(v) for k, v in entry_fields(e).items()}}


def build_json(result: DiffResult) -> dict[str, Any]:
    from mcp_conform.spec import SPEC
    from mcp_conform.spec.about import TOOL_NAME, tool_version

    g, c = result.golden, result.candidate

    def side(s: Side) -> dict[str, Any]:
        return {"file": s.name, "truncated": s.truncated, "datagrams": s.datagrams, "messages": s.messages,
                "metadata": s.metadata,
                "overlaps": [{"start_s": (o.start_ns - s.t0_ns) / 1e9, "cases": list(o.cases)}
                             for o in s.overlaps]}
    convs = []
    for peers in sorted(set(g.conversations) | set(c.conversations), key=_order_key):
        convs.append({"peers": list(peers),
                      "golden_messages": len(g.conversations[peers].entries) if peers in g.conversations else 0,
                      "candidate_messages": len(c.conversations[peers].entries) if peers in c.conversations else 0,
                      "divergences": sum(1 for d in result.divergences if d.peers == peers)})
    return {
        "schema_version": SCHEMA_VERSION,
        "tool": {"name": TOOL_NAME, "version": tool_version()},
        "spec": {"version": SPEC.version, "sha256": SPEC.sha256},
        "golden": side(g), "candidate": side(c),
        "parameters": {"copies_tolerance": result.options.copies_tolerance,
                       "time_tolerance": result.options.time_tolerance,
                       "addresses": result.options.addresses},
        "same": result.same,
        "max_drift_s": result.max_drift_ns / 1e9,
        "conversations": convs,
        "divergences": [{"kind": d.kind, "peers": list(d.peers), "note": d.note,
                         "golden_pos": d.golden_pos, "candidate_pos": d.candidate_pos,
                         "golden": _entry_json(d.golden, g.t0_ns),
                         "candidate": _entry_json(d.candidate, c.t0_ns),
                         "fields": [{"field": f, "golden": _jsonable(a), "candidate": _jsonable(b)}
                                    for f, a, b in d.fields]}
                        for d in result.divergences],
        "summary": {"divergences": len(result.divergences), **result.summary()},
    }


# ---------------------------------------------------------------- command line
def register(sub: Any) -> None:
    """Add ``diff`` to ``mcp-capture``'s subparsers."""
    from mcp_conform.captures.cli import add_protocol_option
    p = sub.add_parser("diff", help="compare two captures as MCP conversations",
                       description=__doc__.split("\n\n")[0] if __doc__ else None)
    p.add_argument("golden", metavar="GOLDEN", help="the reference capture (MCAP, pcap, pcapng)")
    p.add_argument("candidate", metavar="CANDIDATE", help="the capture to compare with it")
    p.add_argument("--copies-tolerance", type=_nonneg_int, default=1, metavar="N",
                   help="retransmission counts may differ by N (1)")
    p.add_argument("--time-tolerance", type=_nonneg_float, default=None, metavar="S",
                   help="compare timing: drift beyond S seconds diverges (default: not compared)")
    p.add_argument("--addresses", action="store_true", help="compare addresses and ports too")
    p.add_argument("--context", type=_nonneg_int, default=3, metavar="N",
                   help="messages of context around the first divergence (3)")
    p.add_argument("--json", metavar="OUT", help="write the comparison as JSON")
    p.add_argument("--html", metavar="OUT", help="write both sides' sequence charts side by side")
    add_protocol_option(p)
    p.set_defaults(run=run)


def _nonneg_int(text: str) -> int:
    import argparse

    try:
        v = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if v < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0: {v}")
    return v


def _nonneg_float(text: str) -> float:
    import argparse
    import math

    try:
        v = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not math.isfinite(v) or v < 0:
        raise argparse.ArgumentTypeError(f"must be a number >= 0: {text}")
    return v


def run(args: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """``mcp-capture diff``: the options checked, then the protocol's diff (the golden's)."""
    from mcp_conform.captures.cli import capture_tools, check_writable
    from mcp_conform.traceio.reader import CaptureError

    err = err or sys.stderr
    check_writable(args.json, "--json")
    check_writable(args.html, "--html")
    try:
        return int(capture_tools(args, args.golden).run_diff(args, out, err))
    except CaptureError as exc:
        err.write(f"mcp-capture: error: diff: {exc}\n")
        return 2

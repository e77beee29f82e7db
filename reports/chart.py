"""Message-sequence charts of MCP traffic, as standalone SVG text (no external assets).

One lifeline per MCP node (manager 0, drones by ID, the broadcast ID, and a lifeline per
address for datagrams without an MCP header), one row per datagram, top to bottom in capture
order, the time since the first shown datagram on the left. An arrow is labelled with its
action and seq; at a glance:

- ACKs are thin and green; broadcasts blue; datagrams that do not decode red and dotted;
- a retransmission is orange and says which copy it is (↻2 = the second retransmission);
- a unicast copy that no ACK answered is dashed and ends in a cross;
- a violation is drawn thick and red on the arrow of its evidence, with its rule IDs.

``render(lifelines, arrows)`` takes plain data (:class:`Arrow`), so any producer can chart
a conversation (``mcp-capture show --svg``, the HTML reports, a golden diff);
``trace_svg(trace, entries)`` charts entries of a :class:`traceio.trace.Trace`. Every
arrow is an SVG ``<g class="arrow ...">`` with ``data-index`` and ``data-rules`` attributes
and a ``<title>`` tooltip, so a browser (or a test, through the DOM) can find it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from html import escape
from typing import Any, NamedTuple

__all__ = ["Arrow", "Lifeline", "arrow_of", "render", "trace_svg"]

ROW = 28
HEAD = 54
LEFT = 92
COL = 180
MAX_ROWS = 400

STYLE = """
.mcp-chart { font: 12px ui-monospace, SFMono-Regular, Menlo, Consolas, monospace; }
.mcp-chart .head rect { fill: #eef2f7; stroke: #4a5568; }
.mcp-chart .head .title { font-weight: bold; }
.mcp-chart .head .sub { fill: #4a5568; font-size: 10px; }
.mcp-chart .life { stroke: #a0aec0; stroke-dasharray: 4 4; }
.mcp-chart .time { fill: #4a5568; font-size: 10px; }
.mcp-chart .arrow line, .mcp-chart .arrow path { stroke: #1a202c; stroke-width: 1.4; fill: none; }
.mcp-chart .arrow text { fill: #1a202c; }
.mcp-chart .arrow.ack line { stroke: #2f855a; stroke-width: 1; }
.mcp-chart .arrow.ack text { fill: #2f855a; }
.mcp-chart .arrow.bcast line { stroke: #2b6cb0; }
.mcp-chart .arrow.bcast text { fill: #2b6cb0; }
.mcp-chart .arrow.copy line { stroke: #dd6b20; }
.mcp-chart .arrow.copy text { fill: #c05621; }
.mcp-chart .arrow.unanswered line { stroke-dasharray: 6 3; }
.mcp-chart .arrow.malformed line { stroke: #c53030; stroke-dasharray: 2 3; }
.mcp-chart .arrow.malformed text { fill: #c53030; }
.mcp-chart .arrow.violation line, .mcp-chart .arrow.violation path { stroke: #e53e3e; stroke-width: 3; }
.mcp-chart .arrow.violation text { fill: #c53030; font-weight: bold; }
.mcp-chart .arrow .cross { stroke: #c53030; stroke-width: 2; }
.mcp-chart .arrow .badge { fill: #fff5f5; stroke: #e53e3e; }
.mcp-chart .arrow .badge-text { fill: #c53030; font-size: 10px; font-weight: bold; }
.mcp-chart .more { fill: #4a5568; font-style: italic; }
"""


class Lifeline(NamedTuple):
    key: str  # what Arrow.src / Arrow.dst name
    title: str  # "manager 0"
    subtitle: str = ""  # its addresses


class Arrow(NamedTuple):
    t_ns: int
    src: str
    dst: str
    label: str  # action and seq
    kind: str = "msg"  # msg | ack | bcast | malformed | gap (a placeholder row: no arrow, no time)
    copy: int = 0  # k-th retransmission (0: the first send)
    unanswered: bool = False
    rules: tuple[str, ...] = ()  # violations shown on this arrow
    note: str = ""  # tooltip
    index: int | None = None  # type: ignore[assignment]  # the datagram's index in its capture
    extra_class: str = ""  # e.g. a diff's "missing" / "extra"


def _esc(text: Any) -> str:
    return escape(str(text), quote=True)


def render(lifelines: Sequence[Lifeline], arrows: Sequence[Arrow], title: str = "",
           max_rows: int = MAX_ROWS, t0_ns: int | None = None) -> str:
    """The SVG document (a string) of ``arrows`` between ``lifelines``; times are since
    ``t0_ns`` (default: the first arrow's), so a window of a listing shows the listing's."""
    shown = list(arrows[:max_rows])
    hidden = len(arrows) - len(shown)
    keys = [lf.key for lf in lifelines]
    for a in shown:  # a lifeline the caller forgot still gets a column
        for k in (a.src, a.dst):
            if k not in keys:
                keys.append(k)
                lifelines = [*lifelines, Lifeline(k, k)]
    x_of = {k: LEFT + COL // 2 + n * COL for n, k in enumerate(keys)}
    badges = max((7 * len(" ".join(a.rules)) + 30 for a in shown if a.rules), default=0)
    width = LEFT + COL * max(1, len(keys)) + max(20, badges - COL // 2)
    top = HEAD + (22 if title else 0)
    height = top + ROW * (len(shown) + (1 if hidden else 0)) + ROW
    out = [f'<svg xmlns="http://www.w3.org/2000/svg" class="mcp-chart" width="{width}" height="{height}" '
           f'viewBox="0 0 {width} {height}" role="img" aria-label="{_esc(title or "MCP sequence chart")}">',
           f"<style>{STYLE}</style>", _defs()]
    if title:
        out.append(f'<text x="8" y="16" class="chart-title" font-weight="bold">{_esc(title)}</text>')
    y0 = top - HEAD + 6
    for lf in lifelines:
        x = x_of[lf.key]
        out.append(f'<g class="head" data-lifeline="{_esc(lf.key)}"><rect x="{x - COL // 2 + 6}" y="{y0}" '
                   f'width="{COL - 12}" height="38" rx="4"/><text class="title" x="{x}" y="{y0 + 16}" '
                   f'text-anchor="middle">{_esc(lf.title)}</text><text class="sub" x="{x}" y="{y0 + 31}" '
                   f'text-anchor="middle">{_esc(_clip(lf.subtitle, 27))}</text></g>')
        out.append(f'<line class="life" x1="{x}" y1="{y0 + 38}" x2="{x}" y2="{height - 8}"/>')
    timed = [a for a in shown if a.kind != "gap"]
    t0 = t0_ns if t0_ns is not None else timed[0].t_ns if timed else 0
    for row, a in enumerate(shown):
        y = top + ROW * row + ROW // 2 + 8
        if a.kind == "gap":  # a row the other side of a diff has: a note, not a datagram
            out.append(_gap(a, x_of[a.src], x_of[a.dst], y))
            continue
        out.append(f'<text class="time" x="6" y="{y + 4}">+{(a.t_ns - t0) / 1e9:.6f}s</text>')
        out.append(_arrow(a, x_of[a.src], x_of[a.dst], y))
    if hidden:
        y = top + ROW * len(shown) + ROW // 2 + 8
        out.append(f'<text class="more" x="{LEFT}" y="{y}">… {hidden} more datagram(s) not shown</text>')
    out.append("</svg>")
    return "\n".join(out)


def _clip(text: str, n: int) -> str:
    return text if len(text) <= n else text[:n - 1] + "…"


def _defs() -> str:
    heads = {"m-msg": "#1a202c", "m-ack": "#2f855a", "m-bcast": "#2b6cb0", "m-copy": "#dd6b20",
             "m-malformed": "#c53030", "m-violation": "#e53e3e"}
    marks = "".join(f'<marker id="{k}" viewBox="0 0 10 10" refX="9" refY="5" markerUnits="userSpaceOnUse" '
                    f'markerWidth="9" markerHeight="9" orient="auto-start-reverse">'
                    f'<path d="M0,0 L10,5 L0,10 z" fill="{c}"/></marker>'
                    for k, c in heads.items())
    return f"<defs>{marks}</defs>"


def _gap(a: Arrow, x1: int, x2: int, y: int) -> str:
    """A placeholder row: its label between the lifelines, grey and italic; no line, no time
    (the time would be the other capture's)."""
    classes = " ".join(["arrow", "gap", *a.extra_class.split()])
    classes = " ".join(dict.fromkeys(classes.split()))
    return (f'<g class="{classes}" data-index="" data-rules=""><title>{_esc(a.note or a.label)}</title>'
            f'<text x="{(x1 + x2) // 2}" y="{y}" text-anchor="middle" font-style="italic" fill="#a0aec0">'
            f"{_esc(a.label)}</text></g>")


def _arrow(a: Arrow, x1: int, x2: int, y: int) -> str:
    classes = ["arrow", a.kind]
    if a.copy:
        classes.append("copy")
    if a.unanswered:
        classes.append("unanswered")
    if a.rules:
        classes.append("violation")
    if a.extra_class:
        classes.append(a.extra_class)
    marker = "m-violation" if a.rules else "m-copy" if a.copy and a.kind == "msg" else f"m-{a.kind}"
    label = a.label + (f"  ↻{a.copy}" if a.copy else "") + ("  (no ACK)" if a.unanswered else "")
    tip = "\n".join(x for x in (f"#{a.index}" if a.index is not None else "", label, a.note,
                                *(f"violates {r}" for r in a.rules)) if x)
    attrs = (f'class="{" ".join(classes)}" data-index="{"" if a.index is None else a.index}" '
             f'data-rules="{_esc(" ".join(a.rules))}"')
    parts = [f"<g {attrs}><title>{_esc(tip)}</title>"]
    if x1 == x2:  # a node sending to itself: a loop
        parts.append(f'<path d="M{x1},{y - 6} h40 v12 h-40" marker-end="url(#{marker})"/>')
        tx, anchor = x1 + 46, "start"
    else:
        end = x2 - 4 if x2 > x1 else x2 + 4
        parts.append(f'<line x1="{x1}" y1="{y}" x2="{end}" y2="{y}" marker-end="url(#{marker})"/>')
        tx, anchor = (x1 + x2) // 2, "middle"
        if a.unanswered:
            cx = end - (10 if x2 > x1 else -10)
            parts.append(f'<path class="cross" d="M{cx - 4},{y - 4} l8,8 M{cx - 4},{y + 4} l8,-8"/>')
    parts.append(f'<text x="{tx}" y="{y - 5}" text-anchor="{anchor}">{_esc(label)}</text>')
    if a.rules:  # beyond the arrow's far end, on its own row: never over a label
        badge = "✗ " + " ".join(a.rules)
        bx = max(x1, x2) + (50 if x1 == x2 else 10)
        w = 7 * len(badge) + 6
        parts.append(f'<rect class="badge" x="{bx}" y="{y - 7}" width="{w}" height="14" rx="3"/>'
                     f'<text class="badge-text" x="{bx + 4}" y="{y + 4}">{_esc(badge)}</text>')
    parts.append("</g>")
    return "".join(parts)


# ---------------------------------------------------------------- from a Trace
def arrow_of(e: Any, broadcast_id: int | None = None) -> Arrow:
    """The arrow of a :class:`traceio.trace.Entry`."""
    from mcp_conform.traceio.trace import describe_payload

    if e.msg is None:
        kind = "malformed"
    elif e.header[3] == 7:
        kind = "ack"
    elif broadcast_id is not None and e.header[0] == broadcast_id:
        kind = "bcast"
    else:
        kind = "msg"
    d = e.dgram
    notes = [f"{_addr(d.src_addr)} → {_addr(d.dst_addr)}", f"{len(d.data)} bytes"]
    if e.msg is not None:
        desc = describe_payload(e.msg)
        if desc:
            notes.append(desc)
    if e.error:
        notes.append(e.error)
    if e.first is not None:
        notes.append(f"retransmission {e.copy} of #{e.first}")
    if e.acked_by is not None:
        notes.append(f"ACKed by #{e.acked_by}")
    if e.ack_of is not None:
        notes.append(f"answers #{e.ack_of}")
    rules = tuple(dict.fromkeys(getattr(v, "rule", str(v)) for v in e.violations))
    return Arrow(d.t_ns, e.src, e.dst, e.label, kind, e.copy, e.unanswered and kind == "msg", rules,
                 "\n".join(notes), d.index)


def _addr(addr: Any) -> str:
    return f"{addr[0]}:{addr[1]}" if addr else "?"


def trace_svg(trace: Any, entries: Iterable[Any] | None = None, title: str = "",
              max_rows: int = MAX_ROWS, t0_ns: int | None = None) -> str:
    """The chart of ``entries`` (default: all) of a :class:`traceio.trace.Trace`; times
    since ``t0_ns`` (default: the first entry's)."""
    entries = list(trace.entries if entries is None else entries)
    keys = trace.lifelines(entries)
    lifelines = [Lifeline(k, *trace.lifeline_title(k)) for k in keys]
    return render(lifelines, [arrow_of(e, trace.broadcast_id) for e in entries], title, max_rows, t0_ns)

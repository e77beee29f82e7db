"""``mcp-capture diff --html OUT``: both sides' sequence charts side by side.

One section per conversation with divergences (then the others, folded): the golden
conversation on the left, the candidate's on the right, each a chart of
:mod:`reports.chart` whose rows are the aligned messages — a missing message leaves a gap
on the right, an extra one a gap on the left (a grey "(not here)" row: no arrow, no time of
the other capture's) — with divergent arrows marked by class
(``missing``, ``extra``, ``changed``, ``reordered``, ``copies``, ``timing``, ``address``)
and the divergence list above. Arrows stay in time order; where cases ran side by side the
page says so (their interleaving was not compared: :mod:`captures.overlap`).
"""

from __future__ import annotations

from html import escape
from pathlib import Path
from typing import Any

from captures.conversation import Entry, describe, peers_text
from captures.overlap import spans_text
from reports.chart import Arrow, Lifeline, render
from spec.codec import BROADCAST_ID, MANAGER_ID, Action

__all__ = ["html_report", "write_html"]

STYLE = """
body { font: 14px system-ui, sans-serif; margin: 1.5em; color: #1a202c; }
h1 { font-size: 1.3em; } h2 { font-size: 1.1em; margin-top: 1.5em; }
.same { color: #2f855a; font-weight: bold; } .different { color: #c53030; font-weight: bold; }
table.divs { border-collapse: collapse; margin: .5em 0; }
table.divs td, table.divs th { border: 1px solid #cbd5e0; padding: 2px 8px; font-size: 12px; text-align: left; }
.pair { display: flex; gap: 16px; align-items: flex-start; overflow-x: auto; }
.pair > div { flex: 0 0 auto; }
.mcp-chart .arrow.missing line, .mcp-chart .arrow.extra line, .mcp-chart .arrow.changed line,
.mcp-chart .arrow.reordered line { stroke: #c53030 !important; stroke-width: 3 !important; }
.mcp-chart .arrow.copies line, .mcp-chart .arrow.timing line, .mcp-chart .arrow.address line
{ stroke: #d69e2e !important; stroke-width: 3 !important; }
.mcp-chart .arrow.gap text { fill: #a0aec0; font-style: italic; }
"""


def _node(n: Any) -> str:
    if n is None:
        return "?"
    if n == BROADCAST_ID:
        return "broadcast"
    return "manager 0" if n == MANAGER_ID else f"drone {n}"


def _arrow(e: Entry | None, other: Entry | None, kind: str) -> Arrow:
    if e is None:  # the other side has a message here: a gap row on this side
        assert other is not None
        return Arrow(other.t_ns, _node(other.src), _node(other.dst), "(not here)", "gap",
                     extra_class=kind, note=describe(other))
    if e.action is None:
        style = "malformed"
    elif e.action == Action.ACK:
        style = "ack"
    elif e.dst == BROADCAST_ID:
        style = "bcast"
    else:
        style = "msg"
    return Arrow(e.t_ns, _node(e.src), _node(e.dst), describe(e), style, copy=e.copies - 1,
                 note=describe(e), index=e.index, extra_class=kind)


def _charts(result: Any, peers: tuple[Any, Any]) -> tuple[str, str]:
    g = result.golden.conversations.get(peers)
    c = result.candidate.conversations.get(peers)
    kinds: dict[tuple[int | None, int | None], str] = {}
    for d in result.divergences:
        if d.peers == peers:
            kinds.setdefault((d.golden_pos, d.candidate_pos), d.kind)
    left: list[Arrow] = []
    right: list[Arrow] = []
    for i, j in result.aligned.get(peers, []):
        eg = g.entries[i] if (g is not None and i is not None) else None
        ec = c.entries[j] if (c is not None and j is not None) else None
        kind = kinds.get((i, j), "")
        left.append(_arrow(eg, ec, kind))
        right.append(_arrow(ec, eg, kind))
    lifelines = [Lifeline(_node(p), _node(p)) for p in peers]
    return (render(lifelines, left, title=f"golden: {result.golden.name}"),
            render(lifelines, right, title=f"candidate: {result.candidate.name}"))


def html_report(result: Any) -> str:
    verdict = ('<p class="same">same: every conversation matches</p>' if result.same else
               f'<p class="different">{len(result.divergences)} divergence(s): ' +
               escape(", ".join(f"{n} {k}" for k, n in result.summary().items())) + "</p>")
    rows = "".join(
        f"<tr><td>{escape(d.kind)}</td><td>{escape(peers_text(d.peers))}</td>"
        f"<td>{escape(describe(d.golden)) if d.golden else ''}</td>"
        f"<td>{escape(describe(d.candidate)) if d.candidate else ''}</td><td>{escape(d.note)}</td></tr>"
        for d in result.divergences[:500])
    table = ("<table class='divs'><tr><th>kind</th><th>conversation</th><th>golden</th><th>candidate</th>"
             f"<th>what</th></tr>{rows}</table>") if rows else ""
    diverging = [p for p in result.aligned if any(d.peers == p for d in result.divergences)]
    others = [p for p in result.aligned if p not in diverging]
    sections = []
    for peers in diverging + others:
        left, right = _charts(result, peers)
        body = f"<div class='pair'><div>{left}</div><div>{right}</div></div>"
        title = escape(peers_text(peers))
        if peers in diverging:
            sections.append(f"<h2>conversation {title}</h2>{body}")
        else:
            sections.append(f"<details><summary>conversation {title} (same)</summary>{body}</details>")
    drift = f"<p>largest timing drift {result.max_drift_ns / 1e9:+.3f} s</p>" + "".join(
        f"<p>{label}: {escape(spans_text(side.overlaps))}</p>"
        for side, label in ((result.golden, "golden"), (result.candidate, "candidate")) if side.overlaps)
    return ("<!DOCTYPE html><html><head><meta charset='utf-8'><title>mcp-capture diff</title>"
            f"<style>{STYLE}</style></head><body><h1>mcp-capture diff</h1>"
            f"<p>golden: {escape(result.golden.name)}<br>candidate: {escape(result.candidate.name)}</p>"
            f"{verdict}{drift}{table}{''.join(sections)}</body></html>\n")


def write_html(result: Any, path: str | Path) -> None:
    Path(path).write_text(html_report(result), encoding="utf-8")

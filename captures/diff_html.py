"""``mcp-capture diff --html OUT``: both sides' sequence charts side by side.

One section per conversation with divergences (then the others, folded): the golden
conversation on the left, the candidate's on the right, each a chart of
:mod:`reports.chart` whose rows are the aligned messages — a missing message leaves a gap
on the right, an extra one a gap on the left (a grey "(not here)" row: no arrow, no time of
the other capture's) — with divergent arrows marked by class
(``missing``, ``extra``, ``changed``, ``reordered``, ``copies``, ``timing``, ``address``)
and the divergence list above. Arrows stay in time order; where cases ran side by side the
page says so (their interleaving was not compared: :mod:`captures.overlap`). Values are
escaped by ``reports.templating.fill`` (autoescape) unless they are markup built here.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from mcp_conform.captures.conversation import Entry, describe, peers_text
from mcp_conform.captures.overlap import spans_text
from mcp_conform.reports.chart import Arrow, Lifeline, render
from mcp_conform.reports.templating import Markup, Template, fill, join
from mcp_conform.spec.codec import BROADCAST_ID, MANAGER_ID, Action

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


_PAGE = Template("<!DOCTYPE html><html><head><meta charset='utf-8'><title>mcp-capture diff</title>"
                 "<style>$style</style></head><body><h1>mcp-capture diff</h1>"
                 "<p>golden: $golden<br>candidate: $candidate</p>$verdict$drift$table$sections</body></html>\n")
_SAME = Template('<p class="same">$text</p>')
_DIFFERENT = Template('<p class="different">$n divergence(s): $kinds</p>')
_ROW = Template("<tr><td>$kind</td><td>$peers</td><td>$golden</td><td>$candidate</td><td>$note</td></tr>")
_TABLE = Template("<table class='divs'><tr><th>kind</th><th>conversation</th><th>golden</th><th>candidate</th>"
                  "<th>what</th></tr>$rows</table>")
_PAIR = Template("<div class='pair'><div>$left</div><div>$right</div></div>")
_DIVERGING = Template("<h2>conversation $title</h2>$body")
_FOLDED = Template("<details><summary>conversation $title (same)</summary>$body</details>")
_P = Template("<p>$text</p>")


def html_report(result: Any) -> str:
    """The page: every value escaped by ``reports.templating.fill`` unless it is markup built
    here or a chart (``reports.chart`` escapes its own text)."""
    verdict = fill(_SAME, text="same: every conversation matches") if result.same else fill(
        _DIFFERENT, n=len(result.divergences), kinds=", ".join(f"{n} {k}" for k, n in result.summary().items()))
    rows = join(fill(_ROW, kind=d.kind, peers=peers_text(d.peers), golden=describe(d.golden) if d.golden else "",
                     candidate=describe(d.candidate) if d.candidate else "", note=d.note)
                for d in result.divergences[:500])
    table = fill(_TABLE, rows=rows) if rows else Markup("")
    diverging = [p for p in result.aligned if any(d.peers == p for d in result.divergences)]
    others = [p for p in result.aligned if p not in diverging]
    sections = []
    for peers in diverging + others:
        left, right = _charts(result, peers)
        body = fill(_PAIR, left=Markup(left), right=Markup(right))
        sections.append(fill(_DIVERGING if peers in diverging else _FOLDED, title=peers_text(peers), body=body))
    drift = join([fill(_P, text=f"largest timing drift {result.max_drift_ns / 1e9:+.3f} s")]
                 + [fill(_P, text=f"{label}: {spans_text(side.overlaps)}")
                    for side, label in ((result.golden, "golden"), (result.candidate, "candidate")) if side.overlaps])
    return str(fill(_PAGE, style=Markup(STYLE), golden=result.golden.name, candidate=result.candidate.name,
                    verdict=verdict, drift=drift, table=table, sections=join(sections)))


def write_html(result: Any, path: str | Path) -> None:
    Path(path).write_text(html_report(result), encoding="utf-8")

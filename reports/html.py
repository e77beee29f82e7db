"""Self-contained HTML reports: ``mcp-capture check --html`` and ``mcp-conform --html``.

One file, no external assets (inline CSS, inline SVG charts, no script), that opens from
disk in any browser: a summary, the per-rule table, every case of a run (passed ones too, with
skip reasons and INFO notes), and for every violation (check) or every
failed, warned or errored case (a run) the rule's text from the spec, expected, actual, the
evidence and the sequence chart of its traffic (``reports.chart``) — for a run, the
datagrams of the case's capture window (``capture.start_ns`` / ``end_ns`` of the JSON
report), with the datagrams the case's evidence names marked.

Elements carry stable hooks for tools and tests: ``section.finding`` with ``data-rule`` and
``data-outcome``, ``table.rules`` with one ``tr[data-rule]`` per rule, ``table.cases`` with one
``tr[data-case][data-outcome]`` per case, and the charts' ``svg.mcp-chart`` / ``g.arrow``.

Every fragment is a ``string.Template`` filled by ``reports.templating.fill``, which escapes
each value (a rule's text, a node's output, a path) unless it is ``Markup``, HTML built here
or a chart: escaping is the default, as in a template engine with autoescape.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

from mcp_conform.reports.chart import trace_svg
from mcp_conform.reports.nsqd_chart import stream_svg
from mcp_conform.reports.templating import Markup, Template, attrs, fill, join
from mcp_conform.spec import RULES, SPEC
from mcp_conform.spec.profiles import Profile, ProfileError, pick, profile_of_role
from mcp_conform.traceio.reader import Datagram, StreamFrame
from mcp_conform.traceio.trace import Trace, evidence_indexes

__all__ = ["page", "render_check", "render_run", "write_run"]

CSS = """
body { font: 14px/1.45 system-ui, -apple-system, Segoe UI, Roboto, sans-serif; margin: 24px; color: #1a202c; }
h1 { font-size: 22px; margin: 0 0 4px; } h2 { font-size: 18px; margin: 28px 0 8px; }
.meta { color: #4a5568; }
table { border-collapse: collapse; margin: 8px 0; }
th, td { border: 1px solid #cbd5e0; padding: 3px 8px; text-align: left; vertical-align: top; }
th { background: #edf2f7; }
table.rules td:first-child, table.nodes td:first-child, table.cases td:first-child { white-space: nowrap; }
table.cases td:last-child { white-space: pre-wrap; font-size: 12.5px; }
td.num { text-align: right; }
span.passed { color: #2f855a; } span.failed, span.error { color: #c53030; font-weight: bold; }
span.warned { color: #b7791f; font-weight: bold; } span.info { color: #2b6cb0; }
span.skipped, span.not_observed { color: #718096; } span.consequence { color: #c53030; }
section.finding h3 { color: #c53030; } section.finding.warned h3 { color: #b7791f; }
.summary span { display: inline-block; margin-right: 14px; }
.banner { padding: 8px 12px; border-radius: 4px; margin: 8px 0; }
.banner.bad { background: #fff5f5; border: 1px solid #feb2b2; }
.banner.good { background: #f0fff4; border: 1px solid #9ae6b4; }
.banner.warn { background: #fffff0; border: 1px solid #f6e05e; }
section.finding { border: 1px solid #cbd5e0; border-left: 5px solid #c53030; border-radius: 4px;
                  padding: 8px 14px; margin: 14px 0; }
section.finding.warned { border-left-color: #d69e2e; }
section.finding.error { border-left-color: #805ad5; }
section.finding h3 { margin: 2px 0 6px; font-size: 16px; }
.rule-text { font-style: italic; color: #2d3748; margin: 4px 0 8px; }
dl { display: grid; grid-template-columns: max-content 1fr; gap: 2px 12px; margin: 6px 0; }
dt { font-weight: bold; color: #4a5568; } dd { margin: 0; white-space: pre-wrap; font-family: ui-monospace, monospace; font-size: 12.5px; }
ul.evidence { margin: 4px 0; padding-left: 20px; font-family: ui-monospace, monospace; font-size: 12.5px; }
.chart { overflow-x: auto; border: 1px solid #e2e8f0; margin: 8px 0; background: #fff; }
.none { color: #718096; font-style: italic; }
"""


_PAGE = Template('<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
                 '<meta name="viewport" content="width=device-width, initial-scale=1">'
                 "<title>$title</title><style>$css</style></head>\n<body>\n$body\n</body></html>\n")
_TABLE = Template('<table class="$cls"><thead><tr>$heads</tr></thead><tbody>$rows</tbody></table>')
_TH = Template("<th>$cell</th>")
_TD = Template("<td>$cell</td>")
_TR = Template("<tr$attrs>$cells</tr>")
_LI = Template("<li>$item</li>")
_UL = Template("<ul>$items</ul>")
_SPAN = Template('<span class="$cls">$text</span>')
_H1 = Template("<h1>$text</h1>")
_H2 = Template("<h2>$text</h2>")
_META = Template('<p class="meta">$text</p>')
_BANNER = Template('<p class="banner $cls">$text</p>')
_NONE = Template('<p class="none">$text</p>')
_FINDING = Template('<section class="finding $outcome" data-rule="$rule" data-outcome="$outcome">\n'
                    "<h3>$heading</h3>")
_RULE_TEXT = Template('<p class="rule-text">$rule ($level): $text</p>')
_DL = Template("<dl>$items</dl>")
_DT_DD = Template("<dt>$term</dt><dd>$value</dd>")
_EVIDENCE = Template('<b>evidence</b><ul class="evidence">$items</ul>')
_CHART = Template('<div class="chart">$svg</div>')
_COUNT = Template("<span><b>$n</b> $text</span>")
_SPAN_PLAIN = Template("<span>$text</span>")
_KIND = Template('<span class="$cls"><b>$n</b> $text</span>')
_NUM = Template('<span class="num">$text</span>')


def page(title: str, body: str) -> str:
    """A whole HTML document around ``body`` (HTML: a :class:`Markup`, or a string this
    module's renderers returned)."""
    return str(fill(_PAGE, title=title, css=Markup(CSS), body=Markup(body)))


def _rule_text(rule: str | None) -> str:
    r = RULES.get(rule or "")
    return r.text if r else ""


def _level(rule: str | None) -> str:
    r = RULES.get(rule or "")
    return r.level if r else ""


def _table(headers: Sequence[str], rows: Iterable[Sequence[Any]], cls: str = "",
           row_attrs: Iterable[dict[str, Any]] | None = None) -> Markup:
    """A table; its cells are values (escaped) or :class:`Markup`; ``row_attrs``: each row's
    attributes (``data-rule``, ...)."""
    each = list(row_attrs) if row_attrs is not None else None
    body = join(fill(_TR, attrs=attrs(each[n]) if each is not None else Markup(""),
                       cells=join(fill(_TD, cell=c) for c in row)) for n, row in enumerate(rows))
    return fill(_TABLE, cls=cls, heads=join(fill(_TH, cell=h) for h in headers), rows=body)


def _verdict(v: str | None) -> Markup:
    return fill(_SPAN, cls=v, text=v) if v else Markup("")


def _consequence(roots: Sequence[str]) -> Markup:
    """A rule the trace monitor proved violated as an earlier failure's consequence."""
    return fill(_SPAN, cls="consequence", text=f"see {', '.join(roots)}" if roots else "consequence")


def _finding(rule: str | None, outcome: str, heading: str, fields: Sequence[tuple[str, Any]],
             evidence: Sequence[str], chart: Markup | None, chart_note: str = "") -> Markup:
    out = [fill(_FINDING, outcome=outcome, rule=rule or "", heading=heading)]
    text = _rule_text(rule)
    if text:
        out.append(fill(_RULE_TEXT, rule=rule, level=_level(rule), text=text))
    items = [(k, v) for k, v in fields if v not in (None, "", [])]
    if items:
        out.append(fill(_DL, items=join(fill(_DT_DD, term=k, value=v) for k, v in items)))
    if evidence:
        out.append(fill(_EVIDENCE, items=join(fill(_LI, item=x) for x in evidence)))
    if chart:
        out.append(fill(_CHART, svg=chart))
    elif chart_note:
        out.append(fill(_NONE, text=chart_note))
    out.append(Markup("</section>"))
    return join(out, "\n")


# ---------------------------------------------------------------- mcp-capture check
def render_check(j: Any, doc: dict[str, Any]) -> str:
    """The page of a :class:`judge.judging.Judgement` (``doc``: its JSON, ``check.to_json``)."""
    trace = Trace(j.kept or (), j.params.broadcast_id)
    trace.mark(j.shown_violations)
    f, s = doc["file"], doc["summary"]
    body = [fill(_H1, text=f"mcp-capture check: {f['path']}"),
            fill(_META, text=f'{f["format"]} · {f["datagrams"]} datagram(s) over {f["duration_s"]:.3f} s · '
                              f'{doc["tool"]["name"]} {doc["tool"]["version"]} · MCP spec {doc["spec"]["version"]}')]
    if f["truncated"]:
        body.append(fill(_BANNER, cls="warn", text=f"Truncated: {f['truncated']}; judged what was read."))
    counts = join([fill(_COUNT, n=s["violations"], text="violation(s)")]
                   + [fill(_SPAN_PLAIN, text=f"{k.upper()} {s[k]}") for k in ("must", "should", "info")]
                   + [fill(_SPAN_PLAIN, text=f"exit code {s['exit_code']}")])
    body.append(fill(_BANNER, cls=("bad" if s["failing"] else "good") + " summary", text=counts))
    notes = [*f["notes"], *([doc["parameters"]["challenge_note"]] if doc["parameters"]["challenge_note"] else [])]
    if notes:
        body.append(fill(_UL, items=join(fill(_LI, item=n) for n in notes)))
    body.append(fill(_H2, text="Nodes"))
    body.append(_table(["ID", "role", "addresses", "sent", "received"],
                       [[n["id"], n["role"], ", ".join(n["addresses"]) or "-",
                         n["datagrams"]["sent"], n["datagrams"]["received"]] for n in doc["nodes"]],
                       "nodes"))
    body.append(fill(_H2, text=f"Violations ({len(doc['violations'])})"))
    if not doc["violations"]:
        body.append(fill(_NONE, text="No violations."))
    for v, raw in zip(doc["violations"], j.shown_violations, strict=True):
        idx = evidence_indexes(raw)
        entries = trace.around(idx) if idx else []
        chart = Markup(trace_svg(trace, entries, title=f"{v['rule']} · node {v['node']}")) if entries else None
        outcome = "failed" if v["level"] == "MUST" or (v["level"] == "SHOULD" and j.params.strict) else "warned"
        body.append(_finding(v["rule"], outcome, f"{v['rule']} · node {v['node']} · +{v['t']:.6f} s",
                             [("expected", v["expected"]), ("actual", v["actual"])],
                             [e["summary"] for e in v["evidence"]], chart,
                             "" if chart else "no datagrams in the evidence to chart"))
    body.append(fill(_H2, text="Rules"))
    body.append(_rules_by_node(doc))
    return page(f"mcp-capture check {f['path']}", join(body, "\n"))


def _rules_by_node(doc: dict[str, Any]) -> Markup:
    nodes = sorted(doc["rules"], key=int)
    rules = {r for by in doc["rules"].values() for r in by}
    order = [r for r in RULES if r in rules] + sorted(rules - set(RULES))
    counts: dict[str, int] = {}
    for v in doc["violations"]:
        counts[v["rule"]] = counts.get(v["rule"], 0) + 1
    rows = [[r, _level(r), *(_verdict(doc["rules"][n].get(r)) for n in nodes), counts.get(r, "") or ""]
            for r in order]
    return _table(["rule", "level", *(f"node {n}" for n in nodes), "violations"], rows, "rules",
                  [{"data-rule": r} for r in order])


# ---------------------------------------------------------------- mcp-conform


def _case_chart(case: dict[str, Any], trace: Trace | None) -> tuple[Markup | None, str]:
    if trace is None:
        return None, "no capture of the run's traffic"
    cap = case.get("capture") or {}
    start, end = cap.get("start_ns"), cap.get("end_ns")
    if start is None:
        return None, "the case has no capture window"
    entries = trace.window(start, end)
    if not entries:
        return None, "no datagrams in the case's capture window"
    return Markup(trace_svg(trace, entries, title=f"{case['id']} · {len(entries)} datagram(s)")), ""


def _stream_chart(case: dict[str, Any], frames: Sequence[StreamFrame] | None) -> tuple[Markup | None, str]:
    if frames is None:
        return None, "no capture of the run's traffic"
    cap = case.get("capture") or {}
    start, end = cap.get("start_ns"), cap.get("end_ns")
    if start is None:
        return None, "the case has no capture window"
    window = [f for f in frames if start <= f.t_ns <= (end or f.t_ns)]
    if not window:
        return None, "no frames in the case's capture window"
    return Markup(stream_svg(window, title=f"{case['id']} · {len(window)} frame(s)")), ""


def _profile(doc: dict[str, Any]) -> Profile:
    """The run's protocol (``spec.profiles``): the report's, else its role's (a role belongs to
    one protocol), else the default."""
    name = (doc.get("parameters") or {}).get("protocol")
    try:
        return profile_of_role(str(doc["role"])) if name is None and doc.get("role") else pick(name)[0]
    except ProfileError:
        return pick()[0]


def render_run(doc: dict[str, Any], datagrams: Sequence[Datagram] | None = None,
               frames: Sequence[StreamFrame] | None = None) -> str:
    """The page of an ``mcp-conform`` JSON report, with charts from the run's datagrams (or,
    for a stream protocol's run, its frames)."""
    trace = Trace(datagrams, doc.get("parameters", {}).get("broadcast_id") or SPEC.protocol["broadcast_id"]) \
        if datagrams is not None else None
    monitor = doc.get("monitor") or {}
    violations = _monitor_violations(monitor, trace)
    if trace is not None:
        trace.mark(violations)
    s = doc.get("summary", {})
    target = doc.get("target") or "the embedded reference node"
    tool, spec = doc.get("tool", {}), doc.get("spec", {})
    prof = _profile(doc)
    #: each case's chart, as the protocol's framing carries its messages: datagrams or a stream's frames
    chart_of = {"datagram": lambda c: _case_chart(c, trace), "stream": lambda c: _stream_chart(c, frames)}.get(
        prof.framing, lambda c: (None, f"no sequence chart of {prof.name}'s {prof.framing}s yet"))
    body = [fill(_H1, text=f"mcp-conform: {doc.get('role') or prof.default_role.name} at {target}"),
            fill(_META, text=f'{_str(tool.get("name"))} {_str(tool.get("version"))} · '
                              f'{_str(spec.get("protocol", "MCP"))} spec {_str(spec.get("version"))} · '
                              f'{s.get("duration_s", 0):.1f} s')]
    if doc.get("error"):
        body.append(fill(_BANNER, cls="bad", text=f"Error: {doc['error']}"))
    by_monitor = [f for f in doc.get("failures", []) if f.get("source") == "monitor" and not f.get("consequence_of")]
    mon_failed = sum(f.get("outcome") == "failed" for f in by_monitor)
    bad = s.get("failed", 0) + s.get("error", 0) + mon_failed
    kinds = [fill(_KIND, cls=k, n=s.get(k, 0), text=k) for k in ("passed", "failed", "warned", "skipped", "info", "error")]
    if by_monitor:
        kinds += [fill(_KIND, cls="failed", n=mon_failed, text="failed by the monitor"),
                  fill(_KIND, cls="warned", n=len(by_monitor) - mon_failed, text="warned by the monitor")]
    cls = "bad" if bad else "warn" if s.get("warned") or by_monitor else "good"
    body.append(fill(_BANNER, cls=f"{cls} summary", text=join(kinds)))
    cases = [c for c in doc.get("cases", []) if c.get("outcome") in ("failed", "warned", "error")]
    body.append(fill(_H2, text=f"Failed, warned and errored cases ({len(cases)})"))
    if not cases:
        body.append(fill(_NONE, text="None."))
    for c in cases:
        chart, why = chart_of(c)
        rule = c.get("failed_rule") or (c.get("rules") or [None])[0]
        heading = f"{c['outcome'].upper()} {c['id']} · {' '.join(c.get('rules', []))}"
        fields = [("expected", c.get("expected")), ("actual", c.get("actual")), ("reason", c.get("reason")),
                  ("notes", "\n".join(c.get("notes") or []))]
        body.append(_finding(rule, c["outcome"], heading, fields, c.get("evidence") or [], chart, why))
    if violations:
        body.append(fill(_H2, text=f"Trace monitor ({len(violations)} violation(s))"))
        for v in violations:
            idx = evidence_indexes(v)
            entries = trace.around(idx) if trace is not None and idx else []
            chart = Markup(trace_svg(trace, entries, title=f"{v.rule} · node {v.node}")) \
                if trace is not None and entries else None
            body.append(_finding(v.rule, "failed" if _level(v.rule) == "MUST" else "warned",
                                 f"{v.rule} · node {v.node}",
                                 [("expected", v.expected), ("actual", v.actual)],
                                 [f"#{i}" for i in idx], chart, "" if chart else "no datagrams to chart"))
    body.append(_all_cases(doc.get("cases", [])))
    rules = doc.get("rules", {})
    order = [r for r in RULES if r in rules] + sorted(set(rules) - set(RULES))
    #: a ``consequence`` row (schema 1.5) names its root, as the report's failures do
    roots = {f["rule"]: f["consequence_of"] for f in doc.get("failures", [])
             if f.get("source") == "monitor" and f.get("consequence_of")}
    body.append(fill(_H2, text="Rules"))
    body.append(_table(["rule", "level", "outcome", "requirement"],
                       [[r, _level(r), _consequence(roots.get(r, ())) if rules[r] == "consequence" else _verdict(rules[r]),
                         _rule_text(r)] for r in order],
                       "rules", [{"data-rule": r} for r in order]))
    return page(f"mcp-conform {target}", join(body, "\n"))


def _str(value: Any) -> str:
    """A value as the page shows it: None as nothing."""
    return "" if value is None else str(value)


def _case_details(c: dict[str, Any]) -> str:
    """What a case's row says beside its outcome: a skip's reason, what an INFO case (or a
    pass) recorded, a failure's actual."""
    if c.get("outcome") in ("skipped", "error"):
        parts = [c.get("reason")]
    elif c.get("failed_rule"):
        parts = [f"{c['failed_rule']}: {c.get('actual') or ''}"]
    else:
        parts = [c.get("actual")] + [n for n in c.get("notes") or [] if n != c.get("actual")]
    if c.get("baseline"):
        parts.append(f"baseline: {c['baseline']}")
    return "\n".join(str(p) for p in parts if p)


def _all_cases(cases: Sequence[dict[str, Any]]) -> Markup:
    """Every case of the run, passed ones included, as Autobahn's report lists them: its
    rules, outcome, time, and the skip reason or the INFO note."""
    rows = [[c["id"], " ".join(c.get("rules") or []), _verdict(c.get("outcome")),
             fill(_NUM, text=f'{float(c.get("duration_s") or 0):.3f} s'), _case_details(c)]
            for c in cases]
    table = _table(["case", "rules", "outcome", "time", "details"], rows, "cases",
                   [{"data-case": c["id"], "data-outcome": c.get("outcome")} for c in cases]) \
        if cases else fill(_NONE, text="No case ran.")
    return join([fill(_H2, text=f"All cases ({len(cases)})"), table], "\n")


class _JsonViolation:
    """A violation as the JSON report's monitor section holds it; its evidence as the
    capture's datagram indexes (found by timestamp: the monitor and the recorder stamp each
    datagram with the same run clock)."""

    def __init__(self, d: dict[str, Any], index_at: dict[int, int]) -> None:
        self.rule = d.get("rule")
        self.node = d.get("node")
        self.expected = d.get("expected")
        self.actual = d.get("actual")
        self.evidence = [index_at.get(e.get("t_ns") or -1, e.get("index")) if isinstance(e, dict) else e
                         for e in d.get("evidence") or []]


def _monitor_violations(monitor: dict[str, Any], trace: Trace | None) -> list[_JsonViolation]:
    index_at = {e.dgram.t_ns: e.index for e in trace.entries} if trace is not None else {}
    return [_JsonViolation(v, index_at) for v in monitor.get("violations", []) if isinstance(v, dict)]


def write_run(path: str, doc: dict[str, Any], capture: str | None) -> None:
    """Write the run's page; the charts come from ``capture`` (our MCAP) where it reads."""
    from mcp_conform.traceio.reader import CaptureError, open_capture

    datagrams = frames = None
    if capture:
        try:
            records = list(open_capture(capture))
            datagrams = [r for r in records if type(r) is Datagram]
            frames = [r for r in records if type(r) is StreamFrame]
        except CaptureError:
            datagrams = frames = None
    with open(path, "w", encoding="utf-8") as f:
        f.write(render_run(doc, datagrams, frames))

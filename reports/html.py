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
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from html import escape
from typing import Any

from reports.chart import trace_svg
from reports.stream_chart import stream_svg
from spec import RULES, SPEC
from traceio.reader import Datagram, StreamFrame
from traceio.trace import Trace, evidence_indexes

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
span.skipped, span.not_observed { color: #718096; }
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


def _e(text: Any) -> str:
    return escape("" if text is None else str(text), quote=True)


def page(title: str, body: str) -> str:
    """A whole HTML document around ``body``."""
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{_e(title)}</title><style>{CSS}</style></head>\n<body>\n{body}\n</body></html>\n")


def _rule_text(rule: str | None) -> str:
    r = RULES.get(rule or "")
    return r.text if r else ""


def _level(rule: str | None) -> str:
    r = RULES.get(rule or "")
    return r.level if r else ""


def _table(headers: Sequence[str], rows: Iterable[Sequence[str]], cls: str = "",
           row_attrs: Iterable[str] | None = None) -> str:
    """A table of already-escaped cells."""
    attrs = list(row_attrs) if row_attrs is not None else None
    out = [f'<table class="{cls}"><thead><tr>' + "".join(f"<th>{_e(h)}</th>" for h in headers) + "</tr></thead><tbody>"]
    for n, row in enumerate(rows):
        extra = f" {attrs[n]}" if attrs is not None else ""
        out.append(f"<tr{extra}>" + "".join(f"<td>{c}</td>" for c in row) + "</tr>")
    out.append("</tbody></table>")
    return "".join(out)


def _verdict(v: str | None) -> str:
    return f'<span class="{_e(v)}">{_e(v)}</span>' if v else ""


def _finding(rule: str | None, outcome: str, heading: str, fields: Sequence[tuple[str, Any]],
             evidence: Sequence[str], chart: str | None, chart_note: str = "") -> str:
    out = [f'<section class="finding {_e(outcome)}" data-rule="{_e(rule or "")}" data-outcome="{_e(outcome)}">',
           f"<h3>{heading}</h3>"]
    text = _rule_text(rule)
    if text:
        out.append(f'<p class="rule-text">{_e(rule)} ({_e(_level(rule))}): {_e(text)}</p>')
    items = [(k, v) for k, v in fields if v not in (None, "", [])]
    if items:
        out.append("<dl>" + "".join(f"<dt>{_e(k)}</dt><dd>{_e(v)}</dd>" for k, v in items) + "</dl>")
    if evidence:
        out.append('<b>evidence</b><ul class="evidence">' + "".join(f"<li>{_e(x)}</li>" for x in evidence) + "</ul>")
    if chart:
        out.append(f'<div class="chart">{chart}</div>')
    elif chart_note:
        out.append(f'<p class="none">{_e(chart_note)}</p>')
    out.append("</section>")
    return "\n".join(out)


# ---------------------------------------------------------------- mcp-capture check
def render_check(j: Any, doc: dict[str, Any]) -> str:
    """The page of a :class:`judge.judging.Judgement` (``doc``: its JSON, ``check.to_json``)."""
    trace = Trace(j.kept or (), j.params.broadcast_id)
    trace.mark(j.shown_violations)
    f, s = doc["file"], doc["summary"]
    body = [f"<h1>mcp-capture check: {_e(f['path'])}</h1>",
            f'<p class="meta">{_e(f["format"])} · {f["datagrams"]} datagram(s) over {f["duration_s"]:.3f} s · '
            f'{_e(doc["tool"]["name"])} {_e(doc["tool"]["version"])} · MCP spec {_e(doc["spec"]["version"])}</p>']
    if f["truncated"]:
        body.append(f'<p class="banner warn">Truncated: {_e(f["truncated"])}; judged what was read.</p>')
    cls = "bad" if s["failing"] else "good"
    body.append(f'<p class="banner {cls} summary"><span><b>{s["violations"]}</b> violation(s)</span>'
                f'<span>MUST {s["must"]}</span><span>SHOULD {s["should"]}</span><span>INFO {s["info"]}</span>'
                f'<span>exit code {s["exit_code"]}</span></p>')
    notes = [*f["notes"], *([doc["parameters"]["challenge_note"]] if doc["parameters"]["challenge_note"] else [])]
    if notes:
        body.append("<ul>" + "".join(f"<li>{_e(n)}</li>" for n in notes) + "</ul>")
    body.append("<h2>Nodes</h2>")
    body.append(_table(["ID", "role", "addresses", "sent", "received"],
                       [[_e(n["id"]), _e(n["role"]), _e(", ".join(n["addresses"]) or "-"),
                         _e(n["datagrams"]["sent"]), _e(n["datagrams"]["received"])] for n in doc["nodes"]],
                       "nodes"))
    body.append(f"<h2>Violations ({len(doc['violations'])})</h2>")
    if not doc["violations"]:
        body.append('<p class="none">No violations.</p>')
    for v, raw in zip(doc["violations"], j.shown_violations, strict=True):
        idx = evidence_indexes(raw)
        entries = trace.around(idx) if idx else []
        chart = trace_svg(trace, entries, title=f"{v['rule']} · node {v['node']}") if entries else None
        outcome = "failed" if v["level"] == "MUST" or (v["level"] == "SHOULD" and j.params.strict) else "warned"
        heading = f"{_e(v['rule'])} · node {_e(v['node'])} · +{v['t']:.6f} s"
        body.append(_finding(v["rule"], outcome, heading,
                             [("expected", v["expected"]), ("actual", v["actual"])],
                             [e["summary"] for e in v["evidence"]], chart,
                             "" if chart else "no datagrams in the evidence to chart"))
    body.append("<h2>Rules</h2>")
    body.append(_rules_by_node(doc))
    return page(f"mcp-capture check {f['path']}", "\n".join(body))


def _rules_by_node(doc: dict[str, Any]) -> str:
    nodes = sorted(doc["rules"], key=int)
    rules = {r for by in doc["rules"].values() for r in by}
    order = [r for r in RULES if r in rules] + sorted(rules - set(RULES))
    counts: dict[str, int] = {}
    for v in doc["violations"]:
        counts[v["rule"]] = counts.get(v["rule"], 0) + 1
    rows = [[_e(r), _e(_level(r)), *(_verdict(doc["rules"][n].get(r)) for n in nodes), _e(counts.get(r, "") or "")]
            for r in order]
    return _table(["rule", "level", *(f"node {n}" for n in nodes), "violations"], rows, "rules",
                  [f'data-rule="{_e(r)}"' for r in order])


# ---------------------------------------------------------------- mcp-conform


def _case_chart(case: dict[str, Any], trace: Trace | None) -> tuple[str | None, str]:
    if trace is None:
        return None, "no capture of the run's traffic"
    cap = case.get("capture") or {}
    start, end = cap.get("start_ns"), cap.get("end_ns")
    if start is None:
        return None, "the case has no capture window"
    entries = trace.window(start, end)
    if not entries:
        return None, "no datagrams in the case's capture window"
    return trace_svg(trace, entries, title=f"{case['id']} · {len(entries)} datagram(s)"), ""


def _stream_chart(case: dict[str, Any], frames: Sequence[StreamFrame] | None) -> tuple[str | None, str]:
    if frames is None:
        return None, "no capture of the run's traffic"
    cap = case.get("capture") or {}
    start, end = cap.get("start_ns"), cap.get("end_ns")
    if start is None:
        return None, "the case has no capture window"
    window = [f for f in frames if start <= f.t_ns <= (end or f.t_ns)]
    if not window:
        return None, "no frames in the case's capture window"
    return stream_svg(window, title=f"{case['id']} · {len(window)} frame(s)"), ""


def _framing(doc: dict[str, Any]) -> str:
    """How the run's protocol carries its messages (``spec.profiles``: datagram, stream), from
    the report's protocol (else its role, which belongs to one protocol)."""
    from spec.profiles import PROFILES, ProfileError, profile_of_role

    name = (doc.get("parameters") or {}).get("protocol")
    if name in PROFILES:
        return PROFILES[name].framing
    try:
        return profile_of_role(str(doc.get("role") or "drone")).framing
    except ProfileError:
        return "datagram"


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
    body = [f"<h1>mcp-conform: {_e(doc.get('role', 'drone'))} at {_e(target)}</h1>",
            f'<p class="meta">{_e(doc.get("tool", {}).get("name"))} {_e(doc.get("tool", {}).get("version"))} · '
            f'{_e(doc.get("spec", {}).get("protocol", "MCP"))} spec {_e(doc.get("spec", {}).get("version"))} · '
            f'{s.get("duration_s", 0):.1f} s</p>']
    if doc.get("error"):
        body.append(f'<p class="banner bad">Error: {_e(doc["error"])}</p>')
    by_monitor = [f for f in doc.get("failures", []) if f.get("source") == "monitor" and not f.get("consequence_of")]
    mon_failed = sum(f.get("outcome") == "failed" for f in by_monitor)
    bad = s.get("failed", 0) + s.get("error", 0) + mon_failed
    body.append(f'<p class="banner {"bad" if bad else "warn" if s.get("warned") or by_monitor else "good"} summary">'
                + "".join(f'<span class="{k}"><b>{_e(s.get(k, 0))}</b> {k}</span>'
                          for k in ("passed", "failed", "warned", "skipped", "info", "error"))
                + (f'<span class="failed"><b>{mon_failed}</b> failed by the monitor</span>'
                   f'<span class="warned"><b>{len(by_monitor) - mon_failed}</b> warned by the monitor</span>'
                   if by_monitor else "") + "</p>")
    cases = [c for c in doc.get("cases", []) if c.get("outcome") in ("failed", "warned", "error")]
    body.append(f"<h2>Failed, warned and errored cases ({len(cases)})</h2>")
    if not cases:
        body.append('<p class="none">None.</p>')
    for c in cases:
        chart, why = _stream_chart(c, frames) if _framing(doc) == "stream" else _case_chart(c, trace)
        rule = c.get("failed_rule") or (c.get("rules") or [None])[0]
        heading = f"{_e(c['outcome'].upper())} {_e(c['id'])} · {_e(' '.join(c.get('rules', [])))}"
        fields = [("expected", c.get("expected")), ("actual", c.get("actual")), ("reason", c.get("reason")),
                  ("notes", "\n".join(c.get("notes") or []))]
        body.append(_finding(rule, c["outcome"], heading, fields, c.get("evidence") or [], chart, why))
    if violations:
        body.append(f"<h2>Trace monitor ({len(violations)} violation(s))</h2>")
        for v in violations:
            idx = evidence_indexes(v)
            entries = trace.around(idx) if trace is not None and idx else []
            chart = trace_svg(trace, entries, title=f"{v.rule} · node {v.node}") if entries else None
            body.append(_finding(v.rule, "failed" if _level(v.rule) == "MUST" else "warned",
                                 f"{_e(v.rule)} · node {_e(v.node)}",
                                 [("expected", v.expected), ("actual", v.actual)],
                                 [f"#{i}" for i in idx], chart, "" if chart else "no datagrams to chart"))
    body.append(_all_cases(doc.get("cases", [])))
    rules = doc.get("rules", {})
    order = [r for r in RULES if r in rules] + sorted(set(rules) - set(RULES))
    body.append("<h2>Rules</h2>")
    body.append(_table(["rule", "level", "outcome", "requirement"],
                       [[_e(r), _e(_level(r)), _verdict(rules[r]), _e(_rule_text(r))] for r in order],
                       "rules", [f'data-rule="{_e(r)}"' for r in order]))
    return page(f"mcp-conform {target}", "\n".join(body))


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


def _all_cases(cases: Sequence[dict[str, Any]]) -> str:
    """Every case of the run, passed ones included, as Autobahn's report lists them: its
    rules, outcome, time, and the skip reason or the INFO note."""
    rows = [[_e(c["id"]), _e(" ".join(c.get("rules") or [])), _verdict(c.get("outcome")),
             f'<span class="num">{float(c.get("duration_s") or 0):.3f} s</span>', _e(_case_details(c))]
            for c in cases]
    return (f"<h2>All cases ({len(cases)})</h2>\n"
            + (_table(["case", "rules", "outcome", "time", "details"], rows, "cases",
                      [f'data-case="{_e(c["id"])}" data-outcome="{_e(c.get("outcome"))}"' for c in cases])
               if cases else '<p class="none">No case ran.</p>'))


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
    from traceio.reader import CaptureError, open_capture

    datagrams = frames = None
    if capture:
        try:
            records = list(open_capture(capture))
            datagrams = [r for r in records if type(r) is Datagram]
            frames = [r for r in records if type(r) is StreamFrame]
        except CaptureError:
            datagrams = frames = None
    with open(path, "w", encoding="utf-8") as f:
        f.write(render_run(doc, datagrams, frames if _framing(doc) == "stream" else None))

"""``mcp-capture check FILE``: judge a capture with the trace monitor.

Prints the nodes found (MCP ID, role, addresses, datagrams sent and received), every
violation grouped by rule with the rule's text, expected, actual and the evidence datagrams,
and a per-rule table of the monitor's verdicts per node. ``--json OUT`` writes the result
(``check.schema.json``, beside this module); ``--html OUT`` one self-contained page with the
sequence chart of each violation's traffic. Exit 0: no MUST violated (and no SHOULD under
``--strict``); 1: violations; 2: unreadable input or a bad option, with a one-line reason. A
truncated file is judged up to its last whole record, and the output says so (the verdict
reads INCOMPLETE, never OK); a file corrupt before its first record is an error (exit 2).
"""

from __future__ import annotations

import argparse
import json
from collections.abc import Iterator
from typing import TYPE_CHECKING, Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table

from mcp_conform.captures.check_doc import SCHEMA_VERSION, document, load_schema, validate_json
from mcp_conform.captures.cli import (
    UsageError,
    add_protocol_option,
    capture_tools,
    check_writable,
    to_terminal,
    write_output,
)
from mcp_conform.judge.params import add_monitor_options, params_from_args, selected
from mcp_conform.judge.verdicts import of_judgement
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import peek_header
from mcp_conform.traceio.grammar import open_output
from mcp_conform.traceio.reader import Datagram
from mcp_conform.traceio.trace import action_name, evidence_indexes

if TYPE_CHECKING:
    from mcp_conform.judge.judging import Judgement

__all__ = ["SCHEMA_VERSION", "describe_datagram", "load_schema", "register", "run", "run_check", "to_json",
           "validate_json"]

EXAMPLES = 3  # violations shown in full per rule; the rest are counted (all of them in --json)
NODE_ROWS = 30  # rows of the terminal's nodes table at most (a noisy capture's random IDs)
NODE_COLUMNS = 6  # node columns of the terminal's rules table at most
VERDICT_STYLES = {"passed": "green", "failed": "bold red", "warned": "yellow", "info": "cyan",
                  "not_observed": "dim"}


def register(sub: Any) -> None:
    p = sub.add_parser("check", help="judge a capture with the trace monitor",
                       description="Judge every MCP rule the traffic of a capture can show (MCAP, pcap, "
                       "pcapng). Exit 0: no MUST violated (no SHOULD either under --strict); 1: "
                       "violations; 2: unreadable input.")
    p.add_argument("file", metavar="FILE", help="the capture (MCAP, pcap, pcapng; .gz too)")
    add_monitor_options(p)
    p.add_argument("--json", metavar="OUT", help="write the result as JSON (check.schema.json)")
    p.add_argument("--html", metavar="OUT", help="write a self-contained HTML report with sequence charts")
    add_protocol_option(p)
    p.set_defaults(run=run)


def run(ns: argparse.Namespace) -> int:
    """``mcp-capture check``: the options checked, then the capture's protocol's check."""
    params_from_args(ns)  # the monitor options' errors, whatever the protocol
    check_writable(ns.json, "--json")
    check_writable(ns.html, "--html")
    return int(capture_tools(ns, ns.file).run_check(ns))


def run_check(ns: argparse.Namespace) -> int:
    """MCP's check (``captures.mcp``): the trace monitor's judgement of every datagram."""
    # imported here: mcp-capture's other subcommands, --help and --version never load the judge
    from mcp_conform.judge.judging import evidence_of, judge

    params = params_from_args(ns)
    j = judge(ns.file, params, keep=bool(ns.html))
    evidence = evidence_of(j)
    if ns.json:  # the files first: an interrupted or piped terminal report loses neither
        write_json(ns.json, j, evidence)
    if ns.html:
        from mcp_conform.reports.html import render_check

        write_output(ns.html, render_check(j, to_json(j, evidence)), "--html")
    to_terminal(lambda: print_report(j, evidence, json_path=ns.json,
                                     examples=len(j.violations) if getattr(ns, "verbose", False) else EXAMPLES))
    return j.exit_code()


# ---------------------------------------------------------------- shared descriptions
def _addr(addr: Any) -> str:
    if not addr:
        return "?"
    text = _ADDR_TEXT.get(addr)
    if text is None:
        text = f"{addr[0]}:{addr[1]}"
        if len(_ADDR_TEXT) < 4096:  # a capture's few peers (a million datagrams' evidence: issue 17)
            _ADDR_TEXT[addr] = text
    return text


_ADDR_TEXT: dict[Any, str] = {}


def describe_datagram(d: Datagram, first_ns: int | None) -> str:
    """One line: ``#12 +1.234567s 0 (127.0.0.1:7889) → 2 (127.0.0.1:7890) WP_Off #4``."""
    index, t_ns, src_addr, dst_addr, data = d[:5]
    t = (t_ns - (first_ns or t_ns)) / 1e9
    h = peek_header(data, require_preamble=False)
    if h is None:
        return f"#{index} +{t:.6f}s {_addr(src_addr)} → {_addr(dst_addr)}: {len(data)} bytes, no MCP header"
    dst, src, seq, action = h
    key = (src, src_addr, dst, dst_addr, action)
    between = _BETWEEN.get(key)  # who to whom, what: the same for many datagrams (issue 17)
    if between is None:
        between = f"{src} ({_addr(src_addr)}) → {dst} ({_addr(dst_addr)}) {action_name(action)}"
        if len(_BETWEEN) < 4096:
            _BETWEEN[key] = between
    return f"#{index} +{t:.6f}s {between} seq {seq}, {len(data)} bytes"


_BETWEEN: dict[Any, str] = {}


def _rule_text(rule: str) -> str:
    r = SPEC.rules_by_id.get(rule)
    return r.text if r else ""


def _level(v: Any) -> str:
    level = getattr(v, "level", None)
    if level:
        return str(level).upper()
    r = SPEC.rules_by_id.get(v.rule)
    return r.level if r else "?"


def _pairs(evidence: Any) -> bool:
    """Whether a violation's evidence is the monitor's ``(index, t_ns)`` pairs (ints), whose
    indexes :func:`traceio.trace.evidence_indexes` gives as their first items."""
    return type(evidence) is tuple and all(type(e) is tuple and e and type(e[0]) is int for e in evidence)


# ---------------------------------------------------------------- JSON
def _violations_json(j: Judgement, evidence: dict[int, Datagram]) -> Iterator[dict[str, Any]]:
    """Each shown violation as the JSON lists it, one at a time (a million of them stream)."""
    doc = _violation_json(j, evidence)
    for v in j.shown_violations:
        yield doc(v)


def _violation_json(j: Judgement, evidence: dict[int, Datagram]) -> Any:
    """A violation's JSON (a dict), by the function returned. What repeats from one violation
    to the next (a rule's level and text) is looked up once (issue 17: a million violations)."""
    first_ns = j.first_ns
    zero = first_ns or 0  # Judgement.rel's origin
    rules: dict[tuple[str, Any], tuple[str, str]] = {}

    def ev(v: Any) -> list[dict[str, Any]]:
        pairs = v.evidence if _pairs(getattr(v, "evidence", None)) else None
        idx = [e[0] for e in pairs] if pairs is not None else evidence_indexes(v)
        if not idx and getattr(v, "evidence", None):
            return [{"index": None, "t": None, "summary": str(x)} for x in v.evidence]
        out = []
        for i in idx:
            d = evidence.get(i)
            out.append({"index": i, "t": round((d.t_ns - zero) / 1e9, 9), "summary": describe_datagram(d, first_ns)}
                       if d is not None else {"index": i, "t": None, "summary": f"#{i}"})
        return out

    def doc(v: Any) -> dict[str, Any]:
        rule = v.rule
        got = rules.get((rule, getattr(v, "level", None)))
        if got is None:
            got = rules[rule, getattr(v, "level", None)] = (_level(v), _rule_text(rule))
        return {"rule": rule, "level": got[0], "node": v.node, "t": round((v.t_ns - zero) / 1e9, 9),
                "t_ns": v.t_ns, "text": got[1], "expected": _str(v.expected),
                "actual": _str(v.actual), "evidence": ev(v)}

    return doc


def _violation_lines(j: Judgement, evidence: dict[int, Datagram]) -> Iterator[str]:
    """Each shown violation's line of ``--json``: ``json.JSONEncoder().encode`` of its
    :func:`_violation_json`, byte for byte. A violation of the monitor's plain types (int
    node and times, str texts, ``(index, t_ns)`` evidence: every one the monitor makes) is
    written from its parts as the encoder writes them (ints and floats by ``repr``, strings
    by ``encode_basestring_ascii``, ``", "`` and ``": "``) without its dict; any other
    through the dict and the encoder (a million violations: issue 17)."""
    doc = _violation_json(j, evidence)
    dumps = _one_line()
    text = json.encoder.encode_basestring_ascii
    first_ns = j.first_ns
    zero = first_ns or 0
    heads: dict[tuple[str, Any], tuple[str, str]] = {}
    said_before: dict[str, str] = {}
    for v in j.shown_violations:
        rule, node, t_ns, ev = v.rule, v.node, v.t_ns, getattr(v, "evidence", None)
        if type(rule) is not str or type(node) is not int or type(t_ns) is not int or type(ev) is not tuple:
            yield dumps(doc(v))
            continue
        items = []
        for e in ev:  # as _pairs has them, else the encoder's
            if type(e) is not tuple or not e or type(e[0]) is not int:
                break
            i = e[0]
            d = evidence.get(i)
            if d is None:
                items.append(f'{{"index": {i}, "t": null, "summary": "#{i}"}}')
                continue
            t = round((d.t_ns - zero) / 1e9, 9)
            if type(t) is not float or t - t != 0.0:  # not a finite float: the encoder's words
                break
            items.append(f'{{"index": {i}, "t": {t!r}, "summary": {text(describe_datagram(d, first_ns))}}}')
        else:
            t = round((t_ns - zero) / 1e9, 9)
            if t - t == 0.0:
                head = heads.get((rule, getattr(v, "level", None)))
                if head is None:
                    level, about = _level(v), _rule_text(rule)
                    head = heads[rule, getattr(v, "level", None)] = (
                        f'{{"rule": {text(rule)}, "level": {text(level)}, "node": ',
                        f', "text": {text(about)}, "expected": ')
                expected, actual = v.expected, v.actual
                said = said_before.get(expected) if type(expected) is str else None
                if said is None:
                    said = "null" if expected is None else text(str(expected))
                    if type(expected) is str and len(said_before) < 4096:  # a rule's expectation repeats
                        said_before[expected] = said
                yield (f'{head[0]}{node}, "t": {t!r}, "t_ns": {t_ns}{head[1]}{said}, "actual": '
                       f'{"null" if actual is None else text(str(actual))}, "evidence": [{", ".join(items)}]}}')
                continue
        yield dumps(doc(v))


def to_json(j: Judgement, evidence: dict[int, Datagram], *, violations: bool = True) -> dict[str, Any]:
    """The ``--json`` document (``check.schema.json``, ``captures.check_doc``) of MCP's judgement;
    ``violations=False`` leaves the list empty (:func:`write_json` streams it into the file)."""
    v = of_judgement(j)
    duration = (j.last_ns - j.first_ns) / 1e9 if j.first_ns is not None and j.last_ns is not None else 0.0
    segments = {"segments": [_segment_json(name, s, j.params.select) for name, s in j.segments.items()]} \
        if j.segments else {}
    return document(v, SPEC, {"path": j.path, "format": j.format, "truncated": j.truncated, "notes": list(j.notes),
                              "datagrams": j.datagrams, "unattributed": j.unattributed,
                              "duration_s": round(duration, 9)},
                    {**j.params.to_json(), **({"rto_declared": True} if j.params.rto_declared else {})},
                    [n.to_json() for n in j.nodes.values()],
                    list(_violations_json(j, evidence)) if violations else [], segments)


def write_json(path: str, j: Judgement, evidence: dict[int, Datagram]) -> None:
    """Write :func:`to_json`'s document, indented as ``json.dumps(doc, indent=2)`` would but for
    the violations, one per line, streamed: memory stays that of one violation's JSON, not the
    whole document's (a capture with a million violations makes a document of hundreds of MB),
    and each line is written by the C encoder (``indent`` takes the pure-Python one: half the
    time of checking a million violations went to indenting them)."""
    head = json.dumps(to_json(j, evidence, violations=False), indent=2)
    marker = '\n  "violations": [],\n'
    before, after = head.split(marker, 1)  # the key is unique at the top level (indent 2)
    try:
        with open_output(path) as f:
            f.write(before + '\n  "violations": [')
            first = True
            lines: list[str] = []  # written a thousand at a time
            for line in _violation_lines(j, evidence):
                lines.append(("\n    " if first else ",\n    ") + line)
                first = False
                if len(lines) == 1000:
                    f.write("".join(lines))
                    lines.clear()
            f.write("".join(lines))
            f.write(("\n  ],\n" if not first else "],\n") + after + "\n")
    except OSError as exc:
        raise UsageError(f"--json: cannot write {path!r}: {exc.strerror or exc}") from None


def _one_line() -> Any:
    """``json.JSONEncoder().encode`` of a violation's JSON: the same C encoder, with the same
    settings, made once rather than once per violation (a million violations: issue 17). No
    circular check: a violation's JSON is strings, numbers and lists and dicts of them."""
    default = json.JSONEncoder()
    make = getattr(json.encoder, "c_make_encoder", None)
    if make is None or not default.ensure_ascii:
        return default.encode
    encode = make(None, default.default, json.encoder.encode_basestring_ascii, None, default.key_separator,
                  default.item_separator, default.sort_keys, default.skipkeys, default.allow_nan)
    return lambda doc: "".join(encode(doc, 0))


def _segment_json(name: str, s: Judgement, select: tuple[str, ...]) -> dict[str, Any]:
    """One worker's session of a merged capture, as its own monitor judged it."""
    node = None
    if s.vehicle_drone is not None:
        node = {"id": s.vehicle_drone}
        for n in s.nodes.values():
            if n.id == s.vehicle_drone:
                node["addresses"] = n.to_json()["addresses"]
    return {"name": name, "datagrams": s.datagrams, "node": node, "nodes": [n.to_json() for n in s.nodes.values()],
            "violations": len([v for v in s.violations if selected(v.rule, select)]),
            "rules": {str(n): {r: v for r, v in sorted(t.items()) if selected(r, select)}
                      for n, t in sorted(s.verdicts.items())}}


def _str(value: Any) -> str | None:
    return None if value is None else str(value)


# ---------------------------------------------------------------- terminal
def _violation_text(j: Judgement, v: Any, evidence: dict[int, Datagram]) -> str:
    """One violation as the terminal shows it: when and who, expected, actual, evidence."""
    lines = [f"  node {v.node} at +{j.rel(v.t_ns):.6f} s"]
    if v.expected is not None:
        lines.append(f"    expected: {v.expected}")
    if v.actual is not None:
        lines.append(f"    actual:   {v.actual}")
    for i in evidence_indexes(v):
        lines.append(f"    evidence: {describe_datagram(evidence[i], j.first_ns) if i in evidence else f'#{i}'}")
    return "\n".join(lines)


def print_report(j: Judgement, evidence: dict[int, Datagram], console: Console | None = None, *,
                 examples: int = EXAMPLES, json_path: str | None = None) -> None:
    """The terminal report: nodes, the violations summarised per rule (the count and the first
    ``examples`` in full; ``--json`` has every one), the rules table and the verdict. Its
    size is bounded by the rules and nodes, not by the violations: a capture with a million
    of them prints in the time of a few."""
    con = console or Console(highlight=False)
    span = (j.last_ns - j.first_ns) / 1e9 if j.first_ns is not None and j.last_ns is not None else 0.0
    con.print(f"[bold]mcp-capture check[/bold] {escape(j.path)} · {j.format} · {j.datagrams} datagram(s) "
              f"over {span:.3f} s · MCP spec {SPEC.version}", soft_wrap=True)
    if j.truncated:
        con.print(f"[yellow]truncated:[/yellow] {escape(j.truncated)}; judged what was read", soft_wrap=True)
    for note in j.notes:
        con.print(f"[dim]note: {escape(note)}[/dim]", soft_wrap=True)
    if j.params.challenge_note:
        con.print(escape(j.params.challenge_note), soft_wrap=True)
    for name, s in j.segments.items():
        bad = len([v for v in s.violations if selected(v.rule, j.params.select)])
        con.print(f"session {escape(name)}: {s.datagrams} datagram(s), node under test "
                  f"{s.vehicle_drone if s.vehicle_drone is not None else '?'}, {bad} violation(s)", soft_wrap=True)
    nodes = Table(title="Nodes", title_justify="left", show_edge=False)
    for col in ("ID", "role", "addresses", "sent", "received"):
        nodes.add_column(col, justify="right" if col in ("ID", "sent", "received") else "left")
    listed = list(j.nodes.values())
    for n in listed[:NODE_ROWS]:
        nodes.add_row(str(n.id), n.role, n.address_text(), str(n.sent), str(n.received))
    if len(listed) > NODE_ROWS:
        nodes.add_row("…", f"{len(listed) - NODE_ROWS} more", "(--json lists them all)", "", "")
    if j.unattributed:
        nodes.add_row("-", "no MCP header", "", str(j.unattributed), "")
    con.print(nodes)
    shown = j.shown_violations
    con.print(f"\n[bold]Violations[/bold] ({len(shown)})" if shown else "\n[green]No violations.[/green]")
    by_rule: dict[str, list[Any]] = {}
    for v in shown:
        by_rule.setdefault(v.rule, []).append(v)
    for rule, vs in by_rule.items():  # per rule: its count, the first examples, how many more
        con.print(f"[bold red]{rule}[/bold red] ({_level(vs[0])}): {escape(_rule_text(rule))}", soft_wrap=True)
        if len(vs) > examples:
            con.print(f"  {len(vs)} violations of {rule}; the first {examples}:", soft_wrap=True)
        for v in vs[:examples]:
            con.print(_violation_text(j, v, evidence), soft_wrap=True, markup=False)
        if len(vs) > examples:
            where = f"; all of them in {json_path}" if json_path else "; --json OUT lists them all"
            con.print(f"  … and {len(vs) - examples} more{escape(where)}", soft_wrap=True)
    con.print(rules_table(j))
    failing = j.failing()
    verdict = "[bold red]FAILED[/bold red]" if failing else "[bold green]OK[/bold green]"
    incomplete = ""
    if j.truncated:  # never a plain "OK" over a cut or corrupt file (issue 19 item 8)
        verdict = "[bold red]FAILED[/bold red]" if failing else "[bold yellow]INCOMPLETE[/bold yellow]"
        incomplete = f" in what was read of {j.datagrams} datagram(s) (see 'truncated:' above)"
    con.print(f"{verdict}: {len(shown)} violation(s){incomplete}, {len(failing)} counting against the exit code"
              f"{' (--strict)' if j.params.strict else ''}", soft_wrap=True)


def rules_table(j: Judgement) -> Table:
    """Verdicts per rule and node; beyond ``NODE_COLUMNS`` nodes, those with a failed or warned
    verdict first (the violations column counts every node's)."""
    nodes = sorted(j.verdicts)
    more = 0
    if len(nodes) > NODE_COLUMNS:
        def clean(n: int) -> bool:
            return not any(v in ("failed", "warned") for r, v in j.verdicts[n].items() if selected(r, j.params.select))
        more = len(nodes) - NODE_COLUMNS
        nodes = sorted(sorted(nodes, key=lambda n: (clean(n), n))[:NODE_COLUMNS])
    t = Table(title="Rules", title_justify="left", show_edge=False,
              caption=f"{more} more node(s) not shown (--json has every node's verdicts)" if more else None)
    t.add_column("rule")
    t.add_column("level")
    for n in nodes:
        t.add_column(f"node {n}")
    t.add_column("violations", justify="right")
    counts: dict[str, int] = {}
    for v in j.shown_violations:
        counts[v.rule] = counts.get(v.rule, 0) + 1
    for rule in rule_order(j):
        r = SPEC.rules_by_id.get(rule)
        cells = []
        for n in nodes:
            verdict = j.verdicts[n].get(rule)
            cells.append(f"[{VERDICT_STYLES.get(verdict, '')}]{verdict}[/]" if verdict else "")
        t.add_row(rule, r.level if r else "?", *cells, str(counts.get(rule, 0) or ""))
    return t


def rule_order(j: Judgement) -> list[str]:
    """The selected rules the monitor gave a verdict on, in the spec's order."""
    seen = {r for by_rule in j.verdicts.values() for r in by_rule} | {v.rule for v in j.violations}
    order = [r.id for r in SPEC.rules if r.id in seen]
    order += sorted(seen - set(order))
    return [r for r in order if selected(r, j.params.select)]

"""What the runner prints while it works and at the end (rich): each case's line, the rule
table, root failures before their consequences, and the summary."""

from __future__ import annotations

import contextlib
import errno
import os
import sys
from typing import Any

from rich.console import Console
from rich.markup import escape
from rich.table import Table
from rich.text import Text

from mcp_conform.conformance.report import (
    CONSEQUENCE,
    OUTCOMES,
    STYLES,
    CaseRecord,
    RunRecord,
    consequences_of,
    monitor_failures,
    roots_first,
    rule_outcomes,
    spec_of,
)
from mcp_conform.spec import RULES
from mcp_conform.spec.about import TOOL_NAME, tool_version

__all__ = ["TerminalReport", "node_lines"]


def node_lines(node: dict[str, Any] | None) -> list[str]:
    """A spawn failure's details as indented lines: command, exit, stdout, stderr."""
    if not node:
        return []
    import shlex

    lines = [f"    command: {shlex.join(str(w) for w in node.get('command') or [])}"]
    if node.get("exit"):
        lines.append(f"    the node {node['exit']}")
    for stream in ("stdout", "stderr"):
        tail = node.get(stream) or []
        lines.append(f"    {stream}:" + ("" if tail else " (nothing)"))
        lines += [f"      {ln}" for ln in tail]
    return lines


class TerminalReport:
    """The live report: one line per case, details on failures, a per-rule table at the end."""

    def __init__(self, console: Console | None = None, before_line: Any = None) -> None:
        self.console = console or Console(highlight=False)
        self._before_line = before_line  # e.g. pytest's terminal reporter's ensure_newline
        self.closed = False  # stdout went away (``mcp-conform | head -3``): the run goes on
        self.console.on_broken_pipe = self._stdout_closed  # type: ignore[method-assign]  # rich would exit

    def _print(self, *objs: Any, **kw: Any) -> None:
        if self.closed:
            return
        try:
            if self._before_line is not None:
                self._before_line()
            self.console.print(*objs, highlight=False, **kw)
        except (BrokenPipeError, ValueError):
            self._stdout_closed()
        except OSError as exc:
            if exc.errno not in (errno.EPIPE, errno.EBADF):
                raise
            self._stdout_closed()

    def _stdout_closed(self) -> None:
        """The reader of stdout left: stay quiet from now on (the report files are still
        written); stdout is pointed at /dev/null so nothing else fails on it at exit."""
        self.closed = True
        with contextlib.suppress(OSError, ValueError, AttributeError):
            devnull = os.open(os.devnull, os.O_WRONLY)
            os.dup2(devnull, sys.stdout.fileno())
            os.close(devnull)

    def header(self, run: RunRecord, mode: str | None = None) -> None:
        what = f"{run.role} at {run.target}" if run.target else run.role
        extra = f" ({mode})" if mode else ""
        sp = spec_of(run.role)
        self._print(f"[bold]{TOOL_NAME}[/bold] {tool_version()} · {sp.protocol['short_name']} spec {sp.version} · "
                    f"testing {escape(what)}{escape(extra)}", soft_wrap=True)

    def case(self, c: CaseRecord) -> None:
        style = STYLES.get(c.outcome, "")
        line = Text()
        line.append(f"{c.outcome.upper():<8}", style=style)
        line.append(f" {c.id}  ")
        line.append(" ".join(c.rules), style="dim")
        line.append(f"  {c.duration_s:.2f} s", style="dim")
        self._print(line, soft_wrap=True)
        if c.consequence_of:
            self._detail(f"consequence of {', '.join(c.consequence_of)} (failed earlier in this run)")
        if c.failed_rule:
            rule = RULES.get(c.failed_rule)
            self._detail(f"{c.failed_rule} ({rule.level if rule else '?'}): {rule.text if rule else ''}")
            if c.expected is not None:
                self._detail(f"expected: {c.expected}")
            if c.actual is not None:
                self._detail(f"actual:   {c.actual}")
            for e in c.evidence:
                self._detail(f"evidence: {e}")
            notes = [n for n in c.notes if c.actual is None or n not in c.actual]
        else:
            if c.reason and c.outcome in ("skipped", "error"):
                self._detail(c.reason)
            for e in c.evidence:
                self._detail(f"evidence: {e}")
            notes = c.notes
        for n in notes:
            self._detail(f"note: {n}")
        if c.baseline:
            self._detail(f"baseline: {c.baseline}" + ("  (now passes: take it off the baseline)"
                                                      if c.outcome == "xpassed" else ""))

    def _failures(self, run: RunRecord, monitor: list[dict[str, Any]]) -> None:
        """Root failures first (what to fix), then the failures that are their consequences:
        the cases', and the violations the run's trace monitor proved after a root failed
        (the rule table's ``consequence`` rows)."""
        bad = [c for c in roots_first(run.cases) if c.failed_rule]
        roots = [c for c in bad if not c.consequence_of]
        consequences: list[Any] = [c for c in bad if c.consequence_of]
        consequences += [f for f in monitor if f["consequence_of"]]
        for title, group in ((f"root failures ({len(roots)}):", roots),
                             (f"their consequences ({len(consequences)}):", consequences)):
            if not group:
                continue
            self._print(Text(title, style="bold"), soft_wrap=True)
            for c in group:
                line = Text("  ")
                if isinstance(c, dict):  # the monitor's
                    n = c["violations"]
                    line.append(f"{c['outcome'].upper():<7}", style=STYLES.get(c["outcome"], ""))
                    line.append(f" {c['rule']}  monitor  ")
                    line.append(f"consequence of {', '.join(c['consequence_of'])} ({n} violation{'s' if n != 1 else ''} "
                                f"in the run's traffic; first: {c['actual']})", style="dim")
                    self._print(line, soft_wrap=True)
                    continue
                line.append(f"{c.outcome.upper():<7}", style=STYLES.get(c.outcome, ""))
                line.append(f" {c.failed_rule}  {c.id}  ")
                tag = (f"consequence of {', '.join(c.consequence_of)}" if c.consequence_of
                       else (c.actual or ""))
                line.append(tag, style="dim")
                self._print(line, soft_wrap=True)

    def _detail(self, text: str) -> None:
        self._print(Text("    " + text.replace("\n", "\n    "), style="dim"), soft_wrap=True)

    def note(self, text: str) -> None:
        """A dim line of what the runner is doing (e.g. before a long startup phase)."""
        self._print(Text(text, style="dim"), soft_wrap=True)

    def error(self, message: str, node: dict[str, Any] | None = None, detail: list[str] | None = None) -> None:
        """Errors go to stderr (a CI log or ``2>`` keeps them apart from the report); ``detail``
        says what the runner observed (a node that never announced), a spawn failure quotes
        the node's own words."""
        err = Console(stderr=True, highlight=False, no_color=self.console.no_color)
        with contextlib.suppress(OSError, ValueError):
            if self._before_line is not None:
                self._before_line()
            err.print(Text(f"error: {message}", style="bold red"), soft_wrap=True, highlight=False)
            for line in [f"    {ln}" for ln in detail or []] + node_lines(node):
                err.print(Text(line, style="dim"), soft_wrap=True, highlight=False)

    def listing(self, entries: list[tuple[str, tuple[str, ...], str, str]]) -> None:
        """``--list``: (case id, rules, level, phase) per case."""
        for cid, ids, level, phase in entries:
            phase_s = f"  ({phase})" if phase != "main" else ""
            self._print(f"{escape(cid)}  {' '.join(ids)}  {level}{phase_s}", soft_wrap=True)
        self._print(f"{len(entries)} cases", soft_wrap=True)

    def summary(self, run: RunRecord) -> None:
        if run.error is not None and not run.cases:  # a usage or setup error: its one line
            self.error(run.error, run.node, run.error_detail)
            return
        monitor = monitor_failures(run)
        outcomes = rule_outcomes(run.cases, run.role, monitor)
        if run.cases:
            table = Table(title="per-rule outcome", show_lines=False, box=None, pad_edge=False)
            table.add_column("rule")
            table.add_column("level")
            table.add_column("outcome")
            touched = ({r for c in run.cases for r in c.rules} | {c.failed_rule for c in run.cases}
                       | {f["rule"] for f in monitor})
            untouched = [rid for rid in outcomes if rid not in touched]
            roots = consequences_of(monitor)
            for rid, outcome in outcomes.items():
                if rid in untouched:
                    continue
                rule = RULES.get(rid)
                shown = f"see {', '.join(roots.get(rid, ()))}" if outcome == CONSEQUENCE else outcome
                table.add_row(rid, rule.level if rule else "?", Text(shown, style=STYLES.get(outcome, "")))
            self._print(table)
            if untouched:
                self._print(Text(f"{len(untouched)} other rule(s) of the {run.role} role: skipped "
                                 f"(no case of this run): {' '.join(untouched)}", style="dim"), soft_wrap=True)
        self._failures(run, monitor)
        for f in monitor:  # proved by the run's trace monitor, failed by no case (a root's consequence: above)
            if f["consequence_of"]:
                continue
            n = f["violations"]
            self._print(Text.assemble((f"monitor: {f['rule']} {f['outcome']}", STYLES[f["outcome"]]),
                                      f" ({n} violation{'s' if n != 1 else ''} in the run's traffic; "
                                      f"first: {f['actual']})"), soft_wrap=True)
        counts = run.counts()
        parts = [Text(f"{counts[k]} {k}", style=STYLES[k] if counts[k] else "dim") for k in OUTCOMES
                 if counts[k] or k not in ("xfailed", "xpassed")]
        own = [f for f in monitor if not f["consequence_of"]]
        if own:
            failed = sum(f["outcome"] == "failed" for f in own)
            parts.append(Text(f"{failed} failed, {len(own) - failed} warned by the monitor",
                              style=STYLES["failed" if failed else "warned"]))
        line = Text(", ").join(parts)
        self._print(line, soft_wrap=True)
        if run.error is not None:
            self.error(run.error, run.node, run.error_detail)
        self._print(f"suite finished in {run.duration_s:.1f} s", soft_wrap=True)

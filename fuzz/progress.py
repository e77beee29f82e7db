"""Live progress (rich) while a campaign runs, and its one summary line at the end.

On a terminal: cases, judged cases/s, findings, restarts, elapsed, refreshed a few times a
second. When stdout is not a terminal (a CI log), the same figures as a plain line every
``STATUS_S`` seconds, then the findings, one line each, and the summary line.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TypeVar

from fuzz.campaign import Progress
from fuzz.config import FuzzConfig
from fuzz.environment import environment_lines
from fuzz.findings import FindingStore

__all__ = ["STATUS_S", "LiveDisplay", "LiveProgress", "figures_line", "figures_text", "status_line",
           "summary_line"]

STATUS_S = 10.0  # off a terminal: a plain status line this often
_Display = TypeVar("_Display", bound="LiveDisplay")


def summary_line(summary: dict[str, Any]) -> str:
    by_rule = ", ".join(f"{r} x{n}" for r, n in summary["findings_by_rule"].items()) or "none"
    return (f"mcp-fuzz: {summary['cases']} cases in {summary['duration_s']:.1f} s "
            f"({summary['judged_cases_per_s']:.0f} judged cases/s), {summary['findings']} finding(s): "
            f"{by_rule}; seed {summary['seed']}, {summary['restarts']} restart(s)"
            + _reasons(summary.get("restarts_by_reason") or {}))


def budget_line(summary: dict[str, Any]) -> str:
    """Where the time went: triage's share, the --duration bound and its grace (issue 36)."""
    limit = summary.get("duration_limit_s")
    bound = f"--duration {limit:g} s + grace {summary.get('grace_s', 0):g} s" if limit is not None else "no --duration"
    left = f"; {summary['untriaged']} flaw(s) left untriaged at the deadline" if summary.get("untriaged") else ""
    return (f"mcp-fuzz: triage {summary.get('triage_s', 0):g} s of {summary['duration_s']:.1f} s "
            f"({100 * summary.get('triage_share', 0):.0f} %); {bound}{left}")


def _reasons(by_reason: dict[str, int]) -> str:
    """Why the node was restarted, as the summary line's tail (issue 18 item 9)."""
    return f" ({'; '.join(f'{n} {why}' for why, n in by_reason.items())})" if by_reason else ""


def figures_line(label: str, elapsed: float, cases: int, rate: float, findings: str, restarts: int) -> str:
    """A campaign's live figures as one plain line (a CI log's progress), whatever its
    protocol: ``label`` its engine (and protocol), ``findings`` their count (and classes)."""
    return (f"mcp-fuzz: {elapsed:,.0f} s  {label}  cases {cases:,}  {rate:,.0f} judged cases/s  "
            f"findings {findings}  restarts {restarts}")


def figures_text(label: str, elapsed: float, cases: int, rate: float, findings: str, found: bool,
                 restarts: int) -> Any:
    """The same figures as the terminal panel's first line (rich)."""
    from rich.text import Text

    return Text.assemble(
        ("mcp-fuzz ", "bold"), (f"{label}  ", "cyan"), f"cases {cases:,}  ",
        (f"{rate:,.0f} judged cases/s  ", "green"), (f"findings {findings}  ", "red" if found else ""),
        f"restarts {restarts}  ", f"elapsed {elapsed:,.1f} s")


def status_line(engine: str, p: Progress) -> str:
    """MCP's live figures as one plain line."""
    return figures_line(engine, p.elapsed, p.cases, p.judged_rate, str(p.findings), p.restarts)


class LiveDisplay:
    """A rich Live panel on a terminal; a plain status line every ``STATUS_S`` (or ``every``,
    ``mcp-fuzz --status-every``) otherwise: the display both campaigns share (MCP's :class:`LiveProgress`, Nsqd's
    ``fuzz.stream_progress.StreamLive``), each giving its ``first`` panel, ``render`` and
    ``status`` line of what it is shown."""

    def __init__(self, stream: Any = None, every: float | None = None, quiet: bool = False) -> None:
        self.stream = stream or sys.stdout
        self.quiet = quiet  # ``mcp-fuzz -q``: neither the panel nor the status lines
        self.tty = not quiet and bool(getattr(self.stream, "isatty", lambda: False)())
        self._live: Any = None
        self.every = float("inf") if quiet else STATUS_S if every is None else every  # ``--status-every``
        self._next_status = time.monotonic() + self.every

    def __enter__(self: _Display) -> _Display:
        if self.tty:
            from rich.console import Console
            from rich.live import Live

            self._live = Live(self.first(), console=Console(file=self.stream),
                              refresh_per_second=4, transient=True)
            self._live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)
            self._live = None

    def first(self) -> Any:
        """The panel before the first update."""
        raise NotImplementedError

    def render(self, view: Any) -> Any:
        """The panel of ``view`` (a rich renderable)."""
        raise NotImplementedError

    def status(self, view: Any) -> str:
        """``view`` as one plain line."""
        raise NotImplementedError

    def update(self, view: Any) -> None:
        if self._live is not None:
            self._live.update(self.render(view))
        elif time.monotonic() >= self._next_status:
            self._next_status = time.monotonic() + self.every
            print(self.status(view), file=self.stream, flush=True)


class LiveProgress(LiveDisplay):
    """MCP's campaign: cases, judged cases/s, findings, restarts, elapsed, one line."""

    def __init__(self, cfg: FuzzConfig, stream: Any = None, every: float | None = None, quiet: bool = False,
                 verbose: bool = False) -> None:
        super().__init__(stream, every, quiet)
        self.cfg, self.verbose = cfg, verbose

    def first(self) -> Any:
        return self.render(Progress())

    def render(self, p: Progress) -> Any:
        return figures_text(p.engine or self.cfg.engine, p.elapsed, p.cases, p.judged_rate, str(p.findings),
                            bool(p.findings), p.restarts)

    def status(self, p: Progress) -> str:
        return status_line(p.engine or self.cfg.engine, p)

    def final(self, summary: dict[str, Any], store: FindingStore) -> None:
        out = self.stream
        if summary.get("timing"):
            print(f"mcp-fuzz: {summary['timing']}", file=out)
        for n, f in enumerate(store.order, 1):
            print(f"  finding-{n}: {f.describe()}", file=out)
            if self.verbose:
                print(f"    expected: {f.expected}\n    actual: {f.actual}", file=out)
        for line in environment_lines(summary) if not self.quiet else ():
            print(line, file=out)
        print(summary_line(summary), file=out)
        print(budget_line(summary), file=out)

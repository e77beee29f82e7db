"""Live progress (rich) while a campaign runs, whatever its protocol, and its one summary
line at the end (issue 37: one progress layer for MCP and Nsqd).

On a terminal: cases, judged cases/s (triage's replays excluded), findings (by class when
the protocol's findings have one: Nsqd's oracle), restarts, elapsed, refreshed a few times
a second, and, when the campaign counts them, a small table of which message ids x mutation
kinds have been sent. When stdout is not a terminal (a CI log), the same figures as a plain
line every ``STATUS_S`` seconds, then the findings, one line each, and the summary line.
Every campaign hands the display a :class:`Progress` (its ``--jobs`` parent, the workers'
summed: ``fuzz.workers.run_jobs``).
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcp_conform.fuzz.config import EXIT_INTERRUPTED, FuzzConfig
from mcp_conform.fuzz.environment import environment_lines
from mcp_conform.fuzz.findings import FindingStore
from mcp_conform.spec.profiles import pick

__all__ = ["STATUS_S", "LiveProgress", "Progress", "figures_line", "interrupted", "status_line", "summary_line",
           "tried_table"]

STATUS_S = 10.0  # off a terminal: a plain status line this often
_OTHER = ("unknown", "-")  # an id that names no message; bytes with no id at all


@dataclass
class Progress:
    """What the live display shows (summed over workers)."""

    cases: int = 0
    findings: int = 0
    restarts: int = 0
    fuzz_seconds: float = 0.0
    started: float = field(default_factory=time.monotonic)
    engine: str = ""
    #: the findings by class (Nsqd: the oracle), when the protocol's findings have one
    classes: dict[str, int] = field(default_factory=dict)
    #: mutation kind -> message name -> cases sent, when the campaign counts them
    tried: dict[str, dict[str, int]] = field(default_factory=dict)
    #: ``--jobs``: the workers, and how many of them have judged a case (0: one process)
    workers: int = 0
    workers_judging: int = 0

    @property
    def elapsed(self) -> float:
        return time.monotonic() - self.started

    @property
    def judged_rate(self) -> float:
        """Judged cases per second of fuzzing (triage's replays excluded)."""
        return self.cases / self.fuzz_seconds if self.fuzz_seconds > 0 else 0.0

    def found(self) -> str:
        """The findings' count, and their classes when known."""
        if not self.classes:
            return str(self.findings)
        return f"{self.findings} ({', '.join(f'{k} {n}' for k, n in sorted(self.classes.items()))})"


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


def interrupted(cases: int, findings: int, out: str | Path | None) -> int:
    """SIGINT ended the campaign: its one line (stderr), where its summary is; the exit code."""
    where = f"; summary in {str(Path(out) / 'summary.json')!r}" if out else ""
    print(f"mcp-fuzz: interrupted after {cases} cases, {findings} finding(s){where}", file=sys.stderr)
    return EXIT_INTERRUPTED


def _reasons(by_reason: dict[str, int]) -> str:
    """Why the node was restarted, as the summary line's tail (issue 18 item 9)."""
    return f" ({'; '.join(f'{n} {why}' for why, n in by_reason.items())})" if by_reason else ""


def figures_line(label: str, elapsed: float, cases: int, rate: float, findings: str, restarts: int,
                 workers: str = "") -> str:
    """A campaign's live figures as one plain line (a CI log's progress), whatever its
    protocol: ``label`` its engine (and protocol), ``findings`` their count (and classes),
    ``workers`` (``--jobs``) how many workers have judged a case of how many."""
    return (f"mcp-fuzz: {elapsed:,.0f} s  {label}  cases {cases:,}  {rate:,.0f} judged cases/s  "
            f"findings {findings}  restarts {restarts}" + (f"  workers judging {workers}" if workers else ""))


def status_line(label: str, p: Progress) -> str:
    """The live figures as one plain line."""
    workers = f"{p.workers_judging}/{p.workers}" if p.workers else ""
    return figures_line(label, p.elapsed, p.cases, p.judged_rate, p.found(), p.restarts, workers)


def tried_table(tried: dict[str, dict[str, int]], messages: Any,
                ) -> tuple[list[str], list[tuple[str, list[int]]]]:
    """Columns (the protocol's ``messages``' ids as numbers, then ``?`` unknown and ``-``
    none) and a row per mutation kind: the cases sent with each."""
    names = [m.name for m in messages]
    cols = [str(m.id) for m in messages] + ["?", "-"]
    keys = names + list(_OTHER)
    rows = [(kind, [row.get(k, 0) for k in keys]) for kind, row in sorted(tried.items())]
    return cols, rows


def _cell(n: int) -> str:
    return "·" if n == 0 else str(n) if n < 1000 else f"{n // 1000}k"


class LiveProgress:
    """A rich Live panel on a terminal; a plain status line every ``STATUS_S`` (or ``every``,
    ``mcp-fuzz --status-every``) otherwise; the campaign's ``cfg`` names its engine and its
    protocol (the label's first word, the messages of the table)."""

    def __init__(self, cfg: FuzzConfig, stream: Any = None, every: float | None = None, quiet: bool = False,
                 verbose: bool = False) -> None:
        self.cfg, self.verbose = cfg, verbose
        self.profile = pick(cfg.protocol, cfg.role)[0]
        self.stream = stream or sys.stdout
        self.quiet = quiet  # ``mcp-fuzz -q``: neither the panel nor the status lines
        self.tty = not quiet and bool(getattr(self.stream, "isatty", lambda: False)())
        self._live: Any = None
        self.every = float("inf") if quiet else STATUS_S if every is None else every  # ``--status-every``
        self._next_status = time.monotonic() + self.every

    def __enter__(self) -> LiveProgress:
        if self.tty:
            from rich.console import Console
            from rich.live import Live

            self._live = Live(self.render(Progress()), console=Console(file=self.stream),
                              refresh_per_second=4, transient=True)
            self._live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)
            self._live = None

    def label(self, p: Progress) -> str:
        """The protocol and the engine running (``mcp stateful``, ``nsqd both``)."""
        return f"{self.profile.name} {p.engine or self.cfg.engine}"

    def render(self, p: Progress) -> Any:
        """The panel: the figures, and the table of kinds x message ids when counted."""
        from rich.text import Text

        line = Text.assemble(
            ("mcp-fuzz ", "bold"), (f"{self.label(p)}  ", "cyan"), f"cases {p.cases:,}  ",
            (f"{p.judged_rate:,.0f} judged cases/s  ", "green"),
            (f"findings {p.found()}  ", "red" if p.findings else ""), f"restarts {p.restarts}  ",
            f"elapsed {p.elapsed:,.1f} s")
        if not p.tried:
            return line
        from rich.console import Group
        from rich.table import Table

        cols, rows = tried_table(p.tried, getattr(self.profile.spec, "messages", ()))  # a stream spec's
        table = Table(title="cases sent: mutation kind x message id", title_justify="left", box=None,
                      padding=(0, 1), show_edge=False)
        table.add_column("kind", no_wrap=True)
        for c in cols:
            table.add_column(c, justify="right", no_wrap=True)
        for kind, counts in rows:
            table.add_row(kind, *(_cell(n) for n in counts))
        return Group(line, table)

    def status(self, p: Progress) -> str:
        return status_line(self.label(p), p)

    def update(self, p: Progress) -> None:
        if self._live is not None:
            self._live.update(self.render(p))
        elif time.monotonic() >= self._next_status:
            self._next_status = time.monotonic() + self.every
            print(self.status(p), file=self.stream, flush=True)

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

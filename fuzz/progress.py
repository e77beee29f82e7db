"""Live progress (rich) while a campaign runs, and its one summary line at the end.

On a terminal: cases, judged cases/s, findings, restarts, elapsed, refreshed a few times a
second. When stdout is not a terminal (a CI log), the same figures as a plain line every
``STATUS_S`` seconds, then the findings, one line each, and the summary line.
"""

from __future__ import annotations

import sys
import time
from typing import Any

from fuzz.campaign import Progress
from fuzz.config import FuzzConfig
from fuzz.findings import FindingStore

__all__ = ["STATUS_S", "LiveProgress", "status_line", "summary_line"]

STATUS_S = 10.0  # off a terminal: a plain status line this often


def summary_line(summary: dict[str, Any]) -> str:
    by_rule = ", ".join(f"{r} x{n}" for r, n in summary["findings_by_rule"].items()) or "none"
    return (f"mcp-fuzz: {summary['cases']} cases in {summary['duration_s']:.1f} s "
            f"({summary['judged_cases_per_s']:.0f} judged cases/s), {summary['findings']} finding(s): "
            f"{by_rule}; seed {summary['seed']}, {summary['restarts']} restart(s)"
            + _reasons(summary.get("restarts_by_reason") or {}))


def _reasons(by_reason: dict[str, int]) -> str:
    """Why the node was restarted, as the summary line's tail (issue 18 item 9)."""
    return f" ({'; '.join(f'{n} {why}' for why, n in by_reason.items())})" if by_reason else ""


def status_line(engine: str, p: Progress) -> str:
    """The live figures as one plain line (a CI log's progress)."""
    return (f"mcp-fuzz: {p.elapsed:,.0f} s  {engine}  cases {p.cases:,}  "
            f"{p.judged_rate:,.0f} judged cases/s  findings {p.findings}  restarts {p.restarts}")


class LiveProgress:
    """A rich Live line on a terminal; a plain status line every ``STATUS_S`` otherwise."""

    def __init__(self, cfg: FuzzConfig, stream: Any = None) -> None:
        self.cfg = cfg
        self.stream = stream or sys.stdout
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._live: Any = None
        self._last: Progress | None = None
        self._next_status = time.monotonic() + STATUS_S

    def __enter__(self) -> LiveProgress:
        if self.tty:
            from rich.console import Console
            from rich.live import Live

            self._live = Live(self._render(Progress()), console=Console(file=self.stream),
                              refresh_per_second=4, transient=True)
            self._live.__enter__()
        return self

    def __exit__(self, *exc: object) -> None:
        if self._live is not None:
            self._live.__exit__(*exc)
            self._live = None

    def _render(self, p: Progress) -> Any:
        from rich.text import Text

        return Text.assemble(
            ("mcp-fuzz ", "bold"), (f"{p.engine or self.cfg.engine}  ", "cyan"),
            f"cases {p.cases:,}  ", (f"{p.judged_rate:,.0f} judged cases/s  ", "green"),
            (f"findings {p.findings}  ", "red" if p.findings else ""),
            f"restarts {p.restarts}  ", f"elapsed {p.elapsed:,.1f} s")

    def update(self, p: Progress) -> None:
        self._last = p
        if self._live is not None:
            self._live.update(self._render(p))
        elif time.monotonic() >= self._next_status:
            self._next_status = time.monotonic() + STATUS_S
            print(status_line(p.engine or self.cfg.engine, p), file=self.stream, flush=True)

    def final(self, summary: dict[str, Any], store: FindingStore) -> None:
        out = self.stream
        if summary.get("timing"):
            print(f"mcp-fuzz: {summary['timing']}", file=out)
        for n, f in enumerate(store.order, 1):
            print(f"  finding-{n}: {f.describe()}", file=out)
        print(summary_line(summary), file=out)

"""Live progress of ``mcp-fuzz --protocol nsqd`` (issue 21 item 5), as ``fuzz.progress`` is
for MCP.

On a terminal (rich): cases, judged cases/s (triage's replays excluded), findings by class
(the oracle: crash, sanitizer, hang, close, protocol, desync, effect, leak), restarts,
elapsed, and a small table of which message ids x mutation kinds have been sent, refreshed a
few times a second. Off a terminal (a CI log): the same figures as one plain line every
``STATUS_S`` seconds. At the end, the findings one line each and the summary line.
"""

from __future__ import annotations

import time
from typing import Any

from fuzz.progress import STATUS_S, LiveDisplay, figures_line, figures_text
from spec import NSQD
from spec.profiles import NSQD_PROFILE

__all__ = ["STATUS_S", "StreamLive", "by_class", "status_line", "tried_table"]

_OTHER = ("unknown", "-")  # an id that names no message; bytes with no id at all


def by_class(findings: list[Any]) -> dict[str, int]:
    out: dict[str, int] = {}
    for f in findings:
        out[f.signature.oracle] = out.get(f.signature.oracle, 0) + 1
    return out


def _classes(view: Any) -> str:
    return ", ".join(f"{k} {n}" for k, n in sorted(by_class(view.findings).items())) or "none"


def _figures(view: Any) -> tuple[str, float, int, float, str]:
    rate = view.cases / view.fuzz_s if view.fuzz_s > 0 else 0.0
    return (f"{NSQD_PROFILE.name} {view.engine}", time.monotonic() - view.started, view.cases, rate,
            f"{len(view.findings)} ({_classes(view)})")


def status_line(view: Any) -> str:
    """The live figures as one plain line (a CI log's progress: ``fuzz.progress.figures_line``)."""
    return figures_line(*_figures(view), view.restarts)


def tried_table(tried: dict[str, dict[str, int]]) -> tuple[list[str], list[tuple[str, list[int]]]]:
    """Columns (message ids as numbers, then ``?`` unknown and ``-`` none) and a row per
    mutation kind: the cases sent with each."""
    names = [m.name for m in NSQD.messages]
    cols = [str(m.id) for m in NSQD.messages] + ["?", "-"]
    keys = names + list(_OTHER)
    rows = [(kind, [row.get(k, 0) for k in keys]) for kind, row in sorted(tried.items())]
    return cols, rows


def _cell(n: int) -> str:
    return "·" if n == 0 else str(n) if n < 1000 else f"{n // 1000}k"


class StreamLive(LiveDisplay):
    """Nsqd's campaign: the status line, and on a terminal a table of kinds x message ids."""

    def first(self) -> Any:
        from rich.text import Text

        return Text(f"mcp-fuzz {NSQD_PROFILE.name}: starting")

    def status(self, view: Any) -> str:
        return status_line(view)

    def render(self, view: Any) -> Any:
        from rich.console import Group
        from rich.table import Table

        line = figures_text(*_figures(view), bool(view.findings), view.restarts)
        cols, rows = tried_table(view.tried)
        table = Table(title="cases sent: mutation kind x message id", title_justify="left", box=None,
                      padding=(0, 1), show_edge=False)
        table.add_column("kind", no_wrap=True)
        for c in cols:
            table.add_column(c, justify="right", no_wrap=True)
        for kind, counts in rows:
            table.add_row(kind, *(_cell(n) for n in counts))
        return Group(line, table)

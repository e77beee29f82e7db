"""Zeller's delta debugging, the one minimiser of every protocol's findings (issue 21;
issue 37): MCP's datagrams (``fuzz.triage``), Nsqd's frames, writes and suspects
(``fuzz.nsqd_triage``) and a stateful program's moves (``fuzz.nsqd_stateful``)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

__all__ = ["ddmin"]


def ddmin(items: list[Any], test: Callable[[list[Any]], bool], budget: int, singles: int = 0) -> list[Any]:
    """The shortest subsequence of ``items`` that ``test`` still holds for, by Zeller's ddmin
    (complements of ever smaller chunks), within ``budget`` tests. ``singles``: first try up
    to that many items alone, the last first (the likeliest culprits, and the usual minimal
    reproducer of a datagram campaign)."""
    items = list(items)
    spent = 0
    if len(items) > 1:
        for item in reversed(items[-singles:] if singles else []):
            spent += 1
            if test([item]):
                return [item]
    n = 2
    while len(items) >= 2 and spent < budget:
        chunk = max(1, len(items) // n)
        reduced = False
        for i in range(0, len(items), chunk):
            rest = items[:i] + items[i + chunk:]
            spent += 1
            if rest and test(rest):
                items, n, reduced = rest, max(n - 1, 2), True
                break
            if spent >= budget:
                break
        if not reduced:
            if n >= len(items):
                break
            n = min(len(items), n * 2)
    return items

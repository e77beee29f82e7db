"""Zeller's delta debugging, for minimising a finding's input (issue 21: frames, bytes, a
stateful program's moves)."""

from __future__ import annotations

from typing import Any

__all__ = ["ddmin"]


def ddmin(items: list[Any], test: Any, budget: int) -> list[Any]:
    """Zeller's delta debugging, bounded by ``budget`` tests."""
    n, spent = 2, 0
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

"""Flaws that depend on the environment, named as such in both protocols' summaries (issue 36
item 3: "a real DUP-1 finding replays N of N and an environment-dependent one is named as
such").

A flaw that triage reproduced at least once but that a confirming replay then did not show
is not a finding (a finding replays N of N), yet it is not lost among the unconfirmed either:
it is recorded here by rule and shape (MCP: ``fuzz.triage``; Nsqd: its signature,
``fuzz.nsqd_triage``) with how often it was seen and why it is not a finding, and listed in
``summary.json`` (``environment_dependent``) and after the findings on the campaign's last
lines. Workers' records are merged by rule and shape.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

__all__ = ["EnvironmentLog", "environment_lines", "merge_environment"]


class EnvironmentLog:
    """One worker's environment-dependent flaws, by (rule, shape)."""

    def __init__(self) -> None:
        self.by_key: dict[tuple[str, str], dict[str, Any]] = {}

    def note(self, rule: str, shape: str, actual: str, seen: int, tries: int, why: str) -> None:
        """A flaw of ``rule`` and ``shape`` that reproduced ``seen`` of ``tries`` replays."""
        e = self.by_key.setdefault((rule, shape), {"rule": rule, "shape": shape, "actual": actual, "times": 0})
        e["times"] += 1
        e["why"] = f"reproduced {seen} of {tries} replays: {why}"

    def add(self, entry: dict[str, Any]) -> None:
        """Another worker's (or engine's) entry: its times added to this one's of the same key."""
        e = self.by_key.setdefault((entry["rule"], entry["shape"]), {**entry, "times": 0})
        e["times"] += entry["times"]

    def values(self) -> list[dict[str, Any]]:
        return [dict(e) for e in self.by_key.values()]


def merge_environment(entries: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    """Entries of several workers or engines, one per (rule, shape), their times summed."""
    log = EnvironmentLog()
    for e in entries:
        log.add(e)
    return log.values()


def environment_lines(summary: dict[str, Any]) -> list[str]:
    """The summary's environment-dependent flaws, a line each, for the campaign's last lines."""
    return [f"  environment-dependent (not a finding): {e['rule']} ({e['shape']}) x{e['times']}: {e['why']}"
            for e in summary.get("environment_dependent", [])]

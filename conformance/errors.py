"""Outcomes a conformance case can end with, other than passing.

A case sends, then calls one verify helper; the helper raises one of these. Each carries
the rule ID it judges, so reports speak the catalogue's language (MCP-ACK-1 ...).
A timeout is an observation (what was *not* seen is the ``actual``), never an exception
of its own.
"""

from __future__ import annotations

from dataclasses import dataclass, field


@dataclass
class CaseFailure(AssertionError):
    """The node departed from ``rule``: ``expected`` vs ``actual``, with evidence."""

    rule: str
    expected: str
    actual: str
    evidence: list[str] = field(default_factory=list)

    def __post_init__(self) -> None:
        AssertionError.__init__(self, self.describe())

    def describe(self) -> str:
        from spec import SPEC

        text = SPEC.rule(self.rule).text if self.rule in SPEC.rules_by_id else ""
        lines = [f"{self.rule}: {text}", f"  expected: {self.expected}", f"  actual:   {self.actual}"]
        lines += [f"  evidence: {e}" for e in self.evidence]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.describe()


class Inconclusive(Exception):
    """The case could not observe what it claims: it is SKIPPED with this reason."""


class SetupError(Exception):
    """The run cannot start (node never answered, port in use, spawn failed): exit 2."""


class TargetLost(Exception):
    """In attach mode the node died or went silent: the remaining cases are errors."""

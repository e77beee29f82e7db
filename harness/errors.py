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
    #: Rules whose conformance this observation relied on (None: the spec's ``depends_on``
    #: rules of ``rule``; () when the failure stands on its own, e.g. the node died). If one
    #: of them failed earlier in the run, this failure is reported as its consequence.
    relies_on: tuple[str, ...] | None = None

    def dependencies(self) -> tuple[str, ...]:
        if self.relies_on is not None:
            return self.relies_on
        from mcp_conform.spec import RULES

        rule = RULES.get(self.rule)
        return rule.rule_dependencies if rule is not None else ()

    def __post_init__(self) -> None:
        AssertionError.__init__(self, self.describe())

    def describe(self) -> str:
        from mcp_conform.spec import RULES

        text = RULES[self.rule].text if self.rule in RULES else ""
        lines = [f"{self.rule}: {text}", f"  expected: {self.expected}", f"  actual:   {self.actual}"]
        lines += [f"  evidence: {e}" for e in self.evidence]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.describe()


class Inconclusive(Exception):
    """The case could not observe what it claims: it is SKIPPED with this reason."""


class SetupError(Exception):
    """The run cannot start (node never answered, port in use, spawn failed): exit 2.
    ``detail``: what the runner observed that explains it, a few lines (a node that never
    announced: ``harness.startup_report``); the message itself stays one line."""

    detail: list[str]

    def __init__(self, *args: object, detail: list[str] | None = None) -> None:
        super().__init__(*args)
        self.detail = list(detail or [])


class TargetLost(Exception):
    """In attach mode the node died or went silent: the remaining cases are errors."""


class NodeLost(TargetLost):
    """The node stopped answering the runner's liveness probes (or its process exited)
    while a case was running: the case is an ``error``, never a verdict on a rule.
    ``evidence`` is the last exchange (what the node last said, what went unanswered);
    ``exchange`` is the unanswered exchange in progress, when there was one."""

    def __init__(self, reason: str, evidence: list[str] | None = None, *, process_exited: bool = False) -> None:
        super().__init__(reason)
        self.reason = reason
        self.evidence = list(evidence or [])
        self.process_exited = process_exited
        self.exchange: object | None = None


class SilenceUnproven(TargetLost):
    """A case that passes on "no reply" found the node not live right after its window:
    silence from a node that cannot be shown alive proves nothing (an ``error``)."""

    def __init__(self, reason: str, evidence: list[str] | None = None) -> None:
        super().__init__(reason)
        self.reason = reason
        self.evidence = list(evidence or [])


class SpawnFailure(SetupError):
    """The spawned node failed to start or exited during startup. ``node`` holds its own
    words for the reports: ``command`` (as run), ``exit``, ``stdout`` and ``stderr`` tails."""

    def __init__(self, message: str, node: dict[str, object], detail: list[str] | None = None) -> None:
        super().__init__(message, detail=detail)
        self.node = node

"""The one verdict interface of the monitors -- MCP's judgement of a capture (``judge.judging``),
the MAVLink trace monitor (``judge.mavlink_monitor``) and Nsqd's (``judge.nsqd_monitor``) -- that
``mcp-capture check`` writes its one document from (``captures/check.schema.json``): a thin
adapter, read after the monitor has judged; what each monitor decides is its own.

:class:`Verdicts`: the rules' verdicts (MCP's per node, as its monitor gives them; MAVLink's
and Nsqd's one per rule over the whole capture), the violations found (:class:`Found` for the
monitors whose violations are not MCP's), how many each rule broke, per level, those that count
against the exit code (a MUST broken; a SHOULD too under ``--strict``), the exit code and the
verdict (FAILED, else INCOMPLETE for a capture cut short, else OK). ``--select``/``--exclude``
pick the rules each adapter reads (``select``: ``judge.params.Params.select``'s prefixes,
``!PREFIX`` left out; a protocol's rules matched with or without its ``prefix``).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

__all__ = ["Found", "Verdicts", "of_judgement", "of_mavlink", "of_nsqd", "picked"]


class Found(NamedTuple):
    """One violation as the document lists it, whatever monitor found it: the node that broke
    the rule (None: the monitor does not say which), when, what was expected and what came,
    the evidence lines, the frames (their indexes in the capture) and what else the protocol
    says of it (``more``: MAVLink's role, Nsqd's connection)."""

    rule: str
    node: int | str | None
    t_ns: int
    expected: str | None
    actual: str | None
    evidence: tuple[str, ...] = ()
    frames: tuple[int, ...] = ()
    more: tuple[tuple[str, Any], ...] = ()


@dataclass
class Verdicts:
    """A capture's judgement as every monitor gives it (see the module docstring)."""

    protocol: str
    #: the document's ``rules``: node -> rule -> verdict (MCP), rule -> verdict (one per rule)
    rules: dict[str, Any]
    #: the violations (MCP's own, else :class:`Found`), in the monitor's order
    found: Sequence[Any]
    levels: Counter[str]  # violations found per level (MUST, SHOULD, INFO)
    failing: int  # violations that count against the exit code
    truncated: str | None = None
    #: rule -> violations of it found, where the monitor keeps fewer than it counts (MAVLink, Nsqd)
    counts: dict[str, int] = field(default_factory=dict)
    #: how many violations were found (``found`` and those only counted)
    total: int = 0

    @property
    def exit_code(self) -> int:
        return 1 if self.failing else 0

    @property
    def verdict(self) -> str:
        return "FAILED" if self.failing else ("INCOMPLETE" if self.truncated else "OK")

    def verdict_counts(self) -> dict[str, int]:
        """How many verdicts of each kind the rules got (each node's, for MCP)."""
        counts: dict[str, int] = {}
        for v in self.rules.values():
            for verdict in (v.values() if isinstance(v, dict) else (v,)):
                counts[verdict] = counts.get(verdict, 0) + 1
        return counts


def picked(rule: str, select: Iterable[str], prefix: str = "") -> bool:
    """``--select``/``--exclude`` (``select``: prefixes, ``!PREFIX`` left out) of the rule's ID,
    with or without the protocol's ``prefix`` of its rules (``MAV-CMD``, ``CMD-1``, ``CMD``)."""
    names = (rule, rule.removeprefix(prefix))
    chosen = [s for s in select if not s.startswith("!")]
    left_out = [s[1:] for s in select if s.startswith("!")]
    return ((not chosen or any(n.startswith(c) for n in names for c in chosen))
            and not any(n.startswith(x) for n in names for x in left_out))


def _per_rule(protocol: str, spec: Any, verdicts: dict[str, str], counts: dict[str, int], found: list[Found],
              strict: bool, truncated: str | None) -> Verdicts:
    """The verdicts of a monitor that gives one per rule over the whole capture."""
    levels: Counter[str] = Counter()
    failing = 0
    for rule, n in counts.items():
        level = spec.rule(rule).level
        levels[level] += n
        if verdicts[rule] == "failed" or (strict and verdicts[rule] == "warned"):
            failing += n
    return Verdicts(protocol, verdicts, found, levels, failing, truncated, {r: n for r, n in counts.items() if n},
                    sum(counts.values()))


def of_mavlink(mon: Any, select: Iterable[str] = (), *, strict: bool = False,
               truncated: str | None = None) -> Verdicts:
    """A ``MavlinkMonitor``'s judgement (after ``finish``), its rules picked by ``select``."""
    from mcp_conform.judge.mavlink_monitor import RULES

    select = tuple(select)
    rules = [r for r in RULES if picked(r, select, "MAV-")]
    verdicts = mon.verdicts()
    found = [Found(v.rule, v.node, v.t_ns, v.expected, v.actual, tuple(v.evidence), tuple(v.frames),
                   (("role", v.role),)) for v in mon.violations if v.rule in rules]
    return _per_rule("mavlink", mon.spec, {r: verdicts[r] for r in rules}, {r: mon.failed_count[r] for r in rules},
                     found, strict, truncated)


def of_nsqd(mon: Any, select: Iterable[str] = (), *, strict: bool = False,
            truncated: str | None = None) -> Verdicts:
    """A ``StreamMonitor``'s judgement (every connection judged as it stands: the capture's
    end), its rules picked by ``select``; a violation's node is its connection's backend (the
    monitor knows connections, not addresses: None) and ``conn`` its connection."""
    select = tuple(select)
    verdicts = mon.verdicts()
    rules = [r for r in verdicts if picked(r, select, "NSQD-")]
    found = []
    for r in rules:
        for c in verdicts[r][1]:
            v, t_ns = c.violation
            found.append(Found(r, None, t_ns, v.expected, v.actual, tuple(v.evidence), (), (("conn", c.conn),)))
    return _per_rule("nsqd", mon.spec, {r: verdicts[r][0] for r in rules}, {r: verdicts[r][2] for r in rules},
                     found, strict, truncated)


def of_judgement(j: Any) -> Verdicts:
    """MCP's judgement of a capture (``judge.judging.Judgement``): each node's verdicts of the
    rules its ``--select`` keeps, its violations and their levels."""
    from mcp_conform.judge.params import selected
    from mcp_conform.spec import SPEC

    select = j.params.select
    rules = {str(node): {r: verdict for r, verdict in sorted(by_rule.items()) if selected(r, select)}
             for node, by_rule in sorted(j.verdicts.items())}
    shown = j.shown_violations
    levels: Counter[str] = Counter()
    for (rule, level), n in Counter((v.rule, getattr(v, "level", None)) for v in shown).items():
        r = SPEC.rules_by_id.get(rule)
        levels[str(level).upper() if level else (r.level if r else "?")] += n  # per rule and level: few kinds
    return Verdicts("mcp", rules, shown, levels, len(j.failing()), j.truncated, total=len(shown))

"""Marking conformance cases with the rules they verify, and reading those marks back.

A case is a pytest test decorated with :func:`rules`::

    from mcp_conform.conformance.marks import rules

    @rules("MCP-ACK-4")
    def test_broadcast_is_not_acked(node):
        node.expect_silence([node.send(Action.WP_OFF, dst=node.broadcast_id)], "MCP-ACK-4")

The decorator applies two pytest marks, ``mcp_rules(*ids)`` and ``mcp_phase(phase)``; the
plugin orders cases by phase (``startup``, ``main``, ``late``, ``end``) and keeps file order
otherwise. Unknown rule IDs are refused when the module is imported, so a typo is a
collection error naming the ID, never a case that silently judges nothing.

The helpers below turn a collected item into what the reports speak: a short, stable case
ID (``ACK/test_broadcast_is_not_acked``), its rule IDs and its level (the strongest of its
rules: MUST > SHOULD > INFO).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable
from typing import Any, TypeVar

import pytest

from mcp_conform.spec import RULES, SPEC
from mcp_conform.spec.profiles import PROFILES

__all__ = [
    "LEVEL_ORDER",
    "PHASES",
    "UnknownRuleError",
    "case_group",
    "case_id",
    "case_level",
    "case_phase",
    "case_rules",
    "check_rule_ids",
    "is_case",
    "rule_level",
    "rules",
    "strongest_level",
]

F = TypeVar("F", bound=Callable[..., Any])

#: Phases in the order cases run: observations of the node's start, the bulk of the cases,
#: passive judgements over the whole traffic and floods, then End_Mission/RTL (always last).
PHASES: tuple[str, ...] = ("startup", "main", "late", "end")
#: Levels from the strongest down.
LEVEL_ORDER: tuple[str, ...] = ("MUST", "SHOULD", "INFO")

RULES_MARK = "mcp_rules"
PHASE_MARK = "mcp_phase"


class UnknownRuleError(ValueError):
    """A case names a rule ID the spec does not define."""


def check_rule_ids(ids: Iterable[str], where: str = "") -> tuple[str, ...]:
    """Return ``ids`` as a tuple; raise :class:`UnknownRuleError` naming the first unknown ID."""
    out = tuple(ids)
    if not out:
        raise UnknownRuleError(f"rules(){' on ' + where if where else ''}: at least one rule ID is needed")
    for rid in out:
        if not isinstance(rid, str) or rid not in RULES:
            suffix = f" (in {where})" if where else ""
            raise UnknownRuleError(f"unknown rule ID {rid!r}{suffix}: not in spec {SPEC.version}")
    return out


def rules(*ids: str, phase: str = "main") -> Callable[[F], F]:
    """Mark a case with the rule IDs it verifies and the phase it runs in."""
    if phase not in PHASES:
        raise ValueError(f"rules(): unknown phase {phase!r}; expected one of {', '.join(PHASES)}")

    from mcp_conform.conformance.plugin import activate

    activate()  # a module of cases is being collected: the runner (and its fixtures) is needed

    def decorate(fn: F) -> F:
        where = f"{getattr(fn, '__module__', '?')}.{getattr(fn, '__qualname__', '?')}"
        checked = check_rule_ids(ids, where)
        fn = pytest.mark.mcp_rules(*checked)(fn)
        for rid in checked:  # one marker per rule, for `pytest -m mcp_ack_1`
            fn = getattr(pytest.mark, rule_marker(rid))(fn)
        return pytest.mark.mcp_phase(phase)(fn)

    return decorate


def rule_marker(rule_id: str) -> str:
    """The pytest marker name of a rule: MCP-ACK-1 -> mcp_ack_1 (select with ``-m``)."""
    return rule_id.lower().replace("-", "_")


# ---------------------------------------------------------------------- reading marks back
def is_case(item: Any) -> bool:
    """True for a collected item that carries an ``mcp_rules`` mark."""
    get = getattr(item, "get_closest_marker", None)
    return get is not None and get(RULES_MARK) is not None


def case_rules(item: Any) -> tuple[str, ...]:
    """Every rule ID the item's ``mcp_rules`` marks name, in order, without repeats."""
    seen: dict[str, None] = {}
    for mark in item.iter_markers(RULES_MARK):
        for rid in mark.args:
            seen.setdefault(str(rid), None)
    return tuple(seen)


def case_phase(item: Any) -> str:
    """The item's phase (``main`` when unmarked)."""
    mark = item.get_closest_marker(PHASE_MARK)
    if mark is None:
        return "main"
    phase = mark.args[0] if mark.args else mark.kwargs.get("phase", "main")
    return phase if phase in PHASES else "main"


def rule_level(rule_id: str) -> str:
    """The level of a rule (MUST when the spec does not know it: the cautious reading)."""
    rule = RULES.get(rule_id)
    return rule.level if rule is not None else "MUST"


def strongest_level(rule_ids: Iterable[str]) -> str:
    """MUST > SHOULD > INFO over ``rule_ids`` (INFO for none)."""
    levels = {rule_level(r) for r in rule_ids}
    for level in LEVEL_ORDER:
        if level in levels:
            return level
    return "INFO"


def case_level(item: Any) -> str:
    return strongest_level(case_rules(item))


def case_group(item: Any) -> str:
    """The rule group a case belongs to: its module's (``test_ack`` -> ACK) when that is a
    group of the spec, else the group of its first rule."""
    module = getattr(getattr(item, "module", None), "__name__", "") or ""
    base = module.rsplit(".", 1)[-1]
    if base.startswith("test_") and any(base[5:].upper() in p.spec.groups for p in PROFILES.values()):
        return base[5:].upper()
    ids = case_rules(item)
    if ids and ids[0].count("-") >= 2:
        return ids[0].split("-")[1]
    return base.removeprefix("test_").upper() or "CASE"


def case_id(item: Any) -> str:
    """Short and stable: ``GROUP/test_function`` (with pytest's ``[param]`` suffix, if any)."""
    return f"{case_group(item)}/{item.name}"

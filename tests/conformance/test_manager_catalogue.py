"""The manager-role case catalogue against the spec: every MUST rule a Mission Manager can
be held to (roles manager and any) has a manager-role case; every rule ID a case names
exists; one module per rule group. (A case that can only skip, for a rule not observable
on a manager, counts: it reports the spec's reason.)"""

from __future__ import annotations

import mcp_conform.conformance.cases_manager  # noqa: F401  (the attribute the next line's name reaches)
from mcp_conform import conformance
from mcp_conform.spec import SPEC

from .test_case_catalogue import _cases as _collect


def _cases() -> dict[str, tuple[str, ...]]:
    return _collect(conformance.cases_manager)


def test_every_named_rule_exists_and_applies_to_a_manager():
    for case, ids in _cases().items():
        for rid in ids:
            assert rid in SPEC.rules_by_id, f"{case} names unknown rule {rid}"
            assert SPEC.rule(rid).applies_to("manager"), f"{case} names drone-only rule {rid}"


def test_every_manager_must_rule_has_a_case():
    named = {r for ids in _cases().values() for r in ids}
    must = {r.id for r in SPEC.rules_for("manager") if r.level == "MUST"}
    assert must and must - named == set()


def test_every_manager_rule_has_a_case():
    named = {r for ids in _cases().values() for r in ids}
    assert {r.id for r in SPEC.rules_for("manager")} - named == set()


def test_one_module_per_rule_group():
    for case, ids in _cases().items():
        module_group = case.split(".")[0].removeprefix("test_").upper()
        assert module_group in SPEC.groups, case
        assert any(r.split("-")[1] == module_group for r in ids), f"{case} is in the wrong module"


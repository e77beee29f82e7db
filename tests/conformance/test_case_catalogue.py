"""The case catalogue against the spec: every MUST rule a drone can be held to has a case,
and every rule ID a case names exists. (A case that can only skip, for a rule a drone never
exercises as sender, counts: it reports the spec's reason.)"""

from __future__ import annotations

import importlib
import pkgutil

import mcp_conform.conformance.cases  # noqa: F401  (the attribute the next line's name reaches)
from mcp_conform import conformance
from mcp_conform.spec import SPEC


def _cases(package: object = conformance.cases) -> dict[str, tuple[str, ...]]:
    """Case name -> the rule IDs it names, for every case of ``package``."""
    out = {}
    pkg_name = package.__name__  # type: ignore[attr-defined]
    for info in pkgutil.iter_modules(package.__path__):  # type: ignore[attr-defined]
        if not info.name.startswith("test_"):
            continue
        mod = importlib.import_module(f"{pkg_name}.{info.name}")
        for name, fn in vars(mod).items():
            if name.startswith("test_") and callable(fn):
                marks = [m for m in getattr(fn, "pytestmark", []) if m.name == "mcp_rules"]
                assert marks, f"{info.name}.{name} names no rule"
                out[f"{info.name}.{name}"] = tuple(r for m in marks for r in m.args)
    return out


def test_every_named_rule_exists():
    for case, ids in _cases().items():
        for rid in ids:
            assert rid in SPEC.rules_by_id, f"{case} names unknown rule {rid}"


def test_every_drone_must_rule_has_a_case():
    named = {r for ids in _cases().values() for r in ids}
    must = {r.id for r in SPEC.rules_for("drone") if r.level == "MUST"}
    assert must - named == set()


def test_every_drone_rule_has_a_case():
    named = {r for ids in _cases().values() for r in ids}
    assert {r.id for r in SPEC.rules_for("drone")} - named == set()


def test_one_module_per_rule_group():
    for case, ids in _cases().items():
        module_group = case.split(".")[0].removeprefix("test_").upper()
        assert module_group in SPEC.groups, case
        assert any(r.split("-")[1] == module_group for r in ids), f"{case} is in the wrong module"

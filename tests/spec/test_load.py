"""spec._load: the packaged spec holds the catalogue's 55 rules; broken specs fail naming the key."""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest
import yaml

from mcp_conform import spec
from mcp_conform.spec import SPEC, SpecError, load
from mcp_conform.spec._load import SPEC_PATH

# The catalogue (MCP-REQUIREMENTS.md), copied here by hand so that an edit of mcp.yaml that
# drops, renames or re-levels a rule fails this test: ID, level, roles.
CATALOGUE = """
MCP-HDR-1 MUST any
MCP-HDR-2 MUST any
MCP-HDR-3 MUST any
MCP-HDR-4 MUST any
MCP-HDR-5 MUST any
MCP-ACK-1 MUST any
MCP-ACK-2 MUST any
MCP-ACK-3 MUST any
MCP-ACK-4 MUST any
MCP-ACK-5 MUST any
MCP-ACK-6 MUST any
MCP-ACK-7 SHOULD any
MCP-SEQ-1 MUST any
MCP-SEQ-2 MUST any
MCP-SEQ-3 MUST any
MCP-SEQ-4 INFO any
MCP-DUP-1 MUST any
MCP-DUP-2 MUST any
MCP-DUP-3 MUST any
MCP-DUP-4 INFO any
MCP-RTX-1 MUST any
MCP-RTX-2 MUST any
MCP-RTX-3 SHOULD any
MCP-RTX-4 SHOULD any
MCP-BLK-1 MUST any
MCP-BLK-2 MUST manager
MCP-BLK-3 MUST manager
MCP-BLK-4 MUST drone
MCP-BLK-5 MUST drone
MCP-BLK-6 MUST manager
MCP-BLK-7 SHOULD drone
MCP-PAY-1 MUST any
MCP-PAY-2 MUST drone
MCP-PAY-3 MUST manager
MCP-PAY-4 MUST any
MCP-PAY-5 MUST manager
MCP-PAY-6 MUST any
MCP-PAY-7 SHOULD manager
MCP-PAY-8 SHOULD drone
MCP-ROB-1 MUST any
MCP-ROB-2 MUST any
MCP-ROB-3 MUST any
MCP-ROB-4 SHOULD any
MCP-ROB-5 MUST any
MCP-ROB-6 MUST any
MCP-ROB-7 SHOULD any
MCP-FLOW-1 MUST drone
MCP-FLOW-2 MUST manager
MCP-FLOW-3 MUST manager
MCP-FLOW-4 MUST manager
MCP-FLOW-5 MUST manager
MCP-FLOW-6 MUST manager
MCP-FLOW-7 INFO manager
MCP-TRN-1 INFO any
MCP-TRN-2 MUST any
"""
EXPECTED = [tuple(line.split()) for line in CATALOGUE.strip().splitlines()]


def test_catalogue_table_is_54_rules() -> None:
    assert len(EXPECTED) == 55 == len({e[0] for e in EXPECTED})


def test_spec_holds_exactly_the_catalogue_in_order() -> None:
    got = [(r.id, r.level, ",".join(r.roles)) for r in SPEC.rules]
    assert got == EXPECTED


def test_rule_lookup_and_roles() -> None:
    assert SPEC.rule("MCP-ACK-4").level == "MUST"
    drone = {r.id for r in SPEC.rules_for("drone")}
    manager = {r.id for r in SPEC.rules_for("manager")}
    assert "MCP-BLK-4" in drone and "MCP-BLK-4" not in manager
    assert "MCP-BLK-2" in manager and "MCP-BLK-2" not in drone
    for rule in SPEC.rules:
        assert rule.text and rule.source
        for role, obs in rule.observe.items():
            assert obs.observable in ("mcp", "vehicle", "none"), (rule.id, role)
            assert obs.side in ("sender", "receiver"), (rule.id, role)
            if obs.observable == "none":
                assert obs.reason, f"{rule.id} ({role}) is unobservable without a reason"


def test_constants_and_parameters() -> None:
    assert SPEC.preamble == b"NCSU-CM\x01\x01"
    assert SPEC.protocol["manager_id"] == 0 and SPEC.protocol["broadcast_id"] == 0xFFFF
    assert sorted(SPEC.protocol["ports"].values()) == [7889, 7890]
    assert SPEC.params["timeout_s"] == 5.0 and SPEC.params["retries"] == 1000
    assert SPEC.params["ack_deadline_s"] == 0.1
    assert [a.code for a in SPEC.actions if a.on_wire] == list(range(9))
    assert spec.load().sha256 == SPEC.sha256


# ---------------------------------------------------------------- broken specs
def _raw() -> dict[str, Any]:
    return yaml.safe_load(SPEC_PATH.read_text(encoding="utf-8"))


def _bad_level(raw: dict[str, Any]) -> None:
    raw["rules"][3]["level"] = "MAY"


def _missing_key(raw: dict[str, Any]) -> None:
    del raw["rules"][5]["text"]


def _missing_top_key(raw: dict[str, Any]) -> None:
    del raw["header"]


def _duplicate_id(raw: dict[str, Any]) -> None:
    raw["rules"][1]["id"] = raw["rules"][0]["id"]


def _wrong_struct_size(raw: dict[str, Any]) -> None:
    raw["header"]["size"] = 18


def _wrong_item_struct(raw: dict[str, Any]) -> None:
    raw["mission_item"]["struct"] = "<ffffffHHBBBBB"  # the description's 33-byte string (E-1)


def _unknown_depends_on(raw: dict[str, Any]) -> None:
    raw["rules"][0]["depends_on"] = ["D-99"]


def _unknown_rule_dependency(raw: dict[str, Any]) -> None:
    raw["rules"][0]["depends_on"] = ["MCP-ACK-99"]


def _bad_preamble(raw: dict[str, Any]) -> None:
    raw["header"]["preamble_hex"] = "4E4353552D434D0102"


@pytest.mark.parametrize(("mutate", "names"), [
    (_bad_level, ["rules[3].level", "MAY"]),
    (_missing_key, ["rules[5]", "text"]),
    (_missing_top_key, ["header"]),
    (_duplicate_id, ["rules[1].id", "duplicate"]),
    (_wrong_struct_size, ["header.size", "17"]),
    (_wrong_item_struct, ["mission_item"]),
    (_unknown_depends_on, ["rules[0].depends_on", "D-99"]),
    (_unknown_rule_dependency, ["rules[0].depends_on", "MCP-ACK-99"]),
    (_bad_preamble, ["header.preamble_hex"]),
], ids=lambda v: getattr(v, "__name__", "")[1:] if callable(v) else "")
def test_broken_spec_names_the_key(tmp_path: Path, mutate: Any, names: list[str]) -> None:
    raw = copy.deepcopy(_raw())
    mutate(raw)
    path = tmp_path / "broken.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
    with pytest.raises(SpecError) as info:
        load(path)
    msg = str(info.value)
    assert "\n" not in msg and str(path) in msg
    for name in names:
        assert name in msg, msg


def test_unreadable_and_unparsable_specs(tmp_path: Path) -> None:
    with pytest.raises(SpecError, match="cannot read"):
        load(tmp_path / "absent.yaml")
    bad = tmp_path / "bad.yaml"
    bad.write_text("rules: [\n", encoding="utf-8")
    with pytest.raises(SpecError, match="not valid YAML"):
        load(bad)


def _load_in_a_process(cache: Path, path: Path | None = None) -> dict[str, Any]:
    code = ("import json, sys; from spec import load; s = load(sys.argv[1] if len(sys.argv) > 1 else None); "
            "print(json.dumps({'jsonschema': 'jsonschema' in sys.modules, 'sha': s.sha256, 'rules': len(s.rules)}))")
    args = [sys.executable, "-c", code] + ([str(path)] if path else [])
    done = subprocess.run(args, capture_output=True, text=True, timeout=60,
                          env={**os.environ, "MCP_CONFORM_CACHE": str(cache)})
    assert done.returncode == 0, done.stderr
    return json.loads(done.stdout)


def test_a_validated_spec_is_not_validated_again_and_a_changed_one_is(tmp_path: Path) -> None:
    """The spec is read at every process's import: a tree that validated is kept (by the
    sha256 of the spec's and the schema's bytes), so the next process neither imports nor runs
    the JSON-schema validator; a spec whose bytes changed is validated again."""
    cache = tmp_path / "cache"
    first, second = _load_in_a_process(cache), _load_in_a_process(cache)
    assert first["jsonschema"] and not second["jsonschema"]
    assert first == {**second, "jsonschema": True} and first["rules"] > 0
    # one level changed to one the schema refuses: the cached tree of the good bytes is not used
    raw = copy.deepcopy(_raw())
    _bad_level(raw)
    path = tmp_path / "broken.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
    with pytest.raises(SpecError, match=r"rules\[3\]\.level"):
        load(path)
    # a cache that cannot be written is not used: the spec still loads, validated each time
    blocked = tmp_path / "file"
    blocked.write_text("")
    assert _load_in_a_process(blocked)["jsonschema"] and _load_in_a_process(blocked)["jsonschema"]

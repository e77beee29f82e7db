"""spec/mavlink.yaml, MAVLink's microservices: the one schema takes it beside mcp.yaml and
nsqd.yaml, every rule cites its source with a URL, rule IDs are unique, well formed and
stable, every message, field, enum and entry the spec names exists in pymavlink's dialect
(checked here against the dialect module itself, not through the loader), deprecated
messages are the XML's, the issue's topics each have rules, broken files are refused with
one line naming the key, and docs/mavlink.md is current."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest
import yaml

from mcp_conform.spec import docs
from mcp_conform.spec._load import SpecError, load, read_validated
from mcp_conform.spec.mavlink import MAVLINK_PATH, deprecated_messages, load_mavlink
from mcp_conform.spec.nsqd import load_stream

PAGE = Path(__file__).resolve().parents[2] / "docs" / "mavlink.md"

#: Rule IDs once published stay (a rule is retired with ``status: retired``, never renumbered).
STABLE_IDS = (
    [f"MAV-HB-{n}" for n in range(1, 16)] + [f"MAV-CMD-{n}" for n in range(1, 19)]
    + [f"MAV-PRM-{n}" for n in range(1, 18)] + [f"MAV-MIS-{n}" for n in range(1, 28)])

#: Issue 39's topics, each by the MAVLink names some rule's refs must hold.
TOPICS = {
    "heartbeat rate": ["HEARTBEAT"],
    "type and autopilot": ["HEARTBEAT.type", "HEARTBEAT.autopilot"],
    "command answered by one COMMAND_ACK": ["COMMAND_LONG", "COMMAND_INT", "COMMAND_ACK.result"],
    "confirmation incremented": ["COMMAND_LONG.confirmation"],
    "in progress": ["MAV_RESULT_IN_PROGRESS"],
    "unsupported": ["MAV_RESULT_UNSUPPORTED"],
    "target filtering": ["COMMAND_LONG.target_system", "COMMAND_LONG.target_component"],
    "parameter list": ["PARAM_REQUEST_LIST", "PARAM_VALUE.param_count", "PARAM_VALUE.param_index"],
    "read by name and index": ["PARAM_REQUEST_READ.param_id", "PARAM_REQUEST_READ.param_index"],
    "set echoed": ["PARAM_SET", "PARAM_VALUE"],
    "types": ["MAV_PARAM_TYPE", "PARAM_VALUE.param_type"],
    "mission upload": ["MISSION_COUNT.count", "MISSION_REQUEST_INT.seq", "MISSION_ACK.type"],
    "download": ["MISSION_REQUEST_LIST"],
    "clear": ["MISSION_CLEAR_ALL.mission_type"],
    "set current": ["MISSION_SET_CURRENT.seq", "MISSION_CURRENT.seq"],
    "mission_type": ["MISSION_COUNT.mission_type", "MAV_MISSION_TYPE"],
    "out of sequence": ["MAV_MISSION_INVALID_SEQUENCE"],
    "cancel": ["MAV_MISSION_OPERATION_CANCELLED"],
    "degE7": ["MISSION_ITEM_INT.x", "MISSION_ITEM_INT.y", "COMMAND_INT.x"],
    "deprecated messages": ["MISSION_REQUEST", "MISSION_ITEM"],
}

#: A MAVLink name in a rule's text (messages, enums, entries of the microservices).
_NAME = re.compile(r"\b(?:MAV_[A-Z0-9_]+|(?:COMMAND|PARAM|MISSION)_[A-Z_]+|HEARTBEAT|STATUSTEXT)\b")


@pytest.fixture(scope="module")
def spec():
    return load_mavlink()


@pytest.fixture(scope="module")
def dialect(spec):
    return importlib.import_module(spec.raw["dialect"]["module"])


def _dialect_names(dialect):
    messages = {cls.msgname: set(cls.fieldnames) for cls in dialect.mavlink_map.values()}
    entries = {e.name for es in dialect.enums.values() for e in es.values()}
    return messages, set(dialect.enums), entries


def _exists(name, dialect):
    messages, enums, entries = _dialect_names(dialect)
    head, _, member = name.partition(".")
    if member:
        return member in messages.get(head, ())
    return head in messages or head in enums or head in entries


def test_one_schema_takes_the_three_protocols(spec):
    assert spec.protocol["transport"] == "mavlink" and spec.roles == ("vehicle", "gcs")
    assert load().short_name == "MCP" and load_stream().short_name == "NSQD"
    assert not set(spec.rules_by_id) & (set(load().rules_by_id) | set(load_stream().rules_by_id))


def test_every_microservice_has_rules_for_both_roles(spec):
    for group in ("HB", "CMD", "PRM", "MIS"):
        rules = [r for r in spec.rules if r.group == group]
        assert rules, group
        assert {role for r in rules for role in r.observe} == {"vehicle", "gcs"}, group
    assert spec.rules_for("vehicle") and spec.rules_for("gcs")


def test_rule_ids_are_well_formed_unique_and_stable(spec):
    ids = [r.id for r in spec.rules]
    assert len(ids) == len(set(ids))
    assert all(re.fullmatch(r"MAV-(HB|CMD|PRM|MIS)-[1-9][0-9]*", i) for i in ids), ids
    assert set(STABLE_IDS) <= set(ids), sorted(set(STABLE_IDS) - set(ids))
    for group in spec.groups:  # numbered 1..n in file order, no gaps
        numbers = [int(r.id.rsplit("-", 1)[1]) for r in spec.rules if r.group == group]
        assert numbers == list(range(1, len(numbers) + 1)), group


def test_every_rule_cites_a_quote_or_a_paraphrase_with_a_url(spec):
    for r in spec.rules:
        c = spec.citations[r.id]
        assert re.match(r"https://\S+$", c.url), r.id
        assert c.quotes or c.paraphrase, r.id
        assert all(len(q) >= 10 for q in c.quotes), (r.id, c.quotes)
        assert r.level in ("MUST", "SHOULD", "INFO") and r.text


def test_every_name_the_spec_uses_exists_in_the_dialect(spec, dialect):
    named = set()
    for svc in spec.raw["services"].values():
        named |= {m["name"] for m in svc["messages"]} | set(svc.get("enums", []))
    for r in spec.raw["rules"]:
        named |= set(r.get("refs", []))
        named |= set(_NAME.findall(r["text"]))
    missing = sorted(n for n in named if not _exists(n, dialect))
    assert not missing, missing
    assert len(named) > 80


def test_message_ids_and_fields_are_the_dialects(spec, dialect):
    for m in spec.messages:
        assert m.id == getattr(dialect, f"MAVLINK_MSG_ID_{m.name}")
        cls = dialect.mavlink_map[m.id]
        assert [f.name for f in m.layout.fields] == list(cls.fieldnames)
    assert spec.message("COMMAND_LONG").layout.field("confirmation").type == "uint8_t"
    assert spec.message("PARAM_VALUE").layout.field("param_id").type == "char[16]"
    assert spec.message("MISSION_ITEM_INT").layout.field("x").type == "int32_t"
    assert spec.enum_value("MAV_RESULT_UNSUPPORTED") == dialect.MAV_RESULT_UNSUPPORTED


def test_deprecated_messages_are_the_xmls(spec):
    deprecated = deprecated_messages(spec)
    assert {"MISSION_REQUEST", "MISSION_ITEM"} <= deprecated
    for m in spec.messages:
        assert m.deprecated == (m.name in deprecated), m.name


@pytest.mark.parametrize("topic", sorted(TOPICS))
def test_each_topic_of_the_issue_has_a_rule(spec, topic):
    refs = {name for names in spec.refs.values() for name in names}
    assert set(TOPICS[topic]) <= refs, sorted(set(TOPICS[topic]) - refs)


def test_depends_on_names_notes_and_rules_that_exist(spec):
    notes = {n.id for n in spec.errata + spec.decisions}
    for r in spec.rules:
        for d in r.depends_on:
            assert d in notes or d in spec.rules_by_id, (r.id, d)


def _broken(tmp_path, edit):
    raw = yaml.safe_load(MAVLINK_PATH.read_text(encoding="utf-8"))
    edit(raw)
    path = tmp_path / "mavlink.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False), encoding="utf-8")
    return path


@pytest.mark.parametrize("edit, key", [
    (lambda raw: raw["services"]["CMD"]["messages"].append({"name": "COMMAND_LONGER", "sent_by": "gcs"}),
     "services.CMD.messages[3].name"),
    (lambda raw: raw["services"]["PRM"]["enums"].append("MAV_PARAM_KIND"), "services.PRM.enums[1]"),
    (lambda raw: raw["rules"][0].update(refs=["HEARTBEAT.colour"]), "rules[0].refs"),
    (lambda raw: raw["rules"][1].update(source="the page says so"), "rules[1].source"),
    (lambda raw: raw["rules"][2].pop("url"), "rules[2]"),
    (lambda raw: raw["rules"][3].update(roles=["drone"]), "rules[3].roles"),
    (lambda raw: raw["services"].update(XYZ=raw["services"]["HB"]), "services.XYZ"),
    (lambda raw: raw.update(header={}), "(top level)"),
])
def test_broken_specs_are_refused_in_one_line_naming_the_key(tmp_path, edit, key):
    with pytest.raises(SpecError) as err:
        load_mavlink(_broken(tmp_path, edit))
    msg = str(err.value)
    assert "\n" not in msg and f": {key}" in msg, msg


def test_loaders_refuse_the_other_kinds(tmp_path):
    with pytest.raises(SpecError, match="not a MAVLink spec"):
        load_mavlink(Path(load().path))
    with pytest.raises(SpecError, match="protocol.transport"):
        load(MAVLINK_PATH)
    with pytest.raises(SpecError, match="protocol.transport"):
        load_stream(MAVLINK_PATH)
    raw, _, _ = read_validated(MAVLINK_PATH)
    assert raw["protocol"]["short_name"] == "MAV"


def test_committed_page_is_current_and_complete(spec):
    assert PAGE.is_file(), "docs/mavlink.md is missing: run spec.docs.write(load_mavlink())"
    assert docs.check(spec, PAGE), "docs/mavlink.md is stale: regenerate it with spec.docs.write"
    text = PAGE.read_text(encoding="utf-8")
    for r in spec.rules:
        assert r.id in text
        assert spec.citations[r.id].url in text
    for m in spec.messages:
        assert f"`{m.name}`" in text
    for note in spec.errata + spec.decisions:
        assert note.id in text
    assert docs.default_output(spec) == PAGE


def test_write_and_check(tmp_path, spec):
    out = docs.write(spec, tmp_path / "mavlink.md")
    assert docs.check(spec, out)
    out.write_text(out.read_text(encoding="utf-8") + "x", encoding="utf-8")
    assert not docs.check(spec, out)

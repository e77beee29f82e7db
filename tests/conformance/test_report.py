"""conformance.report: per-rule aggregation, the JSON document against its schema, JUnit, terminal."""

from __future__ import annotations

import io
import json
import xml.etree.ElementTree as ET

import jsonschema
import pytest
from rich.console import Console

from mcp_conform.conformance.junit import junit_xml
from mcp_conform.conformance.report import (
    CaseRecord,
    RunRecord,
    build_json,
    load_schema,
    rule_outcomes,
    validate_json,
    write_json,
)
from mcp_conform.conformance.terminal import TerminalReport
from mcp_conform.spec import SPEC


def case(cid: str, rules: tuple[str, ...], outcome: str, **kw) -> CaseRecord:
    return CaseRecord(id=cid, rules=rules, level=kw.pop("level", "MUST"), outcome=outcome, **kw)


def sample_run() -> RunRecord:
    run = RunRecord(role="drone", target="127.0.0.1:7890", parameters={"rto": 0.2}, seed=7)
    run.cases = [
        case("ACK/test_a", ("MCP-ACK-1",), "passed", duration_s=0.5, start_ns=10, end_ns=20),
        case("ACK/test_b", ("MCP-ACK-4", "MCP-ACK-5"), "failed", failed_rule="MCP-ACK-4",
             expected="no ACK", actual="an ACK", reason="MCP-ACK-4: ...", evidence=["seq 3"]),
        case("ACK/test_c", ("MCP-ACK-7",), "warned", level="SHOULD", failed_rule="MCP-ACK-7",
             expected="median < 0.1 s", actual="0.3 s"),
        case("BLK/test_d", ("MCP-BLK-2",), "skipped", reason="not observable"),
        case("SEQ/test_e", ("MCP-SEQ-4",), "info", level="INFO", actual="initial seq 5", notes=["initial seq 5"]),
        case("ROB/test_f", ("MCP-ROB-1",), "error", reason="RuntimeError: boom"),
    ]
    run.finished = run.started + 1.25
    return run


def test_rule_outcomes_contributions_and_aggregation():
    run = sample_run()
    rules = rule_outcomes(run.cases, "drone")
    assert set(rules) >= {r.id for r in SPEC.rules_for("drone")}
    assert rules["MCP-ACK-1"] == "passed"
    assert rules["MCP-ACK-4"] == "failed"
    assert rules["MCP-ACK-5"] == "skipped"  # a CaseFailure contributes to its own rule only
    assert rules["MCP-ACK-7"] == "warned"
    assert rules["MCP-BLK-2"] == "skipped"
    assert rules["MCP-SEQ-4"] == "info"
    assert rules["MCP-ROB-1"] == "skipped"  # an error judged nothing
    assert rules["MCP-DUP-1"] == "skipped"  # untouched


@pytest.mark.parametrize(("outcomes", "expected"), [
    (("passed", "failed"), "failed"),
    (("warned", "passed"), "warned"),
    (("skipped", "passed"), "passed"),
    (("skipped", "skipped"), "skipped"),
])
def test_worst_first(outcomes, expected):
    cases = [case(f"ACK/t{i}", ("MCP-ACK-1",), o, failed_rule="MCP-ACK-1" if o in ("failed", "warned") else None)
             for i, o in enumerate(outcomes)]
    assert rule_outcomes(cases, "drone")["MCP-ACK-1"] == expected


def test_pass_of_an_info_rule_contributes_info():
    assert rule_outcomes([case("TRN/t", ("MCP-TRN-1",), "info", level="INFO")], "drone")["MCP-TRN-1"] == "info"


def test_json_follows_the_design_and_the_schema():
    run = sample_run()
    doc = build_json(run)
    validate_json(doc)
    assert list(doc) == ["schema_version", "tool", "spec", "target", "role", "parameters", "seed",
                         "error", "cases", "failures", "rules", "summary"]
    assert doc["schema_version"] == "1.5" and doc["tool"]["name"] == "mcp-conform"
    assert doc["spec"] == {"protocol": "MCP", "version": SPEC.version, "sha256": SPEC.sha256}
    assert doc["summary"] == {"passed": 1, "failed": 1, "warned": 1, "skipped": 1, "info": 1,
                              "error": 1, "xfailed": 0, "xpassed": 0, "duration_s": 1.25}
    first = doc["cases"][0]
    assert first["capture"] == {"start_ns": 10, "end_ns": 20} and first["duration_s"] == 0.5
    assert set(first) >= {"id", "rules", "level", "outcome", "reason", "expected", "actual",
                          "duration_s", "capture", "failed_rule", "evidence", "notes", "baseline",
                          "consequence_of"}
    failed = doc["cases"][1]  # schema 1.1: the evidence and the failed rule the terminal shows
    assert failed["failed_rule"] == "MCP-ACK-4" and failed["evidence"] == ["seq 3"]
    assert doc["cases"][4]["notes"] == ["initial seq 5"]
    # every failure, root failures first (here no consequences)
    assert [f["case"] for f in doc["failures"]] == ["ACK/test_b", "ACK/test_c"]


def test_schema_rejects_what_the_design_does_not_allow():
    doc = build_json(sample_run())
    v = jsonschema.Draft202012Validator(load_schema())
    bad_outcome = json.loads(json.dumps(doc))
    bad_outcome["cases"][0]["outcome"] = "ok"
    bad_rule = json.loads(json.dumps(doc))
    bad_rule["rules"]["MCP-ACK-1"] = "error"  # the rules map has no "error"
    missing = json.loads(json.dumps(doc))
    del missing["summary"]["warned"]
    for d in (bad_outcome, bad_rule, missing):
        assert not v.is_valid(d)


def test_error_report_and_exit_codes(tmp_path):
    run = RunRecord(error="target never answered")
    path = tmp_path / "r.json"
    write_json(path, run)
    doc = json.loads(path.read_text())
    validate_json(doc)
    assert doc["error"] == "target never answered" and doc["cases"] == []
    assert set(doc["rules"].values()) == {"skipped"}
    assert run.exit_code() == 2
    assert sample_run().exit_code() == 1
    ok = RunRecord(cases=[case("ACK/a", ("MCP-ACK-7",), "warned", level="SHOULD")])
    assert ok.exit_code() == 0


def test_write_json_names_the_option(tmp_path):
    with pytest.raises(OSError, match="--json"):
        write_json(tmp_path / "no" / "such" / "r.json", RunRecord())


def test_junit_mapping():
    root = ET.fromstring(junit_xml(sample_run()))
    suite = root.find("testsuite")
    assert suite is not None
    assert (suite.get("tests"), suite.get("failures"), suite.get("errors"), suite.get("skipped")) == ("6", "1", "1", "1")
    assert suite.get("timestamp") and suite.get("hostname")
    cases = {tc.get("name").removesuffix(" [warned]"): tc for tc in suite.iter("testcase")}
    assert cases["ACK/test_a"].get("classname") == "mcp-conform.ACK"
    assert list(cases["ACK/test_a"]) == []
    failure = cases["ACK/test_b"].find("failure")
    assert failure is not None and "expected: no ACK" in (failure.text or "") and "seq 3" in (failure.text or "")
    assert cases["ROB/test_f"].find("error") is not None
    skipped = cases["BLK/test_d"].find("skipped")
    assert skipped is not None and skipped.get("message") == "not observable"
    for name, word in (("ACK/test_c", "WARNED"), ("SEQ/test_e", "INFO")):
        tc = cases[name]
        assert tc.find("failure") is None and tc.find("error") is None
        out = tc.find("system-out")
        assert out is not None and (out.text or "").startswith(word)
    assert "initial seq 5" in (cases["SEQ/test_e"].find("system-out").text or "")


def test_terminal_report_lines_and_summary():
    buf = io.StringIO()
    rep = TerminalReport(Console(file=buf, width=100, color_system=None))
    run = sample_run()
    for c in run.cases:
        rep.case(c)
    rep.summary(run)
    text = buf.getvalue()
    assert "FAILED   ACK/test_b  MCP-ACK-4 MCP-ACK-5" in text
    assert "expected: no ACK" in text and "actual:   an ACK" in text and "evidence: seq 3" in text
    assert SPEC.rule("MCP-ACK-4").text[:30] in text
    assert "WARNED   ACK/test_c" in text
    assert "not observable" in text and "RuntimeError: boom" in text
    assert "note: initial seq 5" in text
    assert "1 passed, 1 failed, 1 warned, 1 skipped, 1 info, 1 error" in text
    assert "suite finished in 1.2 s" in text or "suite finished in 1.3 s" in text
    assert "MCP-ACK-4" in text.split("per-rule outcome", 1)[1]


def test_terminal_listing():
    buf = io.StringIO()
    TerminalReport(Console(file=buf, width=100, color_system=None)).listing(
        [("ACK/test_a", ("MCP-ACK-1",), "MUST", "main"), ("RTX/test_b", ("MCP-RTX-1",), "MUST", "startup")])
    text = buf.getvalue()
    assert "ACK/test_a  MCP-ACK-1  MUST" in text and "(startup)" in text and "2 cases" in text


def test_merge_json_of_xdist_workers_keeps_the_worst_outcome():
    from mcp_conform.conformance.report import merge_json

    def doc(rules, cases, error=None, dur=1.0, target="a"):
        return {"schema_version": "1.0", "target": target, "error": error, "rules": rules,
                "cases": cases, "summary": {"duration_s": dur}}
    a = doc({"MCP-ACK-1": "passed", "MCP-ACK-2": "skipped"}, [{"id": "x", "outcome": "passed"}])
    b = doc({"MCP-ACK-1": "failed", "MCP-ACK-2": "passed"}, [{"id": "y", "outcome": "failed"}], dur=2.5,
            target="b")
    m = merge_json([a, b])
    assert m["rules"] == {"MCP-ACK-1": "failed", "MCP-ACK-2": "passed"}
    assert [c["id"] for c in m["cases"]] == ["x", "y"]
    assert m["failures"] == [{"case": "y", "rule": None, "outcome": "failed", "consequence_of": []}]
    assert m["summary"]["passed"] == 1 and m["summary"]["failed"] == 1 and m["summary"]["duration_s"] == 2.5
    assert m["target"] == "a, b" and m["error"] is None


# ---------------------------------------------------------------------- cascades
def test_a_failure_relying_on_a_rule_that_failed_first_is_named_its_consequence():
    from mcp_conform.conformance.report import name_consequence

    root = case("ACK/test_ack", ("MCP-ACK-1",), "failed", failed_rule="MCP-ACK-1", actual="no reply",
                reason="MCP-ACK-1: ...")
    rob = case("ROB/test_short", ("MCP-ROB-1", "MCP-ROB-5"), "failed", failed_rule="MCP-ROB-5",
               relies_on=("MCP-ACK-1",), reason="MCP-ROB-5: ...", actual="no ACK of the probe")
    died = case("ROB/test_big", ("MCP-ROB-6",), "failed", failed_rule="MCP-ROB-6", relies_on=(),
                reason="MCP-ROB-6: ...")
    alone = case("ROB/test_flood", ("MCP-ROB-7",), "warned", failed_rule="MCP-ROB-7",
                 relies_on=("MCP-ACK-1",), reason="MCP-ROB-7: ...")
    name_consequence(alone, [])  # nothing failed before it: a root
    run = RunRecord(role="drone")
    for c in (root, rob, died):
        name_consequence(c, run.cases)
        run.cases.append(c)
    run.cases.insert(0, alone)
    assert rob.consequence_of == ["MCP-ACK-1"] and rob.reason.startswith("consequence of MCP-ACK-1 (failed): ")
    assert root.consequence_of == [] and died.consequence_of == [] and alone.consequence_of == []
    assert run.exit_code() == 1 and run.counts()["failed"] == 3  # outcomes unchanged
    doc = build_json(run)
    validate_json(doc)
    assert [c["id"] for c in doc["cases"]] == ["ROB/test_flood", "ACK/test_ack", "ROB/test_short",
                                               "ROB/test_big"]  # run order
    assert [(f["case"], f["consequence_of"]) for f in doc["failures"]] == [
        ("ROB/test_flood", []), ("ACK/test_ack", []), ("ROB/test_big", []),
        ("ROB/test_short", ["MCP-ACK-1"])]
    assert doc["cases"][2]["consequence_of"] == ["MCP-ACK-1"]
    buf = io.StringIO()
    TerminalReport(Console(file=buf, width=120, color_system=None)).summary(run)
    text = buf.getvalue()
    assert text.index("root failures (3):") < text.index("ACK/test_ack") < text.index(
        "their consequences (1):") < text.index("ROB/test_short  consequence of MCP-ACK-1")


def _trn2_then_monitor_ack1() -> RunRecord:
    """A node that drops datagrams from another source port (the sample node's
    source-port-filter, a drone on a connect()ed socket): MCP-TRN-2's case fails, and the trace
    monitor proves MCP-ACK-1 violated after it, on the messages it dropped."""
    run = RunRecord(role="drone", target="127.0.0.1:7890")
    run.cases = [
        case("ACK/test_every_command_type_is_acked", ("MCP-ACK-1",), "passed", start_ns=10, end_ns=20),
        case("TRN/test_datagram_from_another_source_port_is_accepted", ("MCP-TRN-2",), "failed",
             failed_rule="MCP-TRN-2", start_ns=30, end_ns=40, actual="no ACK at either of the runner's sockets"),
    ]
    run.monitor = {"complete": True, "datagrams": 4, "nodes": [], "rules": {"1": {"MCP-ACK-1": "failed"}},
                   "violations": [{"rule": "MCP-ACK-1", "level": "MUST", "node": 1, "t_ns": 50,
                                   "expected": "an ACK within 5 copies", "actual": "no ACK of 5 copies",
                                   "evidence": [{"index": 3, "t_ns": 45}]}]}
    run.finished = run.started + 1.0
    return run


def test_a_monitor_violation_that_is_a_failures_consequence_is_never_passed_in_the_rules():
    """One judge, one verdict: the rules table said MCP-ACK-1 passed while ``failures`` listed
    the monitor's MCP-ACK-1 failure as MCP-TRN-2's consequence. Its row is ``consequence`` (the
    terminal and the HTML say "see MCP-TRN-2"), the terminal lists it under the root's
    consequences, and it still counts as no failure of its own (exit code, summary)."""
    from mcp_conform.reports.html import render_run

    run = _trn2_then_monitor_ack1()
    doc = build_json(run)
    validate_json(doc)
    assert doc["rules"]["MCP-ACK-1"] == "consequence" and doc["rules"]["MCP-TRN-2"] == "failed"
    assert [(f["rule"], f["consequence_of"]) for f in doc["failures"]] == [("MCP-TRN-2", []),
                                                                          ("MCP-ACK-1", ["MCP-TRN-2"])]
    assert run.exit_code() == 1 and doc["summary"]["failed"] == 1
    buf = io.StringIO()
    TerminalReport(Console(file=buf, width=160, color_system=None)).summary(run)
    text = buf.getvalue()
    (row,) = [ln for ln in text.splitlines() if ln.startswith("MCP-ACK-1 ")]
    assert row.split()[2:] == ["see", "MCP-TRN-2"], text
    assert text.index("root failures (1):") < text.index("their consequences (1):") < text.index(
        "FAILED  MCP-ACK-1  monitor  consequence of MCP-TRN-2"), text
    assert "1 failed by the monitor" not in text, text
    html = render_run(doc)
    assert "see MCP-TRN-2" in html


def test_merged_workers_reports_keep_a_monitor_consequence_out_of_passed():
    from mcp_conform.conformance.report import merge_json

    doc = build_json(_trn2_then_monitor_ack1())
    merged = merge_json([doc])
    validate_json(merged)
    assert merged["rules"]["MCP-ACK-1"] == "consequence"

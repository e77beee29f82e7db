"""JUnit that CI systems show truthfully (issue 13): setup and interrupt errors are
``<error>`` testcases, a warned case is visible, rule IDs are properties, timestamp and
hostname are set, and the default family validates against the Jenkins junit-10 model."""

from __future__ import annotations

from pathlib import Path

import pytest
from junitparser import Error, Failure, JUnitXml, Skipped
from lxml import etree

from mcp_conform.conformance.junit import junit_xml
from mcp_conform.conformance.report import CaseRecord, RunRecord

XSD = Path(__file__).parent / "data" / "jenkins-junit10-model.xsd"


def _schema() -> etree.XMLSchema:
    return etree.XMLSchema(etree.parse(str(XSD)))


def _parse(text: str) -> JUnitXml:
    return JUnitXml.fromstring(text.encode())


def _cases(xml: JUnitXml) -> dict[str, object]:
    return {tc.name: tc for suite in xml for tc in suite}


def _warned_run(strict: bool = False) -> RunRecord:
    run = RunRecord(role="drone", target="127.0.0.1:7890", seed=1, strict=strict)
    outcome = "failed" if strict else "warned"
    run.cases = [
        CaseRecord("ACK/test_ok", ("MCP-ACK-1",), "MUST", "passed"),
        CaseRecord("ACK/test_latency", ("MCP-ACK-7",), "SHOULD", outcome, failed_rule="MCP-ACK-7",
                   reason="MCP-ACK-7: ...", expected="median <= 100 ms", actual="median 300 ms"),
    ]
    run.finished = run.started + 1
    return run


def test_a_setup_error_is_an_error_testcase():
    run = RunRecord(error="target never answered: no Mission_Ready and no ACK within 10 s")
    run.finished = run.started
    text = junit_xml(run)
    _schema().assertValid(etree.fromstring(text.encode()))
    xml = _parse(text)
    suite = next(iter(xml))
    assert (suite.tests, suite.errors) == (1, 1)
    (tc,) = list(suite)
    assert tc.name == "setup"
    assert isinstance(tc.result[0], Error) and "target never answered" in tc.result[0].message


def test_an_interrupted_run_is_an_error_testcase_beside_its_cases():
    run = _warned_run()
    run.error = "interrupted by SIGTERM"
    xml = _parse(junit_xml(run))
    cases = _cases(xml)
    assert isinstance(cases["run interrupted"].result[0], Error)
    assert next(iter(xml)).errors == 1


def test_a_warned_case_is_visible_and_a_failure_under_strict():
    text = junit_xml(_warned_run())
    _schema().assertValid(etree.fromstring(text.encode()))
    cases = _cases(_parse(text))
    warned = cases["ACK/test_latency [warned]"]
    assert warned.is_passed and "WARNED" in (warned.system_out or "")
    props = {p.name: p.value for p in next(iter(_parse(text))).properties()}
    assert props["ACK/test_latency.outcome"] == "warned"
    assert props["ACK/test_latency.rule"] == "MCP-ACK-7"
    strict = _cases(_parse(junit_xml(_warned_run(strict=True))))["ACK/test_latency"]
    assert isinstance(strict.result[0], Failure) and strict.result[0].type == "MCP-ACK-7"


def test_suite_has_timestamp_and_hostname():
    suite = next(iter(_parse(junit_xml(_warned_run()))))
    assert suite.timestamp and suite.hostname


def test_xunit1_puts_rule_ids_in_each_testcase_and_is_not_junit10():
    text = junit_xml(_warned_run(), family="xunit1")
    root = etree.fromstring(text.encode())
    tc = root.find(".//testcase[@name='ACK/test_ok']")
    assert [p.get("value") for p in tc.iterfind("properties/property[@name='rule']")] == ["MCP-ACK-1"]
    assert not _schema().validate(root)  # the trade-off the default family avoids
    with pytest.raises(ValueError):
        junit_xml(_warned_run(), family="xunit3")


def test_baseline_outcomes_in_junit():
    run = RunRecord(strict=False)
    run.cases = [CaseRecord("ACK/a", ("MCP-ACK-2",), "MUST", "xfailed", failed_rule="MCP-ACK-2", baseline="known"),
                 CaseRecord("ACK/b", ("MCP-ACK-3",), "MUST", "xpassed", baseline="fixed?")]
    run.finished = run.started
    text = junit_xml(run)
    _schema().assertValid(etree.fromstring(text.encode()))
    cases = _cases(_parse(text))
    assert isinstance(cases["ACK/a"].result[0], Skipped) and "known" in cases["ACK/a"].result[0].message
    assert cases["ACK/b [xpassed]"].is_passed
    run.strict = True
    strict = _cases(_parse(junit_xml(run)))["ACK/b [xpassed]"]
    assert isinstance(strict.result[0], Failure)


def test_a_failures_message_is_what_was_seen_not_the_rules_text():
    """Issue 18 item 16: CI lists show ``message=``; it says what the node did (the rule's
    text stays in the body, the rule ID in ``type``)."""
    run = RunRecord(role="drone", target="127.0.0.1:7890", seed=1)
    run.cases = [CaseRecord("ACK/test_broadcast", ("MCP-ACK-4",), "MUST", "failed", failed_rule="MCP-ACK-4",
                            reason="MCP-ACK-4: A node does not ACK a broadcast message (dst = broadcast ID, D-1).",
                            expected="no ACK of seq 1310 within 0.25 s", actual="ACK received 0.000 s after it")]
    run.finished = run.started + 1
    (result,) = _cases(_parse(junit_xml(run)))["ACK/test_broadcast"].result
    assert isinstance(result, Failure) and result.type == "MCP-ACK-4"
    assert result.message == "MCP-ACK-4: ACK received 0.000 s after it"
    assert "A node does not ACK a broadcast message" in result.text

"""Expected-failures baselines (issue 13): loading, matching, writing, and the round trip
through a real run (``--write-baseline``, then ``--baseline``: exit 0; a fixed node: xpassed)."""

from __future__ import annotations

import json

import pytest

from mcp_conform.conformance.baseline import BaselineError, load_baseline, write_baseline
from mcp_conform.conformance.report import CaseRecord

from .runner_helpers import FAST, run_conform, sample_node_command


def test_yaml_and_json_baselines_match_by_case_or_rule(tmp_path):
    y = tmp_path / "b.yaml"
    y.write_text("version: 1\nexpected_failures:\n"
                 "  - {id: ACK/test_x, reason: known}\n  - {id: MCP-RTX-3, reason: jitter}\n")
    j = tmp_path / "b.json"
    j.write_text(json.dumps({"version": 1, "expected_failures": [{"id": "ACK/test_x", "reason": "known"}]}))
    b = load_baseline(y)
    assert b.match("ACK/test_x", ("MCP-ACK-2",), "MCP-ACK-2").reason == "known"
    assert b.match("RTX/test_y", ("MCP-RTX-3",), "MCP-RTX-3").reason == "jitter"
    assert b.match("RTX/test_y", ("MCP-RTX-3",), None).reason == "jitter"  # a pass: xpassed
    assert b.match("RTX/test_z", ("MCP-RTX-1", "MCP-RTX-3"), None) is None  # not only that rule
    assert b.match("ACK/test_other", ("MCP-ACK-2",), "MCP-ACK-2") is None
    assert load_baseline(j).match("ACK/test_x", (), None) is not None


@pytest.mark.parametrize(("text", "words"), [
    ("version: 2\n", "version 2"),
    ("expected_failures: [{id: MCP-XYZ-1, reason: r}]\n", "not a rule"),
    ("expected_failures: [{id: ACK/a}]\n", "needs a 'reason'"),
    ("expected_failures: [{reason: r}]\n", "needs an 'id'"),
    ("expected_failures: [{id: a, reason: r}, {id: a, reason: r}]\n", "listed twice"),
    ("expected_failures: {a: b}\n", "must be a list"),
    ("[: not yaml", "not YAML or JSON"),
    ("[" * 100_000 + "]" * 100_000, "nested deeper"),  # RecursionError escaped as a traceback
    ("a: " + "[" * 100_000, "nested deeper|not YAML or JSON"),
])
def test_bad_baselines_are_one_line_errors(tmp_path, text, words):
    p = tmp_path / "b.yaml"
    p.write_text(text)
    with pytest.raises(BaselineError, match=words) as info:
        load_baseline(p)
    assert "\n" not in str(info.value) and "b.yaml" in str(info.value)
    with pytest.raises(BaselineError, match="no such file"):
        load_baseline(tmp_path / "missing.yaml")


def test_write_baseline_lists_failed_and_warned_cases(tmp_path):
    cases = [CaseRecord("ACK/a", ("MCP-ACK-2",), "MUST", "failed", failed_rule="MCP-ACK-2", actual="seq 7"),
             CaseRecord("ACK/b", ("MCP-ACK-7",), "SHOULD", "warned", failed_rule="MCP-ACK-7"),
             CaseRecord("ACK/c", ("MCP-ACK-1",), "MUST", "passed"),
             CaseRecord("ROB/d", ("MCP-ROB-1",), "MUST", "error", reason="boom")]
    for name in ("b.yaml", "b.json"):
        n = write_baseline(tmp_path / name, cases, "127.0.0.1:1")
        b = load_baseline(tmp_path / name)
        assert n == 2 and [e.id for e in b.entries] == ["ACK/a", "ACK/b"]
        assert "MCP-ACK-2: seq 7" in b.entries[0].reason


@pytest.mark.slow
def test_baseline_round_trip_against_a_faulty_then_a_fixed_node(tmp_path):
    base = tmp_path / "baseline.yaml"
    sel = ["--select", "MCP-ACK-2", "MCP-ACK-1", "--mavlink", *FAST]
    faulty = sample_node_command("--fault", "ack-little-endian")
    first = run_conform("--spawn", faulty, *sel, "--write-baseline", str(base))
    assert first.rc == 1 and first.rules["MCP-ACK-2"] == "failed", first.explain()
    entries = load_baseline(base).entries
    assert entries and all(e.id.startswith("ACK/") for e in entries)
    again = run_conform("--spawn", faulty, *sel, "--baseline", str(base))
    assert again.rc == 0, again.explain()
    assert again.cases_with("xfailed") and not again.cases_with("failed"), again.explain()
    assert again.report["summary"]["xfailed"] == len(entries)
    fixed = run_conform("--spawn", sample_node_command(), *sel, "--baseline", str(base))
    assert fixed.rc == 0 and fixed.cases_with("xpassed"), fixed.explain()
    assert "take it off the baseline" in fixed.output
    strict = run_conform("--spawn", sample_node_command(), *sel, "--baseline", str(base), "--strict")
    assert strict.rc == 1 and strict.cases_with("xpassed"), strict.explain()

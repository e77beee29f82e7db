"""The runner's trace monitor (judge.run_monitor): fed as the runner feeds it, the
harness's own traffic is never blamed, the node's is; the report's ``monitor`` section
follows the schema. The slow tests run ``mcp-conform`` end to end.
"""

from __future__ import annotations

import pytest

from mcp_conform.conformance.report import RunRecord, build_json, merge_json, validate_json
from mcp_conform.judge.run_monitor import RunMonitor
from mcp_conform.spec.codec import BROADCAST_ID, PREAMBLE, Action, Message, build_datagram, encode

RUNNER = ("0.0.0.0", 7889)
NODE = ("127.0.0.1", 45000)
NS = 1_000_000_000


def _monitor() -> RunMonitor:
    rm = RunMonitor(rto=0.2, ack_window=0.25, broadcast_id=BROADCAST_ID, node_id=1, node_addr=NODE)
    rm.listen = RUNNER
    return rm


def test_the_runners_deliberate_faults_are_not_blamed_the_nodes_are():
    rm = _monitor()
    t = 1_000 * NS
    ready = encode(Message(0, 1, 500, Action.MISSION_READY))
    rm.observe("rx", ready, NODE, t)
    # the runner: a wrong-seq ACK, a wrong-src ACK, a bad preamble, an unknown action
    rm.observe("tx", encode(Message(1, 0, 7, Action.ACK, 0x1234)), NODE, t + 1)
    rm.observe("tx", encode(Message(1, 0x101, 8, Action.ACK, 500)), NODE, t + 2)
    rm.observe("tx", PREAMBLE[:-1] + b"\x02" + bytes(8), NODE, t + 3)
    rm.observe("tx", build_datagram(1, 0, 9, 12), NODE, t + 4)
    rm.observe("tx", encode(Message(1, 0, 10, Action.ACK, 500)), NODE, t + 5)
    assert rm.violations() == []
    # the node: a datagram from its address with a bad preamble, and one with another src
    rm.observe("rx", PREAMBLE[:-1] + b"\x02" + bytes(10), NODE, t + 6)
    rm.observe("rx", encode(Message(0, 2, 501, Action.ACK, 10)), NODE, t + 7)
    rm.finish(t + 10 * NS)
    assert sorted((v.rule, v.node) for v in rm.violations()) == [("MCP-HDR-1", 1), ("MCP-HDR-4", 1)]
    assert [n["id"] for n in rm.to_json()["nodes"]] == [1]
    assert rm.verdict(1, "MCP-HDR-1") == "failed" and rm.verdict(1, "MCP-HDR-5") == "passed"


def test_the_report_carries_the_monitor_section_and_it_validates():
    rm = _monitor()
    rm.observe("rx", encode(Message(0, 1, 500, Action.MISSION_READY)), NODE, NS)
    rm.observe("rx", PREAMBLE[:3], NODE, NS + 1)  # short, from the node's address: MCP-HDR-2
    rm.finish(3 * NS)
    run = RunRecord(role="drone", target="127.0.0.1:45000", parameters={}, seed=1)
    run.monitor = rm.to_json()
    doc = build_json(run)
    validate_json(doc)
    assert doc["monitor"]["violations"][0]["rule"] == "MCP-HDR-2"
    assert doc["monitor"]["rules"]["1"]["MCP-HDR-2"] == "failed"
    merged = merge_json([doc, build_json(run)])
    validate_json(merged)
    assert merged["monitor"]["datagrams"] == 2 * doc["monitor"]["datagrams"]
    run.monitor = None
    assert "monitor" not in build_json(run)


@pytest.mark.slow
def test_a_violation_the_monitor_proves_counts_once_under_its_rule(tmp_path):
    """Issue 18 items 1-2: a node that ACKs every retransmitted copy with a wrong number
    passes every case, yet the run's monitor proves MCP-ACK-2 (not "no ACK", MCP-ACK-1: an
    ACK came). The violation counts: exit 1, a failures entry of source monitor, the rule
    failed in the rule table, a JUnit failure, a terminal line — once, under its rule."""
    import xml.etree.ElementTree as ET

    from tests.conformance.runner_helpers import FAST, run_conform, sample_node_command

    junit = tmp_path / "junit.xml"
    res = run_conform("--spawn", sample_node_command("--fault", "ack-copies-wrong-seq"), "--mavlink",
                      *FAST, "--junit", str(junit))
    mon = res.report["monitor"]
    assert {v["rule"] for v in mon["violations"]} == {"MCP-ACK-2"}, mon["violations"]
    assert res.rc == 1, res.explain()
    entries = [f for f in res.report["failures"] if f.get("source") == "monitor"]
    assert [(f["rule"], f["outcome"]) for f in entries] == [("MCP-ACK-2", "failed")]
    assert res.report["rules"]["MCP-ACK-2"] == "failed" and res.report["rules"]["MCP-ACK-1"] != "failed"
    assert "monitor: MCP-ACK-2 failed" in res.output
    cases = {tc.get("name"): tc for tc in ET.parse(junit).getroot().iter("testcase")}
    assert cases["monitor/MCP-ACK-2"].find("failure") is not None

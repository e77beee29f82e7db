"""mcp-capture check: the monitor's scripted missions written as pcaps, judged from the file.

The conversations are the monitor's own (tests/judge/monitor_scripts.py and
monitor_faults.py). A pcap cannot hold the harness's origin or the autopilot link, so each
faulty mission is checked against the monitor judging the same datagrams in memory: the
command line must find exactly what the monitor finds, and for the faults that traffic
alone shows, that is exactly the fault's rule.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from mcp_conform.captures.check import SCHEMA_VERSION, load_schema, validate_json
from mcp_conform.captures.cli import main
from mcp_conform.judge.monitor import Monitor
from mcp_conform.spec import SPEC
from mcp_conform.spec.mission import load_waypoints, save_waypoints
from tests.judge.monitor_faults import FAULTY
from tests.judge.monitor_scripts import TESTER, Script, clean_script

ROOT = Path(__file__).resolve().parents[2]


def check(tmp_path: Path, script: Script, *args: str, capsys=None) -> tuple[int, dict]:
    pcap = script.write_pcap(tmp_path / "trace.pcap")
    out = tmp_path / "check.json"
    rc = main(["check", str(pcap), "--rto", str(script.rto), "--ack-window", str(script.ack_window),
               "--json", str(out), *args])
    doc = json.loads(out.read_text())
    validate_json(doc)
    return rc, doc


def mission_args(s: Script, tmp_path: Path) -> list[str]:
    """What the mission is: its drones, challenge and items (as a waypoint file)."""
    waypoints = tmp_path / "mission.waypoints"
    save_waypoints(waypoints, s.items)
    return ["--drones", ",".join(map(str, s.drones)), "--challenge", str(s.challenge),
            "--waypoints", str(waypoints)]


def test_schema_is_a_valid_json_schema():
    import jsonschema

    jsonschema.Draft202012Validator.check_schema(load_schema())


def _capture(protocol: str, tmp_path: Path) -> Path:
    """A capture of each protocol that breaks a MUST."""
    if protocol == "nsqd":
        from tests.traceio.test_nsqd_tcp import interleaved

        return interleaved(tmp_path / "nsqd.pcap")  # a backend's UPDATE with a bad state
    if protocol == "mavlink":
        from tests.captures.test_mavlink_capture import FAULTS, TLOG, records

        pick = FAULTS["heartbeat-gap"][1]
        gap = tmp_path / "gap.tlog"
        gap.write_bytes(b"".join(raw for f, raw in records(TLOG) if not pick(f)))
        return gap
    return FAULTY["hdr2-short"].build().write_pcap(tmp_path / "mcp.pcap")  # a datagram shorter than its header


@pytest.mark.parametrize("protocol", ["mcp", "mavlink", "nsqd"])
def test_every_protocols_check_writes_the_one_document(tmp_path, capsys, protocol):
    """MCP's, MAVLink's and Nsqd's check write one document (check.schema.json): the protocol,
    the rules' verdicts, the violations with the rule's level and text, the summary and the
    verdict, the same verdict and exit code the terminal says; a document of another
    protocol's read as MCP's (no protocol) does not pass the schema."""
    import jsonschema

    out = tmp_path / "check.json"
    rc = main(["check", "--protocol", protocol, str(_capture(protocol, tmp_path)), "--json", str(out)])
    doc = json.loads(out.read_text())
    validate_json(doc)
    text = capsys.readouterr().out
    assert doc["protocol"] == protocol and doc["schema_version"] == SCHEMA_VERSION
    assert rc == doc["summary"]["exit_code"] == 1 and doc["verdict"] == "FAILED" and "FAILED" in text.splitlines()[-1]
    assert doc["violations"] and all(v["rule"].startswith({"mcp": "MCP-", "mavlink": "MAV-", "nsqd": "NSQD-"}[protocol])
                                     and v["text"] and v["level"] == "MUST" for v in doc["violations"])
    assert doc["summary"]["failing"] == doc["summary"]["must"] >= len(doc["violations"])
    if protocol != "mcp":
        assert doc["summary"]["violations"] == sum(doc["failed_count"].values())
        assert {r for r, v in doc["rules"].items() if v == "failed"} == set(doc["failed_count"])
        del doc["protocol"]
        with pytest.raises(jsonschema.ValidationError):
            validate_json(doc)


@pytest.mark.parametrize("challenge", [1, 2, 3])
@pytest.mark.parametrize("drones", [(1, 2), pytest.param((1, 2, 3), marks=pytest.mark.slow)])
def test_clean_missions_pass(tmp_path, challenge, drones):
    s = clean_script(challenge, drones=drones, seed=challenge * 10 + len(drones))
    rc, doc = check(tmp_path, s)
    assert rc == 0 and doc["violations"] == [], doc["violations"]
    assert [n["id"] for n in doc["nodes"]] == [0, *sorted(drones)]
    assert doc["nodes"][0]["role"] == "manager" and doc["nodes"][0]["addresses"] == ["127.0.0.1:7889"]
    assert doc["parameters"]["challenge"] == challenge and doc["parameters"]["challenge_source"] == "inferred"
    assert doc["summary"]["exit_code"] == 0 and doc["summary"]["verdicts"]["passed"] > 20
    assert doc["rules"]["0"]["MCP-FLOW-4" if challenge == 1 else "MCP-FLOW-5" if challenge == 2 else "MCP-FLOW-6"] == "passed"
    # what the mission is known to be, and a complete trace: still nothing
    rc, doc = check(tmp_path, s, *mission_args(s, tmp_path), "--complete", "--strict")
    assert rc == 0 and doc["violations"] == [] and doc["parameters"]["challenge_source"] == "given"


@pytest.mark.parametrize("kw", [{"lost_acks": 1}, {"deaf": 2}], ids=["lost-acks", "deaf"])
def test_retransmissions_lost_acks_wrap_and_initial_numbers_pass(tmp_path, kw):
    s = Script((1, 2), challenge=2, seqs={0: 65533, 1: 65535, 2: 4321}, seed=5)
    s.mission(**kw)
    rc, doc = check(tmp_path, s)
    assert rc == 0 and doc["violations"] == []


def pcap_expressible(name: str) -> bool:
    """A fault whose conversation a pcap holds whole: no harness origin to tell apart."""
    return not any(r.origin is TESTER for r in FAULTY[name].build().records)


def in_memory_rules(s: Script, complete: bool, tmp_path: Path) -> set[str]:
    """What the monitor finds in the same datagrams, without the autopilot link, the trace
    ending with its last datagram (as a capture does), the mission's items read back from
    the waypoint file the command line is given (QGC WPL holds no target system/component)."""
    mission_args(s, tmp_path)
    m = Monitor(rto=s.rto, ack_window=s.ack_window, drones=s.drones, challenge=s.challenge,
                waypoints=load_waypoints(tmp_path / "mission.waypoints"), complete=complete)
    found = [v for r in s.datagrams() for v in m.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data)]
    found += m.finish(s.datagrams()[-1].t_ns)
    return {v.rule for v in found}


QUICK = {"hdr1-bad-preamble", "ack4-acks-broadcast", "seq1-skips", "rtx3-uneven", "blk2-start-before-all-ready",
         "pay3-count-mismatch", "flow5-wp-off-without-wp-on"}  # one per group; the rest with the slow tests


@pytest.mark.parametrize("name", [n if n in QUICK else pytest.param(n, marks=pytest.mark.slow)
                                  for n in sorted(n for n in FAULTY if pcap_expressible(n))])
def test_faulty_missions_find_what_the_monitor_finds(tmp_path, name):
    fault = FAULTY[name]
    s = fault.build()
    expected = in_memory_rules(s, fault.complete, tmp_path)
    args = [*mission_args(s, tmp_path), *(["--complete"] if fault.complete else [])]
    rc, doc = check(tmp_path, s, *args)
    found = {v["rule"] for v in doc["violations"]}
    assert found == expected, (found, expected)
    if expected == {fault.rule}:
        level = SPEC.rule(fault.rule).level
        assert rc == (1 if level == "MUST" else 0)
        for v in doc["violations"]:
            assert v["evidence"] and all(e["index"] is not None and e["summary"].startswith(f"#{e['index']} +")
                                         and " → " in e["summary"] for e in v["evidence"])
            assert v["text"] == SPEC.rule(fault.rule).text
        if level == "SHOULD":
            assert check(tmp_path, s, *args, "--strict")[0] == 1


def test_at_least_15_faults_over_every_group_are_found_exactly_from_pcaps(tmp_path):
    exact = {}
    for name in FAULTY:
        if not pcap_expressible(name):
            continue
        s = FAULTY[name].build()
        if in_memory_rules(s, FAULTY[name].complete, tmp_path) == {FAULTY[name].rule}:
            exact[name] = FAULTY[name].rule
    groups = {rule.split("-")[1] for rule in exact.values()}
    assert len(exact) >= 15, exact
    assert groups >= {"HDR", "ACK", "SEQ", "RTX", "BLK", "PAY", "FLOW"}, groups


def test_select_and_terminal_report(tmp_path, capsys):
    s = FAULTY["ack6-acks-ack"].build()
    pcap = s.write_pcap(tmp_path / "t.pcap")
    assert main(["check", str(pcap), *mission_args(s, tmp_path), "--complete"]) == 1
    out = capsys.readouterr().out
    assert "MCP-ACK-6 (MUST): " + SPEC.rule("MCP-ACK-6").text in out
    assert "evidence: #" in out and "Nodes" in out and "Rules" in out and "FAILED" in out
    assert main(["check", str(pcap), *mission_args(s, tmp_path), "--complete", "--select", "MCP-HDR"]) == 0
    out = capsys.readouterr().out
    assert "No violations." in out and "MCP-ACK-6" not in out


def test_truncated_pcap_is_judged_and_said(tmp_path, capsys):
    s = clean_script(1, drones=(1, 2), seed=3)
    pcap = s.write_pcap(tmp_path / "t.pcap")
    data = pcap.read_bytes()
    cut = tmp_path / "cut.pcap"
    cut.write_bytes(data[:len(data) * 2 // 3])
    out = tmp_path / "cut.json"
    assert main(["check", str(cut), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    assert doc["file"]["truncated"] and "cut short" in doc["file"]["truncated"]
    assert "truncated:" in capsys.readouterr().out


def test_html_report_of_a_faulty_pcap(tmp_path):
    from tests.reports.test_html_report import no_external_assets

    s = FAULTY["ack6-acks-ack"].build()
    pcap = s.write_pcap(tmp_path / "t.pcap")
    page = tmp_path / "check.html"
    assert main(["check", str(pcap), *mission_args(s, tmp_path), "--complete", "--html", str(page)]) == 1
    html = page.read_text()
    no_external_assets(html)
    assert html.count('<section class="finding') == 1 and 'data-rule="MCP-ACK-6"' in html
    assert 'class="arrow ack violation"' in html or "violation" in html.split('data-rule="MCP-ACK-6"', 1)[1]


@pytest.mark.parametrize("declared", [True, False], ids=["declared", "assumed"])
def test_a_capture_declaring_its_rto_says_so_in_a_report_the_schema_takes(tmp_path, declared):
    """A run that set the nodes' timeout itself records its rto as declared (the run
    parameters' ``rto_declared``, ``judge.params.Params.adopt``): ``check --json`` says the
    monitor judged with it declared (``parameters.rto_declared``, schema 1.4), and the report
    follows check.schema.json; a run that only assumed its rto says nothing of it."""
    from mcp_conform.spec.codec import Action, Message, encode
    from mcp_conform.traceio.recorder import McapRecorder, run_metadata

    node, runner = ("127.0.0.1", 17011), ("127.0.0.1", 17899)
    params = {"rto": 0.2, "ack_window": 0.25, **({"rto_declared": True} if declared else {})}
    path = tmp_path / "run.mcap"
    rec = McapRecorder(path, metadata=run_metadata("mcp-conform", role="drone", parameters=params), local=runner)
    t = 10**18
    rec.datagram("rx", encode(Message(0, 1, 7, Action.MISSION_READY)), node, t)
    rec.datagram("tx", encode(Message(1, 0, 3, Action.ACK, 7)), node, t + 10**7)
    rec.close()
    out = tmp_path / "check.json"
    assert main(["check", str(path), "--json", str(out)]) == 0
    doc = json.loads(out.read_text())
    validate_json(doc)
    assert doc["schema_version"] == SCHEMA_VERSION == "1.5" and doc["parameters"]["rto"] == 0.2
    assert doc["parameters"].get("rto_declared") is (True if declared else None)

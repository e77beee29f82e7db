"""The HTML reports (reports.html): self-contained, and shown by a real browser.

The slow test runs ``mcp-conform --html`` against the independent sample node with one
fault, opens the page from disk in headless chromium, and checks through the DOM that the
failing rule, its text and the sequence chart of the case's traffic are shown; the
screenshot is written under pytest's tmp_path as the test's artefact.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import lxml.html
import pytest

from mcp_conform.reports.html import render_run
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.traceio.reader import open_capture
from mcp_conform.traceio.recorder import McapRecorder
from tests.conformance.runner_helpers import FAST, run_conform, sample_node_command

from .browser import chromium


def no_external_assets(html: str) -> None:
    """Nothing to fetch: no src/href to a URL, no <link>, no <script src>, no @import."""
    assert not re.search(r"""(src|href)\s*=\s*["'](https?:|//)""", html)
    assert "<link" not in html and "@import" not in html and "<script" not in html


def a_run(tmp_path: Path) -> tuple[dict, list]:
    """A JSON report with one failed case and its capture window, and the capture."""
    cap = tmp_path / "run.mcap"
    bcast, ack = encode(Message(0xFFFF, 0, 7, Action.WP_OFF)), encode(Message(0, 1, 40, Action.ACK, 7))
    with McapRecorder(cap) as rec:
        rec.datagram("tx", bcast, ("127.255.255.255", 7890), 1_000_000)
        rec.datagram("rx", ack, ("127.0.0.1", 40001), 2_000_000)
        rec.datagram("tx", bcast, ("127.255.255.255", 7890), 9_000_000)  # outside the window
    doc = {"role": "drone", "target": "127.0.0.1:40001", "tool": {"name": "mcp-conform", "version": "x"},
           "spec": {"version": SPEC.version}, "summary": {"passed": 3, "failed": 1, "duration_s": 1.0},
           "rules": {"MCP-ACK-4": "failed", "MCP-ACK-1": "passed"},
           "cases": [{"id": "ACK/test_broadcast_is_not_acked", "rules": ["MCP-ACK-4"], "outcome": "failed",
                      "failed_rule": "MCP-ACK-4", "expected": "no ACK of seq 7", "actual": "ACK <1 ms later",
                      "evidence": ["reply: ACK seq 40"], "capture": {"start_ns": 500_000, "end_ns": 5_000_000}},
                     {"id": "ACK/test_ok", "rules": ["MCP-ACK-1"], "outcome": "passed"}]}
    return doc, list(open_capture(cap).datagrams())


def test_run_page_is_self_contained_and_charts_the_case_window(tmp_path):
    doc, datagrams = a_run(tmp_path)
    html = render_run(doc, datagrams)
    no_external_assets(html)
    assert html.count('<section class="finding') == 1
    assert 'data-rule="MCP-ACK-4"' in html and SPEC.rule("MCP-ACK-4").text in html
    assert html.count('class="arrow') == 2  # the two datagrams of the case's window
    assert "no ACK of seq 7" in html and html.count(">ACK/test_ok<") == 1  # in the list of all cases only
    assert "no capture of the run" in render_run(doc, None)


def test_run_page_lists_every_case_with_skip_reasons_and_info_notes(tmp_path):
    """Issue 18 item 16: as Autobahn's report, the page lists the passed cases too, with the
    reason of each skip and what each INFO case recorded."""
    doc, datagrams = a_run(tmp_path)
    doc["cases"] += [
        {"id": "RTX/test_broadcasts", "rules": ["MCP-RTX-4"], "outcome": "skipped", "duration_s": 0.05,
         "reason": "MCP-RTX-4 is not observable on a drone node"},
        {"id": "SEQ/test_initial", "rules": ["MCP-SEQ-4"], "outcome": "info", "duration_s": 0.001,
         "actual": "initial sequence number 48168", "notes": ["initial sequence number 48168", "and a <note>"]}]
    root = lxml.html.fromstring(render_run(doc, datagrams))
    rows = {tr.get("data-case"): tr for tr in root.xpath("//table[@class='cases']//tr[@data-case]")}
    assert list(rows) == [c["id"] for c in doc["cases"]]
    assert rows["ACK/test_ok"].get("data-outcome") == "passed"
    cells = {k: [td.text_content() for td in tr.findall("td")] for k, tr in rows.items()}
    assert cells["ACK/test_ok"][2] == "passed"
    assert cells["RTX/test_broadcasts"][4] == "MCP-RTX-4 is not observable on a drone node"
    assert cells["SEQ/test_initial"][4] == "initial sequence number 48168\nand a <note>"
    assert cells["ACK/test_broadcast_is_not_acked"][4] == "MCP-ACK-4: ACK <1 ms later"


@pytest.mark.slow
def test_mcp_conform_html_of_a_faulty_node_in_chromium(tmp_path):
    page, capture = tmp_path / "report.html", tmp_path / "run.mcap"
    res = run_conform("--spawn", sample_node_command("--fault", "ack-broadcast"), "--mavlink", *FAST,
                      "--html", str(page), "--capture", str(capture))
    assert res.rc == 1, res.explain()
    assert res.rules["MCP-ACK-4"] == "failed", res.explain()
    html = page.read_text()
    no_external_assets(html)
    from selenium.webdriver.common.by import By

    with chromium() as browser:
        browser.get(page.as_uri())
        findings = browser.find_elements(By.CSS_SELECTOR, "section.finding")
        # the failed case, then the trace monitor's violations (the report's monitor section)
        monitor = res.report["monitor"]["violations"]
        assert monitor and {v["rule"] for v in monitor} == {"MCP-ACK-4"}
        assert [f.get_attribute("data-rule") for f in findings] == ["MCP-ACK-4"] * (1 + len(monitor))
        finding = findings[0]
        assert finding.is_displayed()
        assert SPEC.rule("MCP-ACK-4").text in finding.text
        assert "expected" in finding.text and "actual" in finding.text
        chart = finding.find_element(By.CSS_SELECTOR, "svg.mcp-chart")
        assert chart.size["width"] > 300 and chart.size["height"] > 100
        arrows = chart.find_elements(By.CSS_SELECTOR, "g.arrow")
        assert any("bcast" in a.get_attribute("class") for a in arrows)  # the broadcast it sent
        assert any("ack" in a.get_attribute("class").split() for a in arrows)  # the ACK it should not have
        marked = chart.find_elements(By.CSS_SELECTOR, 'g.arrow.violation[data-rules~="MCP-ACK-4"]')
        assert marked, "the monitor's evidence is marked on the case's chart"
        heads = [h.text for h in chart.find_elements(By.CSS_SELECTOR, "g.head")]
        assert any("broadcast" in h for h in heads) and any("drone 1" in h for h in heads)
        row = browser.find_element(By.CSS_SELECTOR, 'table.rules tr[data-rule="MCP-ACK-4"]')
        assert "failed" in row.text
        shot = tmp_path / "mcp-conform-report.png"
        finding.screenshot(str(shot))
        assert shot.stat().st_size > 5_000
    print(f"screenshot: {shot}")
    # the run's capture, judged offline by the trace monitor: the same fault, and only it
    from mcp_conform.captures.cli import main

    out = tmp_path / "check.json"
    assert main(["check", str(capture), "--rto", FAST[1], "--ack-window", FAST[3], "--json", str(out)]) == 1
    doc = json.loads(out.read_text())
    assert {(v["rule"], v["node"]) for v in doc["violations"]} == {("MCP-ACK-4", 1)}, doc["violations"]


@pytest.mark.slow
def test_mcp_capture_check_html_in_chromium(tmp_path):
    """The check page of a faulty mission: the violation, its rule text, and the chart with
    the violating arrow marked."""
    from selenium.webdriver.common.by import By

    from mcp_conform.captures.cli import main
    from mcp_conform.spec.mission import save_waypoints
    from tests.judge.monitor_faults import FAULTY

    s = FAULTY["ack4-acks-broadcast"].build()
    pcap = s.write_pcap(tmp_path / "faulty.pcap")
    save_waypoints(tmp_path / "m.waypoints", s.items)
    page = tmp_path / "check.html"
    assert main(["check", str(pcap), "--rto", str(s.rto), "--ack-window", str(s.ack_window), "--drones", "1,2",
                 "--challenge", str(s.challenge), "--waypoints", str(tmp_path / "m.waypoints"),
                 "--html", str(page)]) == 1
    no_external_assets(page.read_text())
    with chromium() as browser:
        browser.get(page.as_uri())
        (finding,) = browser.find_elements(By.CSS_SELECTOR, "section.finding")
        assert finding.get_attribute("data-rule") == "MCP-ACK-4"
        assert SPEC.rule("MCP-ACK-4").text in finding.text
        marked = finding.find_elements(By.CSS_SELECTOR, 'svg.mcp-chart g.arrow.violation[data-rules~="MCP-ACK-4"]')
        assert marked and all(m.is_displayed() for m in marked)
        assert browser.find_element(By.CSS_SELECTOR, 'table.rules tr[data-rule="MCP-ACK-4"]').text.count("failed")
        finding.screenshot(str(tmp_path / "mcp-capture-check.png"))
    assert (tmp_path / "mcp-capture-check.png").stat().st_size > 5_000

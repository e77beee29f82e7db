"""The HTML pages escape every value they are given (issue 40 item 4: the cells were
f-strings that had to be "already escaped"): a rule's text, a node's output (a case's
expected/actual/reason/notes/evidence, the target, an error) or a capture's path and a
node's role holding ``<script>`` appear as text, never as an element."""

from __future__ import annotations

import dataclasses

import lxml.html

from mcp_conform.captures.check import to_json
from mcp_conform.judge.judging import Params, evidence_of, judge
from mcp_conform.reports.html import render_check, render_run
from mcp_conform.reports.templating import Markup, Template, attrs, fill, join
from mcp_conform.spec import RULES

from .test_html_report import a_run

XSS = '<script>alert("x")</script>'


def assert_inert(page: str, count: int) -> None:
    """No script element; the hostile text shown ``count`` times, escaped, as the reader sees it."""
    assert "<script" not in page and page.count("&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt;") >= count
    root = lxml.html.fromstring(page)
    assert not root.xpath("//script")
    assert root.text_content().count(XSS) >= count


def test_a_run_page_shows_a_nodes_output_and_a_rule_text_as_text(tmp_path, monkeypatch) -> None:
    monkeypatch.setitem(RULES, "MCP-ACK-4", dataclasses.replace(RULES["MCP-ACK-4"], text=f"rule {XSS}"))
    doc, datagrams = a_run(tmp_path)
    case = doc["cases"][0]
    case.update(expected=XSS, actual=XSS, reason=XSS, notes=[XSS], evidence=[XSS])
    doc["target"] = doc["error"] = XSS
    doc["cases"].append({"id": XSS, "rules": ["MCP-ACK-4"], "outcome": "skipped", "reason": XSS})
    page = render_run(doc, datagrams)
    assert_inert(page, 10)
    root = lxml.html.fromstring(page)
    assert root.xpath("//p[@class='rule-text']")[0].text_content().endswith(f"rule {XSS}")
    assert [tr.get("data-case") for tr in root.xpath("//table[@class='cases']//tr[@data-case]")][-1] == XSS


def test_a_check_page_shows_a_path_a_role_and_a_note_as_text(tmp_path) -> None:
    from .test_html_report import a_run as _a_run

    _a_run(tmp_path)  # writes tmp_path/run.mcap
    j = judge(tmp_path / "run.mcap", Params(rto=5.0, ack_window=2.0, challenge=2))
    doc = to_json(j, evidence_of(j))
    doc["file"]["path"] = XSS
    doc["file"]["notes"] = [XSS]
    doc["file"]["truncated"] = XSS
    for node in doc["nodes"]:
        node["role"] = XSS
    page = render_check(j, doc)
    assert_inert(page, 4 + len(doc["nodes"]))


def test_markup_is_the_only_way_in_unescaped() -> None:
    li = Template("<li>$item</li>")
    assert fill(li, item=XSS) == "<li>&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt;</li>"
    assert fill(li, item=Markup("<b>x</b>")) == "<li><b>x</b></li>"
    assert join([XSS, Markup("<br>")]) == "&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt;<br>"
    assert attrs({"data-case": '"><script>'}) == ' data-case="&quot;&gt;&lt;script&gt;"'


def test_a_diff_page_shows_hostile_capture_names_as_text(tmp_path) -> None:
    """``mcp-capture diff --html``: the captures' names (file names may hold anything but /)
    appear as text; the charts stay SVG."""
    from tests.captures.scenario import challenge2, reindex
    from tests.captures.test_diff import _cli, _write_mcap

    golden, cand = tmp_path / f"{XSS.replace('/', '|')}.mcap", tmp_path / "cand.mcap"
    _write_mcap(golden, challenge2())
    _write_mcap(cand, reindex(challenge2()[:-1]))
    assert _cli(str(golden), str(cand), "--html", str(tmp_path / "d.html"))[0] == 1
    page = (tmp_path / "d.html").read_text()
    root = lxml.html.fromstring(page)
    assert "<script" not in page and not root.xpath("//script") and root.xpath("//svg")
    assert '<script>alert("x")<|script>' in root.text_content()

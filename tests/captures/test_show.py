"""mcp-capture show, the conversation view (traceio.trace) and the sequence chart (reports.chart)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from typing import Any, NamedTuple

import pytest

import mcp_conform.judge.judging as judging
from mcp_conform.captures.cli import main
from mcp_conform.reports.chart import Arrow, Lifeline, render, trace_svg
from mcp_conform.spec.codec import Action
from mcp_conform.traceio.reader import open_capture
from mcp_conform.traceio.trace import Trace

from .conversation import Script, mission

SVG = "{http://www.w3.org/2000/svg}"


def arrows(svg: str) -> list[ET.Element]:
    root = ET.fromstring(svg)  # well-formed XML, or this raises
    return [g for g in root.iter(f"{SVG}g") if "arrow" in g.get("class", "").split()]


def test_trace_pairs_acks_marks_copies_and_unanswered(tmp_path):
    s = mission(drones=(1, 2), lose_ack_of=2)
    s.msg(0, 0xFFFF, 9999, Action.WP_OFF)  # a broadcast: never "unanswered"
    s.msg(0, 1, 9000, Action.WP_OFF)  # the trace ends before its ACK
    trace = Trace(open_capture(s.write(tmp_path / "m.pcap")).datagrams())
    by = {e.index: e for e in trace.entries}
    wp2 = [e for e in trace.entries if e.header[3] == Action.WP_LIST and e.header[0] == 2]
    assert [e.copy for e in wp2] == [0, 1] and wp2[1].first == wp2[0].index
    assert wp2[0].unanswered and not wp2[1].unanswered
    assert by[wp2[1].acked_by].ack_of == wp2[1].index
    assert trace.entries[-1].unanswered and not trace.entries[-2].unanswered
    assert sorted(trace.nodes) == [0, 1, 2]
    assert trace.nodes[0].role == "manager" and trace.nodes[2].role == "drone"
    assert trace.nodes[1].addresses == {("127.0.0.1", 40001)}
    assert trace.lifelines(trace.entries) == ["0", "1", "2", "65535"]


def test_chart_is_svg_with_one_arrow_per_datagram(tmp_path):
    s = mission(drones=(1, 2), lose_ack_of=2)
    s.send(("10.9.9.9", 5555), ("127.0.0.1", 40001), b"\x01\x02<&>")  # no MCP header
    trace = Trace(open_capture(s.write(tmp_path / "m.pcap")).datagrams())
    svg = trace_svg(trace, title="a <title> & more")
    got = arrows(svg)
    assert len(got) == len(trace.entries)
    classes = [set(g.get("class").split()) for g in got]
    assert sum("copy" in c for c in classes) == 1
    assert sum("unanswered" in c for c in classes) == 1
    assert sum("ack" in c for c in classes) == 8
    assert "malformed" in classes[-1]
    heads = {h.get("data-lifeline") for h in ET.fromstring(svg).iter(f"{SVG}g") if h.get("data-lifeline")}
    assert heads == {"0", "1", "2", "10.9.9.9:5555"}  # the headerless datagram lands on drone 1's address
    assert got[-1].find(f"{SVG}title").text.startswith(f"#{trace.entries[-1].index}")


def test_chart_marks_violations_and_caps_rows():
    lifelines = [Lifeline("0", "manager 0"), Lifeline("1", "drone 1", "127.0.0.1:7890")]
    many = [Arrow(i * 1000, "0", "1", f"WP_Off #{i}", index=i) for i in range(10)]
    many[3] = many[3]._replace(rules=("MCP-BLK-1",))
    svg = render(lifelines, many, max_rows=5)
    got = arrows(svg)
    assert len(got) == 5
    assert got[3].get("data-rules") == "MCP-BLK-1" and "violation" in got[3].get("class")
    assert "5 more datagram(s) not shown" in svg


class FakeViolation(NamedTuple):
    rule: str
    level: str
    node: int
    t_ns: int
    expected: Any
    actual: Any
    evidence: tuple[int, ...]


class FlagsThirdDatagram:
    """A test double of the monitor's API: flags datagram #2 (wiring only)."""

    def __init__(self) -> None:
        self.n = 0

    def datagram(self, t_ns, src_addr, dst_addr, data):
        self.n += 1
        return [FakeViolation("MCP-SEQ-1", "MUST", 0, t_ns, "x", "y", (2,))] if self.n == 3 else []

    def finish(self, t_ns):
        return []

    def verdicts(self):
        return {0: {"MCP-SEQ-1": "failed"}}


def test_show_lists_window_marks_and_writes_svg(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(judging, "_make_monitor", lambda params, party=None: FlagsThirdDatagram())
    path = mission(drones=(1, 2), lose_ack_of=2).write(tmp_path / "m.pcap")
    assert main(["show", str(path), "--svg", str(tmp_path / "c.svg")]) == 0
    out = capsys.readouterr().out
    lines = [ln for ln in out.splitlines() if ln.startswith("#")]
    assert len(lines) == 17
    assert "Mission_Ready" in lines[0] and "ACK #1" in lines[0]
    assert "answers #0" in lines[1]
    assert "✗ MCP-SEQ-1" in lines[2]
    assert any("↻1 of #" in ln for ln in lines) and any("no ACK" in ln for ln in lines)
    assert "2 item(s)" in out and "1 127.0.0.1:40001 → 0 127.0.0.1:7889" in lines[0]
    svg = (tmp_path / "c.svg").read_text()
    assert len(arrows(svg)) == 17
    assert main(["show", str(path), "--from", "0.02", "--to", "0.05"]) == 0
    window = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("#")]
    assert 0 < len(window) < 17 and all("+" in ln for ln in window)


@pytest.mark.parametrize("args,words", [
    (["--from", "x"], "--from: not a number"),
    (["--to", "-1"], "--to: must be 0 or more"),
    (["--case", "ACK/x"], "has no case marks"),
    (["--case", "A", "--from", "1"], "cannot be combined"),
    (["--svg", "/nonexistent/dir/c.svg"], "--svg: directory"),
    (["--max-rows", "0"], "--max-rows"),
])
def test_show_bad_arguments_are_one_line_errors(tmp_path, capsys, args, words):
    path = Script().write(tmp_path / "empty.pcap")
    assert main(["show", str(path), *args]) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1


def test_show_case_window_of_an_mcap(tmp_path, capsys):
    from mcp_conform.spec.codec import Message, encode
    from mcp_conform.traceio.recorder import McapRecorder

    path = tmp_path / "run.mcap"
    start, ack = encode(Message(1, 0, 5, Action.START_MISSION)), encode(Message(0, 1, 9, Action.ACK, 5))
    with McapRecorder(path) as rec:
        rec.datagram("tx", start, ("127.0.0.1", 7890), 1_000)
        rec.case_mark("ACK/test_one", "start", 2_000, rules=("MCP-ACK-1",))
        rec.datagram("tx", start, ("127.0.0.1", 7890), 3_000)
        rec.datagram("rx", ack, ("127.0.0.1", 7890), 4_000)
        rec.case_mark("ACK/test_one", "end", 5_000, outcome="passed", rules=("MCP-ACK-1",))
        rec.case_mark("ACK/test_two", "start", 6_000, rules=("MCP-ACK-1",))
        rec.datagram("tx", start, ("127.0.0.1", 7890), 7_000)
        rec.case_mark("ACK/test_two", "end", 8_000, outcome="passed", rules=("MCP-ACK-1",))
    assert main(["show", str(path), "--case", "ACK/test_one"]) == 0
    lines = [ln for ln in capsys.readouterr().out.splitlines() if ln.startswith("#")]
    assert [ln.split()[0] for ln in lines] == ["#1", "#2"]
    assert "answers #1" in lines[1]
    assert main(["show", str(path), "--case", "ACK/test_"]) == 2  # a prefix of two cases
    assert "matches several cases" in capsys.readouterr().err


def test_show_window_times_are_the_same_in_the_listing_and_the_chart(tmp_path, capsys):
    """Issue 18 item 16: ``show --from S`` lists times since the capture's first datagram;
    the chart's time column says the same, not times since the window's first row."""
    path = mission(drones=(1, 2), lose_ack_of=2).write(tmp_path / "m.pcap")
    svg_path = tmp_path / "w.svg"
    assert main(["show", str(path), "--from", "0.03", "--svg", str(svg_path)]) == 0
    import re

    listed = [re.search(r"\+\s*([\d.]+)s", ln).group(1) for ln in capsys.readouterr().out.splitlines()
              if ln.startswith("#")]
    root = ET.fromstring(svg_path.read_text())
    charted = [re.fullmatch(r"\+([\d.]+)s", t.text).group(1) for t in root.iter(f"{SVG}text")
               if "time" in (t.get("class") or "").split()]
    assert listed and charted == listed and float(listed[0]) >= 0.03


def _runner_capture(path):
    """A run as mcp-conform records it: the runner (bound to all addresses) plays manager 0
    and, in a robustness case, a stranger ID 2; the node under test is drone 1."""
    from mcp_conform.spec.codec import Message, encode
    from mcp_conform.traceio.recorder import McapRecorder

    node = ("127.0.0.1", 7890)
    with McapRecorder(path, local=("0.0.0.0", 41285)) as rec:
        rec.datagram("tx", encode(Message(0xFFFF, 0, 5, Action.WP_OFF)), node, 1_000)  # a broadcast: right
        rec.datagram("rx", encode(Message(0, 1, 9, Action.ACK, 5)), node, 2_000)  # its ACK: MCP-ACK-4
        rec.datagram("tx", encode(Message(1, 2, 7, Action.WP_OFF)), node, 3_000)  # the runner as ID 2
    return path


def test_the_runners_lifelines_are_named_as_the_runner(tmp_path):
    """Issue 18 item 16: an ID only the recording runner sent from is mcp-conform playing it,
    not "drone 2" at 0.0.0.0."""
    trace = Trace(open_capture(_runner_capture(tmp_path / "run.mcap")).datagrams())
    heads = {h.get("data-lifeline"): [t.text for t in h.iter(f"{SVG}text")]
             for h in ET.fromstring(trace_svg(trace)).iter(f"{SVG}g") if h.get("data-lifeline")}
    assert heads["0"] == ["runner as manager 0", "mcp-conform :41285"]
    assert heads["2"] == ["runner as drone 2", "mcp-conform :41285"]
    assert heads["1"] == ["drone 1", "127.0.0.1:7890"]


def test_a_violation_is_badged_on_the_violators_datagrams_not_the_runners(tmp_path):
    """Issue 18 item 16: an ACK of a broadcast breaks MCP-ACK-4; the runner's broadcast it
    answers is evidence, not a violation: only the ACK carries the badge. A violation whose
    evidence the node did not send (a message it left unanswered) keeps its badge there."""
    trace = Trace(open_capture(_runner_capture(tmp_path / "run.mcap")).datagrams())
    trace.mark([FakeViolation("MCP-ACK-4", "MUST", 1, 2_000, "no ACK", "an ACK", (0, 1)),
                FakeViolation("MCP-ACK-5", "MUST", 1, 3_000, "nothing", "x", (2,))])
    badged = {g.get("data-index"): g.get("data-rules") for g in arrows(trace_svg(trace))}
    assert badged == {"0": "", "1": "MCP-ACK-4", "2": "MCP-ACK-5"}

"""A capture merged from pytest-xdist workers (issue 18 item 7): each worker's session stays a
segment (``traceio.merge``), the reader gives each apart (``traceio.reader``), and the judge
judges each on its own, as that worker's run monitor did (``judge.judging``): two workers
testing the same drone ID from runners with the same ID are not one mixed-up trace (false
MCP-ACK-5 on the runner's ID, MCP-BLK-1, MCP-RTX-3 ...)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

from mcp_conform.captures.check import to_json, validate_json
from mcp_conform.judge.judging import Params, judge
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.traceio.merge import merge_captures
from mcp_conform.traceio.reader import Datagram, Metadata, open_capture
from mcp_conform.traceio.recorder import McapRecorder, run_metadata
from tests.conformance.runner_helpers import verdict_differences

GOLDEN = Path(__file__).resolve().parents[2] / "captures" / "golden" / "drone-suite.mcap"
RUNNER, NODE = ("127.0.0.1", 40001), ("127.0.0.1", 40002)


def _first_ns(path: Path) -> int:
    return next(iter(open_capture(path).datagrams())).t_ns


def _faulty_part(path: Path, t0: int) -> None:
    """A worker's session whose drone 1 sends a Start_Mission (MCP-HDR-5, proven by any trace),
    recorded by the runner as ``mcp-conform`` records its runs."""
    rec = McapRecorder(path, metadata=run_metadata("mcp-conform", target=f"{NODE[0]}:{NODE[1]}"), local=RUNNER)
    rec.add_metadata("mcp-conform node", {"id": "1", "address": f"{NODE[0]}:{NODE[1]}", "complete": "true"})
    ms = 1_000_000
    rec.datagram("rx", encode(Message(0, 1, 0, Action.MISSION_READY)), NODE, t0 + 5 * ms)
    rec.datagram("tx", encode(Message(1, 0, 7, Action.ACK, 0)), NODE, t0 + 6 * ms)
    rec.datagram("rx", encode(Message(0, 1, 1, Action.START_MISSION)), NODE, t0 + 50 * ms)
    rec.datagram("tx", encode(Message(1, 0, 8, Action.ACK, 1)), NODE, t0 + 51 * ms)
    rec.close()


def _merged(tmp_path: Path, second: str = "copy") -> tuple[Path, Path]:
    gw0, gw1 = tmp_path / "run.gw0.mcap", tmp_path / "run.gw1.mcap"
    shutil.copy(GOLDEN, gw0)
    if second == "copy":
        shutil.copy(GOLDEN, gw1)
    else:
        _faulty_part(gw1, _first_ns(GOLDEN))
    out = tmp_path / "run.mcap"
    merge_captures([gw0, gw1], out)
    return out, gw1


def test_the_reader_gives_each_segment_apart_with_the_files_indexes(tmp_path):
    merged, _ = _merged(tmp_path)
    cap = open_capture(merged)
    every = list(cap)
    assert cap.segments == ["gw0", "gw1"]
    dgs = [r for r in every if isinstance(r, Datagram)]
    assert {d.segment for d in dgs} == {"gw0", "gw1"}
    assert {d.recorder for d in dgs} == {"mcp-conform"}  # each part's own writer, not the merger
    assert [d.index for d in dgs] == list(range(len(dgs)))
    runs = [r.data.get("segment") for r in every if isinstance(r, Metadata) and r.name == "mcp-conform"]
    assert runs == ["gw0", "gw1"]
    one = list(open_capture(merged, segment="gw1").datagrams())
    assert one and len(one) == sum(d.segment == "gw1" for d in dgs)
    by_index = {d.index: d for d in dgs}
    assert all(by_index[d.index] == d for d in one)  # the file's indexes, not renumbered


def test_two_workers_on_the_same_ids_are_judged_apart(tmp_path):
    """Two workers' identical sessions interleaved: each judged alone gives the single run's
    verdicts, and so does the file (merged per node); nothing false from the mix."""
    single = judge(GOLDEN, Params())
    merged, _ = _merged(tmp_path)
    j = judge(merged, Params())
    assert list(j.segments) == ["gw0", "gw1"]
    for seg in j.segments.values():
        assert verdict_differences({str(k): v for k, v in single.verdicts.items()}, seg.verdicts) == []
    assert verdict_differences({str(k): v for k, v in single.verdicts.items()}, j.verdicts) == []
    assert sorted((v.rule, v.node) for v in j.violations) == \
        sorted(2 * [(v.rule, v.node) for v in single.violations])
    assert list(j.nodes) == list(single.nodes) and j.datagrams == 2 * single.datagrams
    doc = to_json(j, {})
    validate_json(json.loads(json.dumps(doc)))
    assert [s["name"] for s in doc["segments"]] == ["gw0", "gw1"]


def test_a_violation_in_one_worker_is_that_workers_with_its_evidence(tmp_path):
    merged, _ = _merged(tmp_path, second="faulty")
    j = judge(merged, Params())
    assert [(v.rule, v.node) for v in j.violations] == [("MCP-HDR-5", 1)]
    assert j.verdicts[1]["MCP-HDR-5"] == "failed"
    assert j.segments["gw0"].verdicts[1]["MCP-HDR-5"] == "passed"
    assert [v.rule for v in j.segments["gw1"].violations] == ["MCP-HDR-5"]
    (index, _t), = j.violations[0].evidence
    d = {d.index: d for d in open_capture(merged).datagrams()}[index]
    assert d.segment == "gw1" and d.data == encode(Message(0, 1, 1, Action.START_MISSION))


def test_show_lists_and_charts_each_workers_session_apart(tmp_path, capsys):
    """``mcp-capture show`` of a merged capture: each worker's session under its own heading,
    on its own lifelines (before: one chart drew both workers' drone 1 as one node, the faulty
    worker's Start_Mission beside the other's traffic); ``--segment`` picks one."""
    from mcp_conform.captures.cli import main

    merged, _ = _merged(tmp_path, second="faulty")

    def show(*argv: str, code: int = 0) -> str:
        assert main(["show", str(merged), *argv]) == code
        captured = capsys.readouterr()
        return captured.out + captured.err

    out = show("--svg", str(tmp_path / "all.svg"))
    heads = [line for line in out.splitlines() if line.startswith("── session ")]
    assert [h.split(":")[0] for h in heads] == ["── session gw0", "── session gw1"], heads
    gw1 = out.split("── session gw1")[1]
    assert gw1.count("\n#") == 4 and "MCP-HDR-5" in gw1  # its four datagrams, its violation
    assert "MCP-HDR-5" not in out.split("── session gw1")[0]  # not on the other worker's drone
    svg = (tmp_path / "all.svg").read_text()
    assert "session gw0" in svg
    only = show("--segment", "gw1")
    assert "── session gw1: 4 datagram(s)" in only and "session gw0" not in only
    assert "--segment: 'gw9' is not a session" in show("--segment", "gw9", code=2)

"""The capture tools in linear time on noisy captures, and ``check``'s bounded terminal report
(issue 19 item 7).

No timing here (a shared machine's clock says nothing): the work is counted as the Python
lines the tools' own modules execute (``sys.settrace``), for a noisy capture of n and of 2n
datagrams (tests/captures/noisy.py). Linear work doubles; the quadratic parts this replaced
(``traceio.trace``'s owner of an address, a scan of every node per datagram without an MCP
header; ``captures.diff``'s consequent-ACK pass over every divergence once per conversation)
made it grow about 3.5 to 4 times. bench/bench_capture_tools.py has the seconds.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

import mcp_conform.captures.check as check_mod
import mcp_conform.captures.diff as diff_mod
import mcp_conform.traceio.trace as trace_mod
from mcp_conform.captures.cli import main
from mcp_conform.judge.judging import Params, evidence_of, judge
from mcp_conform.spec.codec import Action, Message, MissionItem, encode
from mcp_conform.traceio.reader import open_capture
from mcp_conform.traceio.recorder import McapRecorder
from mcp_conform.traceio.trace import Trace, evidence_indexes

from .noisy import write_noisy

N = 1500  # and 2N: big enough that a quadratic part shows, small enough for a quick test
LINEAR = 2.4  # work(2N) / work(N) at most; linear is ~2.0, the old quadratic code gave 3.2+


def lines_run(files: set[str], fn: Callable[[], Any]) -> int:
    """Python lines executed in ``files`` while ``fn`` runs."""
    count = 0

    def local(frame: Any, event: str, arg: Any) -> Any:
        nonlocal count
        if event == "line":
            count += 1
        return local

    def tracer(frame: Any, event: str, arg: Any) -> Any:
        return local if frame.f_code.co_filename in files else None

    old = sys.gettrace()
    sys.settrace(tracer)
    try:
        fn()
    finally:
        sys.settrace(old)
    return count


@pytest.fixture(scope="module")
def noisy(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("noisy")
    return {"n": write_noisy(d / "n.mcap", N), "2n": write_noisy(d / "2n.mcap", 2 * N),
            "n-other": write_noisy(d / "n-other.mcap", N, seed=7),
            "2n-other": write_noisy(d / "2n-other.mcap", 2 * N, seed=7)}


def test_the_noisy_captures_are_noisy(noisy):
    """What the scaling tests rely on: a node per few datagrams (random headers), datagrams
    without an MCP header, violations by the hundred."""
    datagrams = list(open_capture(noisy["2n"]).datagrams())
    trace = Trace(datagrams)
    assert len(datagrams) == 2 * N
    assert len(trace.nodes) > N // 4
    assert sum(e.header is None for e in trace.entries) >= N // 2
    assert len(judge(noisy["2n"], Params()).violations) > N // 2


def test_trace_building_is_linear(noisy):
    """``show``'s conversation view: naming a headerless datagram's ends is a lookup."""
    files = {trace_mod.__file__}
    small, big = (list(open_capture(noisy[k]).datagrams()) for k in ("n", "2n"))
    work = [lines_run(files, lambda d=d: Trace(d)) for d in (small, big)]
    assert work[1] / work[0] <= LINEAR, work


def test_headerless_datagrams_keep_their_owners(noisy):
    """The lookup names the same lifelines the scan did: the first node (in order of
    appearance) that sent from the address, else the address."""
    trace = Trace(open_capture(noisy["n"]).datagrams())

    def scan(addr: Any) -> str | None:
        return next((str(n.id) for n in trace.nodes.values() if addr in n.addresses), None)

    headerless = [e for e in trace.entries if e.header is None]
    assert headerless
    for e in headerless:
        assert e.src == (scan(e.dgram.src_addr) or trace_mod.lifeline_of(None, e.dgram.src_addr))
        assert e.dst == (scan(e.dgram.dst_addr) or trace_mod.lifeline_of(None, e.dgram.dst_addr))


def test_diff_is_linear(noisy):
    """Two unrelated noisy captures: thousands of conversations and divergences."""
    files = {diff_mod.__file__}
    sides = {k: diff_mod.load_side(p) for k, p in noisy.items()}
    work = [lines_run(files, lambda a=a, b=b: diff_mod.diff_sides(sides[a], sides[b]))
            for a, b in (("n", "n-other"), ("2n", "2n-other"))]
    result = diff_mod.diff_sides(sides["2n"], sides["2n-other"])
    assert len(result.divergences) > N and len(sides["2n"].conversations) > N // 4
    assert work[1] / work[0] <= LINEAR, work


def test_check_report_is_linear_and_its_terminal_output_bounded(noisy, tmp_path, capsys):
    files = {check_mod.__file__}
    work, lines = [], []
    for k in ("n", "2n"):
        work.append(lines_run(files, lambda k=k: main(["check", str(noisy[k]), "--json", str(tmp_path / "c.json")])))
        lines.append(len(capsys.readouterr().out.splitlines()))
    assert work[1] / work[0] <= LINEAR, work
    assert lines[1] <= lines[0] + 10, lines  # a few more nodes and rules, never more violations


# ---------------------------------------------------------------- the summarised terminal report
ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 1, 16, 1, 1, 3, 0, 1)


def drones_commanding(path: Path, n: int) -> Path:
    """``n`` WP_Ons sent by drone 1 to the manager: n MCP-HDR-5 violations (a drone sends only
    Mission_Ready and ACK)."""
    with McapRecorder(path, local=("127.0.0.1", 7889)) as rec:
        for i in range(n):
            rec.datagram("rx", encode(Message(0, 1, 100 + i, Action.WP_ON, ITEM)), ("127.0.0.1", 7890),
                         1_800_000_000_000_000_000 + i * 1_000_000)
    return path


def test_terminal_summarises_each_rule_with_its_first_examples(tmp_path, capsys):
    cap = drones_commanding(tmp_path / "d.mcap", 40)
    out_json = tmp_path / "c.json"
    assert main(["check", str(cap), "--select", "MCP-HDR-5", "--json", str(out_json)]) == 1
    out = capsys.readouterr().out
    doc = json.loads(out_json.read_text())
    check_mod.validate_json(doc)
    assert len(doc["violations"]) == 40 and {v["rule"] for v in doc["violations"]} == {"MCP-HDR-5"}
    assert "Violations (40)" in out
    assert f"40 violations of MCP-HDR-5; the first {check_mod.EXAMPLES}:" in out
    shown = [v for v in doc["violations"][:check_mod.EXAMPLES]]
    for v in shown:  # the first ones in full: when, expected, actual, evidence
        assert f"node 1 at +{v['t']:.6f} s" in out and v["evidence"][0]["summary"] in out
    assert out.count("    expected: ") == check_mod.EXAMPLES
    assert f"seq {100 + check_mod.EXAMPLES} " not in out  # the next one is only counted
    assert f"… and {40 - check_mod.EXAMPLES} more; all of them in {out_json}" in out


def test_terminal_shows_every_violation_of_a_rule_with_few(tmp_path, capsys):
    cap = drones_commanding(tmp_path / "d.mcap", check_mod.EXAMPLES)
    assert main(["check", str(cap), "--select", "MCP-HDR-5"]) == 1
    out = capsys.readouterr().out
    assert out.count("    expected: ") == check_mod.EXAMPLES and "more" not in out and "violations of" not in out


def test_streamed_json_is_the_document(tmp_path):
    """``--json`` streams the violations, one per line; the file is the document of
    ``to_json(...)``, and apart from the violations' lines it is ``json.dumps(..., indent=2)``'s
    text (with violations and without)."""
    for n in (0, 5):
        cap = drones_commanding(tmp_path / f"d{n}.mcap", n) if n else write_noisy(tmp_path / "q.mcap", 0)
        j = judge(cap, Params())
        evidence = evidence_of(j, {i for v in j.shown_violations for i in evidence_indexes(v)})
        out = tmp_path / f"c{n}.json"
        check_mod.write_json(str(out), j, evidence)
        doc = check_mod.to_json(j, evidence)
        text = out.read_text()
        assert json.loads(text) == json.loads(json.dumps(doc)), "the file is the document"
        lines = text.splitlines()
        shown = [x for x in lines if x.startswith('    {"rule": ')]
        assert len(shown) == len(j.shown_violations) == n, "one line per violation"
        doc["violations"] = []
        pretty = json.dumps(doc, indent=2).splitlines()
        rest = [x for x in lines if x not in shown]
        if n:
            pretty[pretty.index('  "violations": [],')] = '  "violations": ['
            pretty.insert(pretty.index('  "violations": [') + 1, "  ],")
        assert rest == pretty

"""One judge for a node the loaded host made late (MCP-RTX-3, ``judge.spacing``): the run
delay the driver read at each of the node's copies goes into the capture (``run_delay_ns`` of
``/mcp/rx``), comes back out of the reader, and ``mcp-capture check`` of the file gives the live
monitor's verdict -- the late copy excused when the node was kept off the CPU, not otherwise."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from mcp_conform.captures.cli import main
from mcp_conform.harness.driver import TargetDriver
from mcp_conform.judge.judging import Params, judge
from mcp_conform.judge.run_monitor import RunMonitor
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.traceio.reader import Datagram, open_capture
from mcp_conform.traceio.recorder import NODE_METADATA, McapRecorder, run_metadata

NODE, LISTEN = ("127.0.0.1", 17001), ("127.0.0.1", 17889)
MS = 10**6
GAPS_MS = [200, 200, 280, 200]  # the third gap 80 ms late: outside 200 ± 55 ms


def _run(path, starved_ms: int | None) -> list[tuple[str, int]]:
    """The node's Mission_Ready five times, ACKed after the last, through the driver to the
    capture and the run's monitor; ``starved_ms`` of run delay accrue before the late copy
    (None: none known, attach mode). Returns the live monitor's violations."""
    rec = McapRecorder(path, metadata=run_metadata("mcp-conform", role="drone"), local=LISTEN)
    rec.add_metadata(NODE_METADATA, {"id": 1, "address": f"{NODE[0]}:{NODE[1]}", "complete": "true"})
    mon = RunMonitor(rto=0.2, ack_window=0.25, broadcast_id=int(SPEC.protocol["broadcast_id"]),
                     node_id=1, node_addr=NODE)
    mon.listen = LISTEN
    drv = TargetDriver(NODE, LISTEN)
    drv.auto_ack = lambda d: False
    drv.add_observer(rec.datagram)
    drv.add_observer(mon.observe)
    delay = [5 * MS]
    if starved_ms is not None:
        drv.run_delay = lambda: delay[0]
    ready = encode(Message(0, 1, 7, Action.MISSION_READY))
    t = time.time_ns() - 5 * 10**9  # kernel receive times the driver believes (recent)
    drv._arrive(ready, NODE, t)
    for k, gap in enumerate(GAPS_MS):
        t += gap * MS
        if k == 2:
            delay[0] += (starved_ms or 0) * MS
        drv._arrive(ready, NODE, t)
    t += 5 * MS
    drv._notify("tx", encode(Message(1, 0, 3, Action.ACK, 7)), NODE, t)
    mon.finish(t + 10 * 10**9)
    rec.close()
    return sorted((v.rule, v.node) for v in mon.violations())


@pytest.mark.parametrize(("starved_ms", "rtx3"), [(70, False), (0, True), (None, True)],
                         ids=["starved", "not-starved", "unknown"])
def test_check_of_the_capture_gives_the_live_verdict(tmp_path, starved_ms, rtx3):
    path = tmp_path / "run.mcap"
    live = _run(path, starved_ms)
    assert (("MCP-RTX-3", 1) in live) is rtx3, live
    dgrams = [r for r in open_capture(path) if isinstance(r, Datagram)]
    assert len(dgrams) == 6
    expected = [None] * 5 if starved_ms is None else [5 * MS] * 3 + [(5 + starved_ms) * MS] * 2
    assert [d.run_delay_ns for d in dgrams] == [*expected, None]  # the runner's ACK: none
    out = tmp_path / "check.json"
    main(["check", str(path), "--rto", "0.2", "--ack-window", "0.25", "--json", str(out)])
    doc = json.loads(out.read_text())
    assert sorted((v["rule"], v["node"]) for v in doc["violations"]) == live


@pytest.mark.parametrize(("starved_ms", "rtx3"), [(70, False), (0, True), (None, True)],
                         ids=["starved", "not-starved", "unknown"])
def test_a_soak_nodes_view_is_judged_with_its_run_delay(tmp_path, starved_ms, rtx3):
    """``mcp-soak``'s medium records each node's view (``soak.medium``): the node's own
    datagrams as ``tx``, with its run delay; the soak's judge excuses the same late copy."""
    path = tmp_path / "mission.drone1.mcap"
    rec = McapRecorder(path, library="mcp-soak", metadata=run_metadata(
        "mcp-soak", role="drone", node_id=1, complete="true", parameters={"rto": 0.2}), local=NODE)
    ready = encode(Message(0, 1, 7, Action.MISSION_READY))
    t, delay = 1_700_000_000 * 10**9, 5 * MS
    rec.datagram("tx", ready, LISTEN, t, run_delay=None if starved_ms is None else delay)
    for k, gap in enumerate(GAPS_MS):
        t += gap * MS
        delay += (starved_ms or 0) * MS if k == 2 else 0
        rec.datagram("tx", ready, LISTEN, t, run_delay=None if starved_ms is None else delay)
    rec.datagram("rx", encode(Message(1, 0, 3, Action.ACK, 7)), LISTEN, t + 5 * MS)
    rec.close()
    j = judge(path, Params(rto=0.2, ack_window=0.25))
    assert any(v.rule == "MCP-RTX-3" and v.node == 1 for v in j.violations) is rtx3, j.violations


DATA = Path(__file__).with_name("data")


@pytest.mark.parametrize("complete", [False, True])
def test_the_run_delay_read_as_the_node_was_stopped_is_weighed_offline_as_live(complete):
    """A real run of the sample node's rtx-stop-on-any-ack beside 14 CPU burners (the matrix's
    test_mutants, which failed so in fresh-clone CI runs 12, 14 and 15): its Mission_Ready's
    third copy went unretransmitted for 0.705 s after the wrong ACKs, and the node's run delay,
    read as the runner stopped it (``RUN_DELAY_METADATA``, after its last datagram), explains
    that (judge.veto): the live monitor vetoed MCP-RTX-2. ``check`` ended its view at the last
    datagram, left that reading outside it and failed MCP-RTX-2; its view now ends at the
    reading, and it gives the live monitor's verdict on every rule (the file's .live.json)."""
    live = json.loads((DATA / "rtx2-stop-reading.live.json").read_text())
    j = judge(DATA / "rtx2-stop-reading.mcap", Params(complete=complete))
    assert {str(n): v for n, v in j.verdicts.items()} == live["rules"]
    assert j.verdicts[1]["MCP-RTX-2"] == "passed" and ["MCP-RTX-2", 1] in live["vetoed"]
    assert sorted([v.rule, v.node] for v in j.violations) == sorted(live["violations"])
    assert any("MCP-RTX-2 not failed" in n for n in j.notes), j.notes

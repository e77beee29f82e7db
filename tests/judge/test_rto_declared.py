"""MCP-RTX-1 on a lone copy at the run's declared retransmission timeout (issue 38, the
simulator's ``rtx-none`` and ``manager-rtx-none`` models: a sender that never retransmits).

The rule as observed: "at least 3 copies while the ACK is withheld". Where ``--rto`` is only
the runner's assumption, a lone copy's next one is not overdue before the description's 5 s
(a correct node retransmitting every 1.5 s under ``--rto 0.2``, issue 18 item 10). Where the
run set the node's timeout itself -- the runner's embedded reference node, the simulator's
models -- it declares it (``Monitor(rto_declared=True)``, the capture's run parameters
``rto_declared``), and a lone copy whose ACK is withheld past the time its third copy was due
at that pace (two gaps of ``rto`` and MCP-RTX-3's tolerance, plus the timestamp jitter) is
the sender's MCP-RTX-1. ``mcp-capture check`` of the run's capture gives the live verdict
(one judge): the declaration comes back out of the capture's parameters."""

from __future__ import annotations

import json
import time
from pathlib import Path

import pytest

from mcp_conform.captures.cli import main
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import TargetDriver
from mcp_conform.judge.monitor import TESTER, Monitor
from mcp_conform.judge.run_monitor import RunMonitor
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.traceio.recorder import NODE_METADATA, McapRecorder, run_metadata

NS, MS = 10**9, 10**6
RTO, WINDOW = 0.2, 0.25
NODE, LISTEN = ("127.0.0.1", 17011), ("127.0.0.1", 17899)
READY = encode(Message(0, 1, 7, Action.MISSION_READY))


def _lone_ready(ack_after_s: float | None, end_s: float = 1.0) -> list[tuple[int, str, bytes]]:
    """Drone 1's Mission_Ready sent once; the runner's ACK ``ack_after_s`` later (None: never);
    a broadcast of the runner's at ``end_s``: the trace goes on. ``(t_ns, direction, data)``."""
    t = 100 * NS
    out = [(t, "rx", READY)]
    if ack_after_s is not None:
        out.append((t + int(ack_after_s * NS), "tx", encode(Message(1, 0, 3, Action.ACK, 7))))
    out.append((t + int(end_s * NS), "tx", encode(Message(0xFFFF, 0, 4, Action.WP_OFF))))
    return out


def _monitor(records: list[tuple[int, str, bytes]], declared: bool) -> Monitor:
    m = Monitor(rto=RTO, ack_window=WINDOW, complete=True, rto_declared=declared)
    for t, way, data in records:
        m.datagram(t, NODE if way == "rx" else LISTEN, LISTEN if way == "rx" else NODE, data,
                   1 if way == "rx" else TESTER)
    m.finish(records[-1][0])
    return m


def test_a_lone_copy_withheld_past_its_third_copys_time_is_rtx1_where_the_rto_is_declared():
    m = _monitor(_lone_ready(None), declared=True)
    (v,) = m.violations
    assert (v.rule, v.node) == ("MCP-RTX-1", 1) and "1 copy of Mission_Ready" in v.actual
    assert m.verdicts()[1]["MCP-RTX-1"] == "failed"


def test_only_assumed_the_same_copy_waits_for_the_descriptions_timeout():
    m = _monitor(_lone_ready(None), declared=False)
    assert m.violations == [] and m.verdicts()[1]["MCP-RTX-1"] == "not_observed"


@pytest.mark.parametrize("ack_after_s", [0.3, 0.5])
def test_an_ack_before_the_third_copy_was_due_proves_nothing(ack_after_s: float):
    """Two gaps of 0.2 s at +20 % and 45 ms of jitter: 0.525 s. The ACK at 0.3 s or 0.5 s came
    before a third copy was due: at most two were owed, and the rule is observed as three."""
    m = _monitor(_lone_ready(ack_after_s), declared=True)
    assert m.violations == [] and m.verdicts()[1]["MCP-RTX-1"] == "passed"


def test_an_ack_after_it_does_not_undo_it():
    m = _monitor(_lone_ready(0.6), declared=True)
    assert [(v.rule, v.node) for v in m.violations] == [("MCP-RTX-1", 1)]


def test_a_trace_that_ends_before_then_proves_nothing():
    m = _monitor(_lone_ready(None, end_s=0.5), declared=True)
    assert m.violations == []


def test_the_runner_declares_only_the_timeout_it_gave_its_embedded_node():
    from mcp_conform.harness.session_base import EMBEDDED_RTO

    assert RunConfig(embedded=True, rto=EMBEDDED_RTO).rto_declared
    assert RunConfig(embedded=True, rto=EMBEDDED_RTO).parameters()["rto_declared"] is True
    assert not RunConfig(embedded=True, rto=1.0).rto_declared  # --rto 1 given: only assumed
    assert not RunConfig(spawn="node --rto 0.2", rto=EMBEDDED_RTO).rto_declared  # the runner cannot know
    assert "rto_declared" not in RunConfig(spawn="node", rto=EMBEDDED_RTO).parameters()


def _run(path: Path, declared: bool) -> list[tuple[str, int]]:
    """The run: the driver's datagrams to its capture (the run's parameters in its metadata,
    as ``RunConfig.parameters`` writes them) and to its monitor; the live violations."""
    params = {"rto": RTO, "ack_window": WINDOW, **({"rto_declared": True} if declared else {})}
    rec = McapRecorder(path, metadata=run_metadata("mcp-conform", role="drone", parameters=params),
                       local=LISTEN)
    rec.add_metadata(NODE_METADATA, {"id": 1, "address": f"{NODE[0]}:{NODE[1]}", "complete": "true"})
    mon = RunMonitor(rto=RTO, ack_window=WINDOW, broadcast_id=int(SPEC.protocol["broadcast_id"]),
                     node_id=1, node_addr=NODE, rto_declared=declared)
    mon.listen = LISTEN
    drv = TargetDriver(NODE, LISTEN)
    drv.auto_ack = lambda d: False
    drv.add_observer(rec.datagram)
    drv.add_observer(mon.observe)
    t0 = time.time_ns() - 5 * NS  # kernel receive times the driver believes (recent)
    last = t0
    for t, way, data in _lone_ready(None):
        last = t0 + t - 100 * NS
        if way == "rx":
            drv._arrive(data, NODE, last)
        else:
            drv._notify("tx", data, NODE, last)
    mon.finish(last)
    rec.close()
    return sorted((v.rule, v.node) for v in mon.violations())


@pytest.mark.parametrize("declared", [True, False], ids=["declared", "assumed"])
def test_check_of_the_capture_gives_the_live_verdict(tmp_path: Path, declared: bool):
    path = tmp_path / "run.mcap"
    live = _run(path, declared)
    assert live == ([("MCP-RTX-1", 1)] if declared else [])
    out = tmp_path / "check.json"
    main(["check", str(path), "--json", str(out)])  # the rto, and whether declared: the capture's
    doc = json.loads(out.read_text())
    assert sorted((v["rule"], v["node"]) for v in doc["violations"]) == live
    assert doc["parameters"]["rto"] == RTO

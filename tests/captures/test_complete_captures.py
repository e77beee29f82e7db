"""Complete and lossy captures (issue 18 item 8): MCP-RTX-1 is seen passed once the copies it
asks for are in the trace (any trace), failed on a complete trace when later traffic proves
the next copy overdue, not judged when the trace just ends; ``mcp-node --capture`` files say
they are complete and are judged so; on a lossy trace what no loss explains still counts
(an ACK addressed to its own sender's ID: MCP-ACK-3)."""

from __future__ import annotations

import pytest

from judge.judging import Params, judge
from judge.monitor import Monitor
from spec.codec import Action, Message, encode
from traceio.recorder import McapRecorder, run_metadata

DRONE, MANAGER = ("127.0.0.1", 40002), ("127.0.0.1", 40001)
READY = encode(Message(0, 3, 5, Action.MISSION_READY))
MS = 1_000_000


def _ready_copies(m: Monitor, n: int, gap_ms: int = 200) -> list:
    out = []
    for k in range(n):
        out += m.datagram(k * gap_ms * MS, DRONE, MANAGER, READY)
    return out


@pytest.mark.parametrize("complete", [False, True])
def test_six_copies_of_an_unacked_message_pass_rtx1_when_the_trace_ends(complete):
    m = Monitor(rto=0.2, ack_window=0.25, complete=complete)
    out = _ready_copies(m, 6) + m.finish()
    assert [v.rule for v in out if v.rule == "MCP-RTX-1"] == []
    assert m.verdicts()[3]["MCP-RTX-1"] == "passed"


def test_retransmission_stopping_while_time_passes_fails_rtx1_on_a_complete_trace():
    m = Monitor(rto=0.2, ack_window=0.25, complete=True)
    out = _ready_copies(m, 2)
    later = encode(Message(7, 0, 1, Action.START_MISSION))  # other traffic, 3 s on
    out += m.datagram(3000 * MS, MANAGER, ("127.0.0.1", 40007), later) + m.finish()
    (v,) = [v for v in out if v.rule == "MCP-RTX-1"]
    assert v.node == 3 and [i for i, _ in v.evidence] == [0, 1]
    assert m.verdicts()[3]["MCP-RTX-1"] == "failed"


@pytest.mark.parametrize("complete", [False, True])
def test_retransmission_stopping_at_the_end_of_the_trace_is_not_judged(complete):
    m = Monitor(rto=0.2, ack_window=0.25, complete=complete)
    out = _ready_copies(m, 2) + m.finish()
    assert "MCP-RTX-1" not in {v.rule for v in out}
    assert m.verdicts()[3]["MCP-RTX-1"] == "not_observed"


@pytest.mark.parametrize("complete", [False, True])
def test_an_ack_addressed_to_its_own_senders_id_is_a_violation_on_any_trace(complete):
    m = Monitor(rto=0.2, ack_window=0.25, complete=complete)
    out = m.datagram(0, MANAGER, DRONE, encode(Message(1, 0, 4, Action.START_MISSION)))
    out += m.datagram(10 * MS, DRONE, MANAGER, encode(Message(1, 1, 9, Action.ACK, 4)))
    out += m.finish()
    assert [(v.rule, v.node) for v in out if v.rule.startswith("MCP-ACK")] == [("MCP-ACK-3", 1)]


def _node_capture(path, copies: int, complete: str | None = "true", rto: float | None = 0.2) -> None:
    """What ``mcp-node drone --capture`` writes for a drone whose Mission_Ready goes unACKed."""
    values = {"complete": complete} if complete else {}
    if rto is not None:
        values["parameters"] = {"rto": rto}
    rec = McapRecorder(path, library="mcp-node",
                       metadata=run_metadata("mcp-node", role="drone", node_id=3, **values), local=DRONE)
    for k in range(copies):
        rec.datagram("tx", READY, MANAGER, k * 200 * MS)
    rec.close()


def test_a_node_capture_is_judged_complete_with_the_nodes_timeout(tmp_path):
    path = tmp_path / "drone.mcap"
    _node_capture(path, 6)
    j = judge(path, Params())
    assert j.params.complete and j.params.rto == 0.2 and "rto" in j.params.from_capture
    assert j.verdicts[3]["MCP-RTX-1"] == "passed" and j.violations == []


def test_a_node_capture_without_its_record_stays_lossy(tmp_path):
    path = tmp_path / "drone.mcap"
    _node_capture(path, 2, complete=None, rto=None)
    j = judge(path, Params())
    assert not j.params.complete and j.params.rto == 5.0

"""Complete and lossy captures (issue 18 item 8): MCP-RTX-1 is seen passed once the copies it
asks for are in the trace (any trace), failed on a complete trace when later traffic proves
the next copy overdue, not judged when the trace just ends; ``mcp-node --capture`` files say
they are complete and are judged so; on a lossy trace what no loss explains still counts
(an ACK addressed to its own sender's ID: MCP-ACK-3)."""

from __future__ import annotations

import pytest

from mcp_conform.judge.judging import Params, judge
from mcp_conform.judge.monitor import Monitor
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.traceio.recorder import McapRecorder, run_metadata

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


def test_a_node_capture_is_complete_for_its_own_exchanges_only():
    """Drones sharing a port (``--reuse-port``) each overhear the manager's commands to the
    others, never the others' ACKs (sent to the manager): drone 1's own capture proves
    nothing about the manager's exchanges with drone 2 (no MCP-BLK-1 / MCP-RTX-1 against the
    manager), while its own exchanges are still judged complete (a retransmission that
    stops unACKed fails MCP-RTX-1)."""
    d1, d2 = ("127.0.0.1", 40011), ("127.0.0.1", 40012)
    m = Monitor(rto=0.2, ack_window=0.25, complete=True, party=1)
    out = m.datagram(0, MANAGER, d2, encode(Message(2, 0, 10, Action.START_MISSION)))  # overheard
    out += m.datagram(5 * MS, MANAGER, d1, encode(Message(1, 0, 11, Action.START_MISSION)))
    out += m.datagram(6 * MS, d1, MANAGER, encode(Message(0, 1, 70, Action.ACK, 11)))
    ready = encode(Message(0, 1, 71, Action.MISSION_READY))  # drone 1's own, two copies, unACKed
    out += m.datagram(10 * MS, d1, MANAGER, ready) + m.datagram(210 * MS, d1, MANAGER, ready)
    out += m.datagram(4000 * MS, MANAGER, d2, encode(Message(2, 0, 12, Action.WP_OFF)))  # time passes
    out += m.finish()
    assert sorted((v.rule, v.node) for v in out) == [("MCP-RTX-1", 1)], out
    whole = Monitor(rto=0.2, ack_window=0.25, complete=True)  # the same, claimed complete for all
    seen = []
    for t, a, b, data in [(0, MANAGER, d2, encode(Message(2, 0, 10, Action.START_MISSION))),
                          (5 * MS, MANAGER, d1, encode(Message(1, 0, 11, Action.START_MISSION)))]:
        seen += whole.datagram(t, a, b, data)
    assert "MCP-BLK-1" in {v.rule for v in seen + whole.finish()}

"""MCP-ACK-2 on an ACK that names a number no datagram carried (issue 38, the simulator's
``ack-previous-seq`` model: its first ACK names 0, "the message it ACKed before"). "An ACK's
payload is exactly 2 bytes: the acknowledged message's sequence number" (docs/spec.md): on a
trace complete for the ACKing node, an ACK naming a number that no datagram in the trace
carried up to it acknowledges no message, so its payload is not the acknowledged message's
number -- whatever else is true. Proven only there: a number some datagram carried (another
node's message, an ACK, a malformed datagram) may be what it answers wrongly addressed
(MCP-ACK-3/4/6's), a lossy trace may miss the message, and a copy read within the recorder's
reorder grace after the ACK (``seq_reorder_grace_s``) is one it may answer.

The same judge reads the node's capture (``mcp-capture check``): the last test."""

from __future__ import annotations

from mcp_conform.judge.monitor import TESTER, Monitor
from mcp_conform.spec.codec import Action, build_datagram

NS = 1_000_000_000
MGR = ("127.0.0.1", 7889)
DRONE = ("127.0.0.11", 7890)
READY, START, WP_LIST, ACK = (int(Action.MISSION_READY), int(Action.START_MISSION), int(Action.WP_LIST),
                              int(Action.ACK))


def ack(src: int, dst: int, seq: int, named: int) -> bytes:
    return build_datagram(dst, src, seq, ACK, named.to_bytes(2, "big"))


def drone_view(first_named: int, *, end_s: float = 4.0, complete: bool = True, party: int | None = 1,
               late_start_s: float | None = None) -> list[tuple[int, object, object, bytes, object]]:
    """Drone 1's own view of the start of a mission: its Mission_Ready, the manager's ACK and
    Start_Mission (seq 500), its ACK of Start_Mission naming ``first_named``, the right ACK of
    Start_Mission's second copy; ``late_start_s``: Start_Mission recorded that much after the
    ACK (a recorder's order)."""
    t = 100 * NS
    out = [(t, DRONE, MGR, build_datagram(0, 1, 7000, READY), None),
           (t + 1_000_000, MGR, DRONE, ack(0, 1, 499, 7000), None)]
    start_t = t + 2_000_000 if late_start_s is None else t + 3_000_000 + int(late_start_s * NS)
    out.append((start_t, MGR, DRONE, build_datagram(1, 0, 500, START), None))
    out.append((t + 3_000_000, DRONE, MGR, ack(1, 0, 7001, first_named), None))
    out.append((start_t + NS, MGR, DRONE, build_datagram(1, 0, 500, START), None))
    out.append((start_t + NS + 1_000_000, DRONE, MGR, ack(1, 0, 7002, 500), None))
    out.sort(key=lambda r: r[0])
    return out


def judge(records, *, complete: bool = True, party: int | None = 1, end_s: float = 4.0) -> tuple[dict, list]:
    m = Monitor(rto=1.0, ack_window=0.5, drones=(1,), challenge=1, complete=complete, party=party)
    found = []
    for t, src, dst, data, origin in records:
        found += m.datagram(t, src, dst, data, origin)
    found += m.finish(records[0][0] + int(end_s * NS))
    return m.verdicts().get(1, {}), [v for v in m.violations if v.node == 1]


def test_an_ack_naming_a_number_no_datagram_carried_is_mcp_ack_2():
    verdicts, found = judge(drone_view(0))
    assert verdicts["MCP-ACK-2"] == "failed"
    (v,) = [v for v in found if v.rule == "MCP-ACK-2"]
    assert "names 0" in v.actual and "no datagram" in v.actual
    assert {v.rule for v in found} == {"MCP-ACK-2"}


def test_the_right_number_passes():
    verdicts, found = judge(drone_view(500))
    assert verdicts["MCP-ACK-2"] == "passed" and found == []


def test_a_number_another_datagram_carried_is_not_proven_ack_2():
    """The manager's own ACK took seq 499: an ACK naming it is an ACK of an ACK (MCP-ACK-6),
    not a number of nothing."""
    verdicts, found = judge(drone_view(499))
    assert "MCP-ACK-2" not in {v.rule for v in found}


def test_a_copy_recorded_just_after_the_ack_may_be_what_it_answers():
    """Start_Mission recorded 0.3 s after an ACK naming it (a recorder's order of two sockets):
    the ACK answers it, nothing is proven."""
    verdicts, found = judge(drone_view(500, late_start_s=0.3))
    assert "MCP-ACK-2" not in {v.rule for v in found}


def test_not_proven_where_the_trace_may_miss_the_message():
    for kw in ({"complete": False}, {"party": 0}):
        _, found = judge(drone_view(0), **kw)
        assert "MCP-ACK-2" not in {v.rule for v in found}, kw


def test_a_complete_trace_that_ends_within_the_grace_is_judged_whole():
    """The trace ends 0.5 s after the ACK: it holds every datagram, so none came after."""
    verdicts, _ = judge(drone_view(0)[:4], end_s=0.5)
    assert verdicts["MCP-ACK-2"] == "failed"
    verdicts, _ = judge(drone_view(500, late_start_s=0.3)[:4], end_s=0.5)
    assert verdicts["MCP-ACK-2"] == "passed"


def test_the_runner_as_the_manager_the_same():
    """The live monitor's view in the drone role: the runner's datagrams are the harness's."""
    recs = [(t, s, d, data, TESTER if s == MGR else 1) for t, s, d, data, _ in drone_view(0)]
    verdicts, _ = judge(recs, party=None)
    assert verdicts["MCP-ACK-2"] == "failed"

"""conformance.manager_case / manager_monitor: the judgements over a recorded mission, on
synthetic traffic (no sockets)."""

from __future__ import annotations

from mcp_conform.conformance.manager_case import (
    abandoned,
    awaiting_until,
    messages,
    runner_ack_time,
)
from mcp_conform.harness.driver import Datagram, Sent, read_header
from mcp_conform.harness.drone_players import Mission
from mcp_conform.harness.manager_monitor import monitor_mission
from mcp_conform.spec.codec import PREAMBLE, Action, DecodeError, Message, decode, encode

ADDR = ("127.0.0.1", 7889)


def rx(i: int, t: float, data: bytes) -> Datagram:
    try:
        msg, err = decode(data), None
    except DecodeError as exc:
        msg, err = None, exc
    return Datagram(i, t, int(t * 1e9), data, ADDR, msg, err, read_header(data), data[:9] == PREAMBLE)


def cmd(dst: int, seq: int, action: Action, payload=None) -> bytes:
    return encode(Message(dst, 0, seq, action, payload))


def ack(t: float, drone: int, seq: int, own: int) -> Sent:
    return Sent(t, int(t * 1e9), encode(Message(0, drone, own, Action.ACK, seq)), ADDR, 0, drone, own, int(Action.ACK))


def mission(datagrams: list[bytes], times: list[float]) -> Mission:
    m = Mission("main", (1,), 1, None, None, t0=0.0, t_end=times[-1] + 1.0)
    m.rx = [rx(i, t, d) for i, (d, t) in enumerate(zip(datagrams, times, strict=True))]
    return m


def test_copies_group_under_their_message_and_an_ack_ends_the_wait():
    start = cmd(1, 10, Action.START_MISSION)
    m = mission([start, start, start, cmd(1, 11, Action.END_MISSION)], [0.0, 0.2, 0.4, 0.5])
    m.acks[(1, 10)] = ack(0.45, 1, 10, 500)
    m.acks[(1, 11)] = ack(0.51, 1, 11, 501)
    msgs = messages(m)
    assert [len(x.copies) for x in msgs] == [3, 1] and msgs[0].action == Action.START_MISSION
    assert runner_ack_time(m, msgs[0]) == 0.45
    assert abandoned(m, 0.2) == set()


def test_a_retransmission_with_a_new_seq_is_a_copy_until_acked():
    m = mission([cmd(1, 10, Action.START_MISSION), cmd(1, 11, Action.START_MISSION)], [0.0, 0.2])
    assert len(messages(m)) == 1
    m.acks[(1, 10)] = ack(0.1, 1, 10, 500)
    assert len(messages(m)) == 2  # after the ACK, the same bytes again are a new message


def test_broadcasts_with_new_seqs_are_new_messages_not_copies():
    """A broadcast is never ACKed: the same bytes again with a new seq are a new message (MCP-DUP-2),
    not a copy (MCP-RTX-4 warned 'sent 6 times' of six broadcast WP_Offs, each sent once with
    its own seq: H-cmanager's C manager); a broadcast sent again with its seq is a copy."""
    bcast = 0xFFFF
    offs = [cmd(bcast, 20 + n, Action.WP_OFF) for n in range(3)]
    m = mission([*offs, offs[2]], [0.0, 0.2, 0.4, 0.6])
    assert [len(x.copies) for x in messages(m)] == [1, 1, 2]


def test_a_wrong_source_ack_taken_by_the_next_unicast_is_rtx_2s_not_blk_1():
    """The runner withholds drone 1's Start_Mission, then sends the wrong-seq ACK from drone 1
    and a wrong-source ACK from drone 2 (naming drone 1's seq). A manager that takes any ACK
    from the destination moves on to drone 2 and, if drone 2's stale ACK reaches it after that,
    at once to drone 3 (a loaded CI run): drone 2's Start_Mission was answered by that ACK
    (taking it is MCP-RTX-2's), so it no longer awaits its ACK when drone 3's goes out."""
    s1, s2, s3 = (cmd(d, 10 + d, Action.START_MISSION) for d in (1, 2, 3))
    m = mission([s1, s1, s1, s2, s3], [0.0, 0.2, 0.4, 0.5, 0.5001])
    m.drones = (1, 2, 3)
    m.withheld.drone = 1
    m.withheld.wrong_acks = [ack(0.45, 1, (11 + 0x8000) & 0xFFFF, 500), ack(0.4501, 2, 11, 600)]
    m.acks[(3, 13)] = ack(0.6, 3, 13, 700)
    first, second, third = messages(m)
    assert runner_ack_time(m, first) == 0.45  # the wrong-seq ACK, while it awaited
    assert runner_ack_time(m, second) == 0.5  # the stale wrong-source ACK, at once
    assert awaiting_until(m, second, 0.2) == 0.5 < third.first.t
    # a wrong ACK sent before an earlier command to the same drone was that command's
    m2 = mission([s2, cmd(2, 20, Action.END_MISSION)], [0.5, 0.9])
    m2.withheld.wrong_acks = [ack(0.4501, 2, 11, 600)]
    m2.acks[(2, 12)] = ack(0.6, 2, 12, 601)
    assert [runner_ack_time(m2, x) for x in messages(m2)] == [0.5, None]


def _limit_or_taken(second: str) -> Mission:
    """Drone 1's Start_Mission in 3 copies, the wrong ACKs right after the third, no copy after
    them, then drone 2's mission; MCP-RTX-2's second observation (``withheld_again``, drone 3's
    Start_Mission) as ``second`` says: "none" made, "kept" (a copy after its wrong ACKs),
    "taken" (none after them)."""
    s1, s2, s3 = (cmd(d, 10 + d, Action.START_MISSION) for d in (1, 2, 3))
    e2 = cmd(2, 20, Action.END_MISSION)
    m = mission([s1, s1, s1, s2, s3, s3, *([s3] if second == "kept" else []), e2],
                [0.0, 0.2, 0.4, 0.6, 0.61, 0.81, *([1.01] if second == "kept" else []), 1.2])
    m.drones = (1, 2, 3)
    w = m.withheld
    w.drone, w.copies, w.wrong_ack_wait = 1, m.rx[:3], 0.7
    w.wrong_acks = [ack(0.401, 1, (11 + 0x8000) & 0xFFFF, 500), ack(0.4011, 2, 11, 600)]
    m.acks[(2, 12)] = ack(0.601, 2, 12, 601)
    m.acks[(2, 20)] = ack(1.201, 2, 20, 602)
    if second != "none":
        a = m.withheld_again
        a.drone, a.copies, a.wrong_ack_wait = 3, m.rx[4:6], 0.7
        a.wrong_acks = [ack(0.811, 3, (13 + 0x8000) & 0xFFFF, 700), ack(0.8111, 1, 13, 501)]
        a.copy_after_wrong_acks = m.rx[6] if second == "kept" else None
    return m


def test_a_given_up_start_mission_is_told_by_the_second_observation_not_by_when():
    """A retry limit of 2 and a manager that takes a wrong ACK both stop the first Start_Mission
    right after the wrong ACKs. The second observation kept: the wrong ACKs answered nothing,
    drone 1 was given up (excused from the flow rules); taken: they answered it (drone 1 owed
    its mission: MCP-FLOW-3's); none made: drone 1, sent nothing after them, is excused (one
    explanation gives it up) though its Start_Mission's answer stays the wrong ACK (BLK-1/3)."""
    kept, taken, none = (_limit_or_taken(k) for k in ("kept", "taken", "none"))
    assert runner_ack_time(kept, messages(kept)[0]) is None  # the wrong ACKs ended nothing
    assert 1 in abandoned(kept, 0.2)
    assert runner_ack_time(taken, messages(taken)[0]) == 0.401 and 1 not in abandoned(taken, 0.2)
    assert runner_ack_time(none, messages(none)[0]) == 0.401 and 1 in abandoned(none, 0.2)


def test_a_manager_that_stopped_retransmitting_gave_up():
    start = cmd(1, 10, Action.START_MISSION)
    m = mission([start, start], [0.0, 0.2])
    m.acks[(1, 10)] = ack(2.0, 1, 10, 500)  # our ACK long after its last copy
    assert abandoned(m, 0.2) == {1}


def test_the_monitor_judges_the_managers_traffic():
    bad = b"XX" + cmd(1, 10, Action.START_MISSION)[2:]
    m = mission([cmd(1, 9, Action.START_MISSION), bad], [0.0, 0.1])
    m.acks[(1, 9)] = ack(0.05, 1, 9, 500)
    violations, _, trace = monitor_mission(m, [m.acks[(1, 9)]], ("127.0.0.1", 7890), rto=0.2,
                                           ack_window=0.25, broadcast_id=0xFFFF)
    assert "MCP-HDR-1" in {v.rule for v in violations}, violations
    assert len(trace) == 3


def _judge_seq_1(m: Mission) -> str | None:
    """Run the manager-role MCP-SEQ-1 case on ``m``; its failure's actual, or None."""
    from mcp_conform.conformance._case_base import CaseBase
    from mcp_conform.conformance.cases_manager.test_seq import (
        test_each_new_message_takes_the_next_seq,
    )
    from mcp_conform.harness.errors import CaseFailure

    class Node(CaseBase):
        def mission(self, kind: str = "main") -> Mission:
            return m

    try:
        test_each_new_message_takes_the_next_seq(Node(None, "SEQ-1", ("MCP-SEQ-1",)))
    except CaseFailure as exc:
        assert exc.rule == "MCP-SEQ-1"
        return exc.actual
    return None


def test_seq_1_counts_the_numbers_acks_took_not_their_arrival_order():
    """CI (slow suite, 3 workers): a manager that ACKs ACKs sent ACK seq 8235 to one drone,
    then seq 8236 to another; the runner read the message first and SEQ-1 failed ("0 ACKs in
    between"). The gap is explained by the number the ACK carried, wherever it arrived."""
    ack_of_ack = encode(Message(2, 0, 8235, Action.ACK, 77))
    m = mission([cmd(1, 8234, Action.START_MISSION), cmd(3, 8236, Action.START_MISSION), ack_of_ack], [0.0, 0.10, 0.101])
    assert _judge_seq_1(m) is None
    # a number skipped that no ACK carried is a fault, ACKs or not
    m = mission([cmd(1, 8234, Action.START_MISSION), encode(Message(2, 0, 9000, Action.ACK, 77)),
                 cmd(3, 8236, Action.START_MISSION)], [0.0, 0.05, 0.10])
    assert _judge_seq_1(m) == "seq 8236"
    # a repeated or backwards number is a fault
    m = mission([cmd(1, 8234, Action.START_MISSION), cmd(3, 8233, Action.START_MISSION)], [0.0, 0.10])
    assert _judge_seq_1(m) == "seq 8233"


def test_a_mission_ready_never_acked_while_the_manager_went_on_is_ack_1_for_case_and_monitor():
    """One judge: the manager never ACKs the drones' Mission_Ready (5 copies each) yet sends
    them Start_Mission and End_Mission: the MCP-ACK-1 case fails with that evidence, and the
    trace monitor over the same mission says MCP-ACK-1 too (not MCP-FLOW-2)."""
    from mcp_conform.conformance._case_base import CaseBase
    from mcp_conform.conformance.cases_manager.test_ack import test_every_mission_ready_is_acked
    from mcp_conform.harness.driver import Exchange
    from mcp_conform.harness.errors import CaseFailure

    def ready_copies(drone: int, seq: int, t0: float) -> list[Sent]:
        data = encode(Message(0, drone, seq, Action.MISSION_READY))
        return [Sent(t0 + 0.2 * k, int((t0 + 0.2 * k) * 1e9), data, ADDR, 0, drone, seq, int(Action.MISSION_READY))
                for k in range(5)]

    m = Mission("main", (1, 2), 2, None, None, t0=0.0, t_end=3.0)
    m.ready[1], m.ready[2] = Exchange(ready_copies(1, 700, 0.0)), Exchange(ready_copies(2, 900, 1.0))
    sent = [*m.ready[1].copies, *m.ready[2].copies]
    for i, (drone, seq, action, t) in enumerate([(1, 10, Action.START_MISSION, 1.05), (2, 11, Action.START_MISSION, 1.1),
                                                 (1, 12, Action.END_MISSION, 2.15), (2, 13, Action.END_MISSION, 2.25)]):
        m.rx.append(rx(i, t, cmd(drone, seq, action)))
        m.acks[(drone, seq)] = ack(t + 0.01, drone, seq, 800 + i)
        sent.append(m.acks[(drone, seq)])
    violations, _, _ = monitor_mission(m, sent, ("127.0.0.1", 7890), rto=0.2, ack_window=0.25, broadcast_id=0xFFFF)
    assert {v.rule for v in violations} == {"MCP-ACK-1"}, violations

    class Node(CaseBase):
        rto = 0.2

        def mission(self, kind: str = "main") -> Mission:
            return m

    try:
        test_every_mission_ready_is_acked(Node(None, "ACK-1", ("MCP-ACK-1",)))
    except CaseFailure as exc:
        assert exc.rule == "MCP-ACK-1" and exc.actual.startswith("no ACK of seq 700 after 5 copies"), exc
        assert any("went on with the mission" in e and "START_MISSION to 1 (seq 10)" in e for e in exc.evidence)
    else:
        raise AssertionError("MCP-ACK-1 passed on a Mission_Ready never ACKed")

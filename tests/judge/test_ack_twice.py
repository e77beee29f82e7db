"""D-9: a node may ACK one datagram more than once. MCP-ACK-1 asks every copy ACKed, MCP-ACK-2
that an ACK's payload be the acknowledged message's number; nothing forbids answering one
copy twice, so a count of ACKs above the copies proves nothing, and no judge may prove a rule
by one. MCP-ACK-2 is proven where an ACK names a number no datagram carried (test_ack_of_nothing);
a copy left waiting while the node re-ACKed something else is "MCP-ACK-1 or MCP-ACK-2", neither
alone. The simulator's ``ack-twice`` model (a correct drone: duplicates ACKed twice, the message
before each new one ACKed again) is the sweep's control for this (sim.faults)."""

from __future__ import annotations

from mcp_conform.judge.explain import PROVEN, Ack, Bounds, Copy, Trace, decide_receiver
from mcp_conform.judge.monitor import Monitor
from mcp_conform.spec.codec import Action, build_datagram

NS = 1_000_000_000
MS = 1_000_000
MGR = ("127.0.0.1", 7889)
DRONE = ("127.0.0.11", 7890)
READY, START, WP_LIST, ACK = (int(Action.MISSION_READY), int(Action.START_MISSION), int(Action.WP_LIST),
                              int(Action.ACK))
T0 = 100 * NS


def ack(src: int, dst: int, seq: int, named: int) -> bytes:
    return build_datagram(dst, src, seq, ACK, named.to_bytes(2, "big"))


def mission_start() -> list[tuple[int, object, object, bytes]]:
    """Drone 1's Mission_Ready, the manager's ACK, Start_Mission 500 and its ACK."""
    return [(T0, DRONE, MGR, build_datagram(0, 1, 7000, READY)),
            (T0 + 1 * MS, MGR, DRONE, ack(0, 1, 499, 7000)),
            (T0 + 2 * MS, MGR, DRONE, build_datagram(1, 0, 500, START)),
            (T0 + 3 * MS, DRONE, MGR, ack(1, 0, 7001, 500))]


def judge(records, end_s: float) -> tuple[dict, set[str]]:
    m = Monitor(rto=1.0, ack_window=0.5, drones=(1,), challenge=1, complete=True, party=1)
    found = []
    for t, src, dst, data in records:
        found += m.datagram(t, src, dst, data)
    found += m.finish(T0 + int(end_s * NS))
    return m.verdicts().get(1, {}), {v.rule for v in m.violations if v.node == 1}


def late_copy_then(*after: tuple[int, object, object, bytes]) -> list[tuple[int, object, object, bytes]]:
    """Start_Mission ACKed, WP_List 501 sent and ACKed, then a copy of Start_Mission 500 the
    link held back (at 1.0 s) and what ``after`` adds."""
    return [*mission_start(),
            (T0 + 10 * MS, MGR, DRONE, build_datagram(1, 0, 501, WP_LIST, b"\x00\x00")),
            (T0 + 11 * MS, DRONE, MGR, ack(1, 0, 7002, 501)),
            (T0 + NS, MGR, DRONE, build_datagram(1, 0, 500, START)),
            *after]


def test_a_second_ack_of_one_copy_is_no_proof_the_node_read_the_next():
    """WP_List's first copy ACKed, then the held-back copy of Start_Mission, then WP_List's
    second copy; the drone ACKs WP_List again, and the view ends 1 s after the Start_Mission
    copy (its ACK window passed, its deadline -- "however late" -- not yet). Counting each copy
    answered once, the second ACK answered WP_List's second copy, so the drone had read past
    the Start_Mission copy and left it unanswered: MCP-ACK-1 (the judge before D-9). It may be
    the first copy's second answer (D-9), the node not yet past the Start_Mission copy."""
    records = late_copy_then((T0 + NS + 100 * MS, MGR, DRONE, build_datagram(1, 0, 501, WP_LIST, b"\x00\x00")),
                             (T0 + NS + 200 * MS, DRONE, MGR, ack(1, 0, 7003, 501)))
    verdicts, found = judge(records, end_s=2.0)
    assert "MCP-ACK-1" not in found and "MCP-ACK-2" not in found
    assert verdicts["MCP-ACK-1"] == "passed" and verdicts["MCP-ACK-2"] == "passed"


def test_a_copy_then_only_a_re_ack_of_another_message_is_neither_rule_alone():
    """The held-back Start_Mission copy waits; the drone's next ACK names WP_List 501, whose
    one copy was ACKed already. Either it re-ACKed WP_List (D-9: no rule broken) and left the
    copy unanswered (MCP-ACK-1), or it answered the copy naming 501 (MCP-ACK-2): every
    explanation breaks one, neither alone -- the judge before D-9 took the count (501 ACKed
    as often as it came) for proof of MCP-ACK-2."""
    verdicts, found = judge(late_copy_then((T0 + NS + 50 * MS, DRONE, MGR, ack(1, 0, 7003, 501))), end_s=6.0)
    assert not found & {"MCP-ACK-1", "MCP-ACK-2"}, found


def test_the_copy_answered_and_re_acks_beside_it_pass():
    """The same, the copy ACKed too (a correct node that ACKed WP_List twice): nothing."""
    records = late_copy_then((T0 + NS + 50 * MS, DRONE, MGR, ack(1, 0, 7003, 501)),
                             (T0 + NS + 60 * MS, DRONE, MGR, ack(1, 0, 7004, 500)),
                             (T0 + NS + 70 * MS, DRONE, MGR, ack(1, 0, 7005, 500)))
    verdicts, found = judge(records, end_s=6.0)
    assert found == set()
    assert verdicts["MCP-ACK-1"] == "passed" and verdicts["MCP-ACK-2"] == "passed"


def test_a_copy_never_answered_while_nothing_else_was_acked_is_still_mcp_ack_1():
    """Not a loophole: the held-back copy waits and no ACK at all follows it."""
    verdicts, found = judge(late_copy_then(), end_s=6.0)
    assert "MCP-ACK-1" in found


# ------------------------------------------------------------------ judge.explain
def test_explain_proves_nothing_of_a_copy_acked_three_times():
    trace = Trace([Copy(500, 0, 0.0), Copy(501, 1, 0.5)],
                  [Ack(0.01, 500), Ack(0.02, 500), Ack(0.4, 500), Ack(0.51, 501)], end=5.0)
    found = decide_receiver(trace, Bounds(ack_window=1.0, rto=1.0))
    assert not [r for r, v in found.items() if v.status == PROVEN], found


def test_explain_still_proves_an_ack_naming_a_number_no_copy_carried_before_it():
    trace = Trace([Copy(500, 0, 0.0), Copy(501, 1, 0.5)],
                  [Ack(0.01, 500), Ack(0.02, 501), Ack(0.51, 501)], end=5.0)
    found = decide_receiver(trace, Bounds(ack_window=1.0, rto=1.0))
    assert found["MCP-ACK-2"].status == PROVEN
    assert "names no copy" in found["MCP-ACK-2"].evidence

"""fuzz.oracles: each ACK attributed to the input it names, each verdict naming its rule."""

from __future__ import annotations

import time

from mcp_conform.fuzz.oracles import DeliveryLedger, Input, judge_liveness, judge_replies
from mcp_conform.harness.driver import Datagram, read_header
from mcp_conform.spec.codec import BROADCAST_ID, Action, Message, build_datagram, decode, encode

NODE = 1


def _ack(seq: int, dst: int = 0) -> Datagram:
    data = encode(Message(dst, NODE, 500, Action.ACK, seq))
    return Datagram(0, time.monotonic(), time.time_ns(), data, ("127.0.0.1", 1), decode(data), None,
                    read_header(data))


def _msg(seq: int, dst: int = NODE, action: Action = Action.WP_OFF, src: int = 0) -> Input:
    return Input.of(encode(Message(dst, src, seq, action, 7 if action == Action.ACK else None)))


def test_ack_of_broadcast_other_id_and_ack_name_their_rules() -> None:
    inputs = [_msg(1, BROADCAST_ID), _msg(2, NODE + 1), _msg(3, action=Action.ACK)]
    flaws = judge_replies(inputs, [_ack(1), _ack(2), _ack(3)], NODE, BROADCAST_ID, True)
    assert [(f.rule, f.culprit) for f in flaws] == [("MCP-ACK-4", 0), ("MCP-ACK-5", 1), ("MCP-ACK-6", 2)]


def test_ack_of_malformed_input_cites_the_codecs_rule() -> None:
    bad_preamble = Input.of(b"X" + encode(Message(NODE, 0, 5, Action.WP_OFF, None))[1:])
    unknown = Input.of(build_datagram(NODE, 0, 6, 12))
    wrong_len = Input.of(build_datagram(NODE, 0, 7, int(Action.WP_OFF), b"\x00"))
    flaws = judge_replies([bad_preamble, unknown, wrong_len], [_ack(5), _ack(6), _ack(7)], NODE,
                          BROADCAST_ID, True)
    assert [f.rule for f in flaws] == ["MCP-ROB-2", "MCP-ROB-3", "MCP-ROB-4"]


def test_missing_ack_is_ack1_only_when_the_probe_was_acked() -> None:
    inputs = [_msg(10), _msg(11)]
    assert [f.rule for f in judge_replies(inputs, [_ack(10)], NODE, BROADCAST_ID, True)] == ["MCP-ACK-1"]
    assert judge_replies(inputs, [_ack(10)], NODE, BROADCAST_ID, False) == []


def test_correct_answers_are_no_flaws() -> None:
    inputs = [_msg(1), _msg(2, BROADCAST_ID), Input.of(b"\x00" * 5)]
    assert judge_replies(inputs, [_ack(1)], NODE, BROADCAST_ID, True) == []


def test_ambiguous_ack_and_probe_collision_prove_nothing() -> None:
    # a broadcast and a message to another ID share (src, seq): the ACK cannot be pinned
    inputs = [_msg(4, BROADCAST_ID), _msg(4, NODE + 1)]
    assert judge_replies(inputs, [_ack(4)], NODE, BROADCAST_ID, True) == []
    # the probe took the seq of an input: its ACK answers both
    assert judge_replies([_msg(9)], [_ack(9)], NODE, BROADCAST_ID, True, ignore_seqs=[(0, 9)]) == []


def test_messages_bearing_the_nodes_own_src_are_not_judged() -> None:
    assert judge_replies([_msg(3, src=NODE)], [], NODE, BROADCAST_ID, True) == []


def test_liveness_blames_short_oversized_and_other_inputs() -> None:
    dead = {"alive": False, "exit_code": 3, "stderr_tail": "boom"}
    assert judge_liveness([Input.of(b"abc")], True, dead).rule == "MCP-ROB-1"
    assert judge_liveness([Input.of(bytes(9000))], False, {"alive": True}).rule == "MCP-ROB-6"
    assert judge_liveness([_msg(1)], False, {"alive": True}).rule == "MCP-ROB-5"
    assert judge_liveness([_msg(1)], True, {"alive": True}) is None


def _pt(seq: int, dst: int = NODE, src: int = 0, token: str | None = None) -> Input:
    from mcp_conform.vehicle.probe import make_probe

    return Input.of(encode(Message(dst, src, seq, Action.MAV_PASSTHROUGH, make_probe(token or f"t{seq}"))))


def test_every_copy_is_acked_again_one_ack_answers_one_copy() -> None:
    # MCP-ACK-1: "every copy, retransmissions included" (the no-re-ACK-of-copies fault)
    copies = [_msg(20), _msg(20)]
    assert [(f.rule, f.culprit) for f in judge_replies(copies, [_ack(20)], NODE, BROADCAST_ID, True)] == [
        ("MCP-ACK-1", 1)]
    assert judge_replies([_msg(20), _msg(20)], [_ack(20), _ack(20)], NODE, BROADCAST_ID, True) == []
    assert copies[0].received and not copies[1].received


def test_ledger_duplicate_judged_only_when_the_node_was_shown_the_original() -> None:
    # MCP-DUP-1: a duplicate is one of "the one last delivered from that src": a message the
    # kernel dropped before the node read it makes the next (src, seq) new to the node
    def ledger(original_received: bool) -> DeliveryLedger:
        led = DeliveryLedger(NODE, BROADCAST_ID)
        first = _pt(5, token="a")
        first.observed["acked"] = original_received
        led.sent(0, first, "a")
        led.sent(1, _pt(5, token="b"), "b")  # same (src, seq), another frame: a duplicate
        return led

    assert ledger(False).judge({"a": 0, "b": 1}, settled=True) == []
    assert [f.rule for f in ledger(False).judge({"a": 1, "b": 1}, settled=False)] == ["MCP-DUP-1"]  # it had it
    flaws = ledger(True).judge({"a": 0, "b": 1}, settled=False)
    assert [f.rule for f in flaws] == ["MCP-DUP-1"]
    # the finding carries what its judgement needed (issue 36 item 3)
    vehicle, before, timing = flaws[0].evidence
    assert "frame b delivered 1 time(s)" in vehicle
    assert "last delivered from src 0: seq 5" in before and "ACKed" in before
    assert timing.startswith("timing: ") and "forwards still arriving" in timing


def test_ledger_copies_resent_for_ack1_after_later_messages_are_late_copies() -> None:
    led = DeliveryLedger(NODE, BROADCAST_ID)
    first = _pt(7, token="c")
    led.sent(0, first, "c")
    led.sent(1, _msg(8), None)  # a later message from the same source
    assert [f.rule for f in led.judge({"c": 2}, settled=False)] == ["MCP-PAY-8"]
    first.observed["resent"] = 1  # MCP-ACK-1's observation sent one more copy, after seq 8
    assert led.judge({"c": 2}, settled=False) == []  # a late copy: MCP-DUP-4 leaves it open


def test_ledger_duplicate_delivered_twice_is_dup1() -> None:
    led = DeliveryLedger(NODE, BROADCAST_ID)
    led.sent(0, _pt(5), "t5")
    led.sent(1, _pt(5), "t5")
    assert [f.rule for f in led.judge({"t5": 2}, settled=True)] == ["MCP-DUP-1"]
    assert led.judge({"t5": 1}, settled=True) == []


def test_ledger_wrap_not_delivered_is_seq3_and_double_forward_is_pay8() -> None:
    led = DeliveryLedger(NODE, BROADCAST_ID)
    led.sent(0, _pt(0xFFFF), "t65535")
    wrapped = _pt(0)
    led.sent(1, wrapped, "t0")
    # not shown received (no ACK: the kernel may have dropped it): under-delivery not judged
    assert led.judge({"t65535": 1, "t0": 0}, settled=True) == []
    wrapped.observed["acked"] = True  # as judge_replies marks an input the node ACKed
    assert [f.rule for f in led.judge({"t65535": 1, "t0": 0}, settled=True)] == ["MCP-SEQ-3"]
    assert led.judge({"t65535": 1, "t0": 0}, settled=False) == []  # not settled: under-delivery waits
    assert [f.rule for f in led.judge({"t65535": 2, "t0": 1}, settled=False)] == ["MCP-PAY-8"]


def test_ledger_other_id_and_malformed_must_not_reach_the_vehicle() -> None:
    led = DeliveryLedger(NODE, BROADCAST_ID)
    led.sent(0, _pt(1, dst=NODE + 1), "t1")
    bad = Input.of(_pt(2).data[:-1])
    led.sent(1, bad, "t2")
    assert sorted(f.rule for f in led.judge({"t1": 1, "t2": 1}, settled=True)) == ["MCP-ACK-5", "MCP-ROB-4"]


def _ready(seq: int) -> Datagram:
    data = encode(Message(0, NODE, seq, Action.MISSION_READY, None))
    return Datagram(0, time.monotonic(), time.time_ns(), data, ("127.0.0.1", 1), decode(data), None,
                    read_header(data))


def test_withheld_mission_ready_judged_by_rtx1_seq2_rtx2() -> None:
    from mcp_conform.fuzz.oracles import judge_withheld

    same = [_ready(7), _ready(7), _ready(7)]
    assert judge_withheld(same, _ready(7), 3, True) is None
    assert judge_withheld(same[:1], None, 3, True).rule == "MCP-RTX-1"
    assert judge_withheld([_ready(7), _ready(8)], _ready(9), 2, True).rule == "MCP-SEQ-2"
    assert judge_withheld(same, None, 3, True).rule == "MCP-RTX-2"
    assert judge_withheld(same, None, 3, False) is None  # a dead node is judge_liveness's


def test_misaddressed_and_byte_swapped_acks_are_ack3_and_ack2_not_ack1() -> None:
    inputs = [_msg(0x0102), _msg(0x0304)]
    swapped = _ack(0x0201)
    wrong_dst = _ack(0x0304, dst=0x0FFF)
    flaws = judge_replies(inputs, [swapped, wrong_dst], NODE, BROADCAST_ID, True)
    assert sorted((f.rule, f.culprit) for f in flaws) == [("MCP-ACK-2", 0), ("MCP-ACK-3", 1)]
    # both seqs were sent (boundary values): the ACK of 0x0201 answers its own input
    both = [_msg(0x0102), _msg(0x0201)]
    assert judge_replies(both, [_ack(0x0201)], NODE, BROADCAST_ID, True)[0].rule == "MCP-ACK-1"
    long_ack = Datagram(0, 0.0, 0, _ack(5).data + b"\x00", ("127.0.0.1", 1), None, None,
                        read_header(_ack(5).data))
    assert [f.rule for f in judge_replies([_msg(5)], [long_ack], NODE, BROADCAST_ID, True)] == ["MCP-ACK-2"]


def test_acks_naming_a_wrong_seq_are_paired_with_their_inputs_by_order_as_ack2() -> None:
    """Found fuzzing nodes that ACK with their own seq, the previous seq or zero: every
    input was reported as MCP-ACK-1 ("no ACK"), though each was answered, with the wrong
    payload. The node's ACKs that name no input are as many as the inputs awaiting one
    (plus the probe's): they pair up in order of arrival, each an MCP-ACK-2."""
    inputs = [_msg(0x0101), _msg(0x0202)]
    own = [_ack(0x7000), _ack(0x7001), _ack(0x7002)]  # two inputs, then the probe (seq 9)
    flaws = judge_replies(inputs, own, NODE, BROADCAST_ID, True, ignore_seqs=[(0, 9)], probe_copies=1)
    assert [(f.rule, f.culprit) for f in flaws] == [("MCP-ACK-2", 0), ("MCP-ACK-2", 1)], flaws
    assert "names 28672 (7000)" in flaws[0].actual
    # a constant payload that happens to name one input's seq answers it once only
    zero = [_msg(0), _msg(0x0202)]
    flaws = judge_replies(zero, [_ack(0), _ack(0), _ack(0)], NODE, BROADCAST_ID, True, ignore_seqs=[(0, 9)],
                          probe_copies=1)
    assert [(f.rule, f.culprit) for f in flaws] == [("MCP-ACK-2", 1)], flaws
    # a count that does not fit is ambiguous: only MCP-ACK-1 for the unanswered input
    flaws = judge_replies(inputs, [_ack(0x0101), _ack(0x7000), _ack(0x7001), _ack(0x7002)], NODE,
                          BROADCAST_ID, True, ignore_seqs=[(0, 9)], probe_copies=1)
    assert [(f.rule, f.culprit) for f in flaws] == [("MCP-ACK-1", 1)], flaws
    # a correct node: every ACK names its input, the probe's too: nothing
    assert judge_replies(inputs, [_ack(0x0101), _ack(0x0202), _ack(9)], NODE, BROADCAST_ID, True,
                         ignore_seqs=[(0, 9)], probe_copies=1) == []
    # an input's ACK to the wrong dst paired by order is MCP-ACK-3, not MCP-ACK-2
    flaws = judge_replies([_msg(0x0101)], [_ack(0x0101, dst=0x0FFF), _ack(9, dst=0x0FFF)], NODE, BROADCAST_ID,
                          True, ignore_seqs=[(0, 9)], probe_copies=1)
    assert [(f.rule, f.culprit) for f in flaws] == [("MCP-ACK-3", 0)], flaws


def test_an_ack_of_a_message_from_the_nodes_own_id_does_not_spoil_the_pairing() -> None:
    """A message bearing the node's own ID as src may or may not be ACKed (its own looped
    broadcast, MCP-HDR-4); such an ACK goes to the node's own ID and is left out of the
    pairing, so the WP_OFF's wrong-payload ACK is still MCP-ACK-2, not MCP-ACK-1."""
    inputs = [_msg(92, src=NODE, action=Action.MISSION_READY), _msg(2744)]
    replies = [_ack(0x672A, dst=NODE), _ack(0x672B), _ack(0x672C)]
    flaws = judge_replies(inputs, replies, NODE, BROADCAST_ID, True, ignore_seqs=[(0, 9)], probe_copies=1)
    assert [(f.rule, f.culprit) for f in flaws] == [("MCP-ACK-2", 1)], flaws

"""judge.attribution: which command a reply answers, decided before its form is judged."""

from __future__ import annotations

import struct
from typing import NamedTuple

import pytest

from mcp_conform.judge.attribution import BY_SEQ, BY_SEQ_LE, BY_TIMING, Attributor
from mcp_conform.spec.codec import Action, Message, build_datagram, encode, peek_header

NODE = 1


class Sent(NamedTuple):
    t: float
    data: bytes
    dst: int
    src: int
    seq: int
    action: int


class Rx(NamedTuple):
    t: float
    data: bytes
    header: tuple[int, int, int, int] | None


class Link:
    """The runner's side: commands out, replies in, with a fake clock."""

    def __init__(self, horizon: float = 1.0) -> None:
        self.att = Attributor(0, horizon=horizon, peer_id=NODE)
        self.tx: list[Sent] = []
        self.node_seq = 500

    def send(self, t: float, seq: int, action: Action = Action.WP_OFF, dst: int = NODE, src: int = 0,
             copy_of: int | None = None) -> int:
        payload = seq if action == Action.ACK else None
        data = encode(Message(dst, src, seq, action, payload))
        self.tx.append(Sent(t, data, dst, src, seq, int(action)))
        return self.att.sent(len(self.tx) - 1, self.tx[-1], copy_of)

    def reply(self, t: float, payload: bytes, dst: int = 0):
        self.node_seq += 1
        data = build_datagram(dst, NODE, self.node_seq, int(Action.ACK), payload)
        return self.att.received(Rx(t, data, peek_header(data)))

    def ack(self, t: float, seq: int, dst: int = 0):
        return self.reply(t, struct.pack("!H", seq), dst)


def test_a_correct_ack_of_every_copy_is_attributed_by_seq():
    link = Link()
    cmd = link.send(0.0, 1000)
    link.send(0.2, 1000, copy_of=0)  # a retransmission
    a1, a2 = link.ack(0.25, 1000), link.ack(0.26, 1000)
    assert (a1.command, a1.how, a2.command, a2.how) == (cmd, BY_SEQ, cmd, BY_SEQ)
    assert link.ack(0.3, 1000) is None  # more answers than copies: tied to nothing


def test_own_seq_payload_is_attributed_by_timing_and_says_what_it_named():
    link = Link()
    cmd = link.send(0.0, 1315)
    a = link.reply(0.01, struct.pack("!H", link.node_seq + 1))
    assert (a.command, a.seq, a.how, a.ambiguous) == (cmd, 1315, BY_TIMING, None)
    assert "the node's own sequence number" in a.named and "after the command" in a.describe()


def test_a_stale_seq_is_not_taken_for_a_second_ack_of_the_earlier_command():
    """ACK payload = the previous command's seq: that command was answered, so the reply is
    the latest command's (by timing), not a duplicate answer of the earlier one."""
    link = Link()
    first = link.send(0.0, 1311)
    assert link.ack(0.01, 0).command == first  # by timing (0 names nothing)
    second = link.send(0.1, 1315)
    a = link.ack(0.11, 1311)
    assert (a.command, a.how) == (second, BY_TIMING)
    assert a.named == "seq 1311 (0x051f), an earlier command's, already answered"


def test_little_endian_and_constant_payloads():
    link = Link()
    cmd = link.send(0.0, 0x0102)
    a = link.reply(0.01, b"\x02\x01")
    assert (a.command, a.how) == (cmd, BY_SEQ_LE)
    cmd2 = link.send(0.1, 0x0103)
    a = link.reply(0.11, b"\x00\x00\x00")
    assert (a.command, a.how) == (cmd2, BY_TIMING) and a.named.startswith("nothing: 3 payload bytes")


def test_a_reply_when_no_command_awaits_one_is_tied_to_nothing():
    link = Link()
    assert link.ack(0.0, 7) is None
    link.send(0.0, 1000)
    assert link.ack(0.01, 1000) is not None
    assert link.ack(0.02, 4242) is None  # the latest command is answered
    data = encode(Message(0, NODE, 9, Action.MISSION_READY, None))
    assert link.att.received(Rx(0.03, data, peek_header(data))) is None  # not ACK-like


def test_our_own_acks_are_not_commands_for_timing():
    link = Link()
    cmd = link.send(0.0, 1000)
    link.send(0.005, 1001, action=Action.ACK)  # the runner ACKs something of the node's meanwhile
    a = link.reply(0.01, b"\xff\xff")
    assert a.command == cmd and a.how == BY_TIMING
    ack_cmd = link.send(0.1, 1002, action=Action.ACK)
    assert link.ack(0.11, 1002).command == ack_cmd  # but an ACK of our ACK is tied to it by seq


def test_timing_is_ambiguous_when_another_command_is_open():
    link = Link(horizon=1.0)
    link.send(0.0, 1000)  # never answered
    cmd = link.send(0.1, 1001)
    a = link.reply(0.2, b"\x00\x00")
    assert a.command == cmd and a.ambiguous and "1000" in a.ambiguous
    later = link.send(5.0, 1002)  # beyond the horizon: 1000 is old news
    a = link.reply(5.1, b"\x00\x00")
    assert a.command == later and a.ambiguous is None


def test_an_old_silence_check_does_not_capture_an_arbitrary_payload():
    """A broadcast (which a correct node never answers) stays answerable by seq only for one
    horizon, so a node's arbitrary payload that happens to equal its seq later is not taken
    for an ACK of it."""
    link = Link(horizon=1.0)
    link.send(0.0, 1200, dst=0xFFFF)
    cmd = link.send(3.0, 1201)
    a = link.ack(3.01, 1200)
    assert (a.command, a.how) == (cmd, BY_TIMING)


@pytest.mark.parametrize(("dst", "attributed"), [(7, True), (0, False)])
def test_a_command_from_another_src_is_answered_by_seq_only_to_that_src(dst, attributed):
    link = Link()
    link.send(0.0, 900)
    link.ack(0.01, 900)
    other = link.send(0.1, 1000, src=7)
    mine = link.send(0.2, 1000)
    a = link.ack(0.3, 1000, dst=dst)
    assert a.command == (other if attributed else mine)


def test_an_ack_of_a_malformed_input_is_tied_to_it_by_the_seq_it_names():
    """A bad preamble hides the header from the strict reader; a node that parses past it
    and ACKs (MCP-ROB-2) names its seq, even when the ACK arrives after the next command."""
    link = Link()
    bad = b"XXXXXXXXX" + build_datagram(NODE, 0, 1400, int(Action.WP_OFF))[9:]
    link.tx.append(Sent(0.0, bad, -1, -1, -1, -1))
    inp = link.att.sent(0, link.tx[-1])
    probe = link.send(0.001, 1401)
    assert link.ack(0.002, 1400).command == inp
    assert link.ack(0.003, 1401).command == probe


def test_memory_stays_bounded_on_a_long_run():
    from mcp_conform.judge import attribution

    link = Link()
    for i in range(attribution.MAX_COMMANDS + 10):
        link.send(i * 0.001, i & 0xFFFF)
    assert len(link.att._commands) <= attribution.MAX_COMMANDS
    last = attribution.MAX_COMMANDS + 9
    assert link.ack(last * 0.001 + 0.0005, last & 0xFFFF).how == BY_SEQ


def test_a_command_left_open_stays_answerable_for_three_horizons_then_not():
    """The runner's schedule waits for this before it runs a thrown-away batch's cases again:
    a copy the batch left open must not take the reply of a command sent after (a node naming
    the previous message's seq answered it instead, a cascade of retransmissions), and a late
    ACK of the batch's own commands (a slow node) is still tied to them meanwhile."""
    link = Link(horizon=1.0)
    old = link.send(0.0, 1000)
    link.send(0.1, 1000, copy_of=old)  # two copies, one answered: still open
    assert link.ack(0.12, 1000).command == old
    assert link.att.answerable_until(0.5) == pytest.approx(3.1)
    assert link.ack(2.0, 1000).command == old  # a late ACK of the second copy: still its own
    assert link.att.answerable_until(2.1) == 2.1  # answered: nothing open
    other = link.send(3.0, 1001)
    link.send(3.1, 1001, copy_of=other)
    link.ack(3.12, 1001)
    assert link.att.answerable_until(7.0) == 7.0  # expired after 3 horizons
    new = link.send(7.0, 1002)
    a = link.ack(7.01, 1001)  # names the earlier, expired command's seq
    assert (a.command, a.how) == (new, BY_TIMING)


def test_a_copy_the_runners_own_link_dropped_is_owed_no_reply():
    """``--impair``: the runner's link dropped a copy (``on_wire`` with no delays), so the node
    was sent none of it and no reply is owed to it; a stale ACK naming it is then the latest
    command's wrong answer, not an ambiguous late answer of the dropped one (issue 38)."""
    link = Link(horizon=1.0)
    link.send(0.0, 1000)
    link.att.on_wire(0, 0.0, [])  # dropped on the way out
    cmd = link.send(0.1, 1001)
    a = link.ack(0.15, 1000)
    assert (a.command, a.how, a.ambiguous) == (cmd, BY_TIMING, None)
    # without the link's word the same reply could be 1000's late answer: tied to it by seq
    plain = Link(horizon=1.0)
    first = plain.send(0.0, 1000)
    plain.send(0.1, 1001)
    assert plain.ack(0.15, 1000).command == first


def test_a_copy_the_runners_own_link_duplicated_is_owed_two_replies():
    link = Link(horizon=1.0)
    cmd = link.send(0.0, 1000)
    link.att.on_wire(0, 0.0, [0.0, 0.05])  # two copies left, the second 50 ms late
    assert link.ack(0.01, 1000).command == cmd
    assert link.ack(0.06, 1000).command == cmd  # the second copy's ACK, by seq
    assert link.ack(0.07, 1000) is None  # more answers than copies on the wire


def test_a_reply_the_runners_own_link_dropped_still_answered_its_command():
    """What ``harness.driver``'s ``_lost`` relies on: an ACK of 1000 fed to the attribution
    (there, one the runner's link dropped on the way in, never shown to the cases) answers 1000,
    so the node's next ACK naming 1000 is the latest command's wrong answer, not 1000's
    (ack-previous-seq through ``--impair``; the driver's part is tests/sim/test_mutants_sim.py's
    test_a_wrong_ack_payload_is_found_through_the_runners_impaired_link)."""
    link = Link(horizon=1.0)
    link.send(0.0, 1000)
    link.ack(0.01, 1000)  # read by the attribution, never by the cases
    cmd = link.send(0.1, 1001)
    a = link.ack(0.11, 1000)
    assert (a.command, a.how, a.ambiguous) == (cmd, BY_TIMING, None)

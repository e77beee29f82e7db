"""Unit tests of the sans-I/O endpoint (reference_impl.endpoint), one rule at a time."""

from __future__ import annotations

import random

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from mcp_conform.reference_impl import (
    AckReceived,
    AckSent,
    DeliveryConfirmed,
    DeliveryFailed,
    DuplicateDiscarded,
    Endpoint,
    LocalProtocolError,
    Malformed,
    MessageDelivered,
    Retransmitted,
    State,
    Unexpected,
)
from mcp_conform.reference_impl._transitions import FALLBACK_RULE, TRANSITIONS, Input
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import (
    BROADCAST_ID,
    HEADER_SIZE,
    Action,
    DecodeError,
    Message,
    MissionItem,
    build_datagram,
    decode,
    encode,
)
from tests.reference_impl.helpers import Link

ADDR = ("127.0.0.1", 7889)
ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.5, -78.25, 10.0, 1, 16, 1, 1, 3, 0, 1)


def drone(node_id: int = 1, **kw) -> Endpoint:
    kw.setdefault("initial_seq", 100)
    return Endpoint(node_id, **kw)


def feed(ep: Endpoint, msg: Message, now: float = 0.0, addr=ADDR):
    ep.receive_datagram(encode(msg), addr, now)
    return ep.datagrams_to_send(now), ep.events()


# ---------------------------------------------------------------- receiving: ACK-1..6
def test_message_from_the_broadcast_id_is_neither_acked_nor_delivered():
    """Found by mcp-fuzz: a unicast whose src is the broadcast ID was ACKed to the broadcast
    ID (MCP-ACK-3 names no node there); it is ignored and reported instead."""
    for action in (Action.MISSION_READY, Action.WP_OFF, Action.ACK):
        ep = drone()
        out, evs = feed(ep, Message(1, BROADCAST_ID, 4, action, 4 if action == Action.ACK else None))
        assert out == [] and len(evs) == 1
        assert isinstance(evs[0], Unexpected) and evs[0].rule == "MCP-ACK-3"


def test_unicast_is_acked_with_the_right_fields_and_delivered():
    """MCP-ACK-1/2/3 and D-5: dst = msg.src, src = own ID, payload = acked seq, own next seq."""
    ep = drone(5, initial_seq=40)
    out, evs = feed(ep, Message(5, 0, 0x1234, Action.START_MISSION, None))
    assert len(out) == 1
    data, hint = out[0]
    assert hint == ADDR  # the source address, for reply_to_source
    ack = decode(data)
    assert ack == Message(0, 5, 40, Action.ACK, 0x1234)
    assert data[HEADER_SIZE:] == b"\x12\x34"  # big-endian (D-2)
    assert ep.next_seq == 41
    assert [type(e) for e in evs] == [AckSent, MessageDelivered]
    assert evs[1].msg.action == Action.START_MISSION and evs[1].addr == ADDR


def test_every_copy_is_acked_but_delivered_once():
    """MCP-ACK-1 ("every copy") and MCP-DUP-1 (duplicate: ACKed again, not delivered)."""
    ep = drone()
    msg = Message(1, 0, 7, Action.WP_OFF, None)
    out1, evs1 = feed(ep, msg)
    out2, evs2 = feed(ep, msg)
    assert decode(out1[0][0]).payload == decode(out2[0][0]).payload == 7
    assert any(isinstance(e, MessageDelivered) for e in evs1)
    dup = [e for e in evs2 if isinstance(e, DuplicateDiscarded)]
    assert len(dup) == 1 and dup[0].rule == "MCP-DUP-1"
    assert not any(isinstance(e, MessageDelivered) for e in evs2)


def test_new_seq_with_equal_bytes_is_delivered():
    """MCP-DUP-2."""
    ep = drone()
    _, e1 = feed(ep, Message(1, 0, 7, Action.WP_OFF, None))
    _, e2 = feed(ep, Message(1, 0, 8, Action.WP_OFF, None))
    assert sum(isinstance(e, MessageDelivered) for e in e1 + e2) == 2


def test_duplicate_detection_is_per_source():
    """MCP-DUP-3: the same seq from another src is not a duplicate."""
    ep = drone()
    _, e1 = feed(ep, Message(1, 0, 7, Action.WP_OFF, None))
    _, e2 = feed(ep, Message(1, 2, 7, Action.WP_OFF, None))
    assert sum(isinstance(e, MessageDelivered) for e in e1 + e2) == 2


def test_wraparound_zero_after_65535_is_new():
    """MCP-SEQ-3: 0 after 65535 is new, even with an old 0 remembered.

    The sender's seq climbs from 0 to 65535 in steps under half the space, as the runner's
    MCP-SEQ-3 case does (conformance/cases/test_seq.py): only so is 65535 "after" the old 0
    in serial arithmetic. (65534 straight after 0 is two *behind* it, which on a reordering
    link is a late message, not a wrap; see the test below.) Few deliveries in between, so
    the old 0 is still within the duplicate window when the new 0 arrives.
    """
    ep = drone()
    seqs = (0, 16000, 32000, 48000, 64000, 65534, 65535, 0, 1)
    delivered = 0
    for seq in seqs:
        _, evs = feed(ep, Message(1, 0, seq, Action.WP_OFF, None))
        delivered += sum(isinstance(e, MessageDelivered) for e in evs)
    assert delivered == len(seqs)


def test_copy_of_the_highest_after_a_late_older_message_is_not_delivered_again():
    """Root cause of the stateful test's double deliveries (MCP-DUP-4, our answer).

    Reordering link: broadcasts 0, 1, 2, 4 arrive, then 3 late, then a duplicated copy of 4.
    4 is not the *last* delivered (3 is), so a check of "behind the last" took the copy of
    4 for new. Duplicate discard must be relative to the highest seq delivered from the src;
    the same goes for a unicast's retransmission overtaken by a late broadcast (shared seq
    space) and for a window straddling the wrap.
    """
    for base in (0, 65533):
        ep = drone()
        order = [(base + k) & 0xFFFF for k in (0, 1, 2, 4, 3, 4, 3, 2)]
        delivered = []
        for seq in order:
            _, evs = feed(ep, Message(BROADCAST_ID, 0, seq, Action.START_MISSION, None))
            delivered += [e.msg.seq for e in evs if isinstance(e, MessageDelivered)]
        assert delivered == order[:5], base

    ep = drone()
    feed(ep, Message(1, 0, 17, Action.WP_OFF, None))  # unicast 17, delivered and ACKed
    feed(ep, Message(BROADCAST_ID, 0, 16, Action.WP_OFF, None))  # a late broadcast
    out, evs = feed(ep, Message(1, 0, 17, Action.WP_OFF, None))  # 17's retransmission
    assert decode(out[0][0]).payload == 17  # still ACKed (MCP-ACK-1)
    assert not any(isinstance(e, MessageDelivered) for e in evs)
    assert [e.rule for e in evs if isinstance(e, DuplicateDiscarded)] == ["MCP-DUP-4"]
    _, evs = feed(ep, Message(1, 0, 18, Action.WP_OFF, None))  # the next one is new
    assert any(isinstance(e, MessageDelivered) for e in evs)


def _window_model(seqs: list[int], window: int) -> list[str]:
    """The duplicate window as ``Endpoint._deliver``'s docstring states it, done the plain
    way (every seq half the space or more behind a new highest forgotten at once): per seq,
    "new", "MCP-DUP-1" or "MCP-DUP-4"."""
    from collections import deque

    recent: deque[int] = deque(maxlen=window)
    highest: int | None = None
    out = []
    for seq in seqs:
        if recent and seq == recent[-1]:
            out.append("MCP-DUP-1")
            continue
        if recent and ((highest - seq) & 0xFFFF) < 0x8000 and seq in recent:
            out.append("MCP-DUP-4")
            continue
        if highest is None or 0 < ((seq - highest) & 0xFFFF) < 0x8000:
            highest = seq
            kept = [s for s in recent if ((seq - s) & 0xFFFF) < 0x8000]
            recent.clear()
            recent.extend(kept)
        recent.append(seq)
        out.append("new")
    return out


@pytest.mark.parametrize("window", [1, 2, 5, 64])
def test_duplicate_window_forgets_what_the_plain_scan_forgets(window):
    """MCP-DUP-1/4, SEQ-3: the endpoint looks for seqs to forget only when a bound says some
    may be half the space behind; its verdicts must be those of looking every time. Walks
    with steps at the boundaries (half the space, one either side), late and repeated seqs
    and sequential runs, across the wrap, per seed."""
    steps = [0, 1, 1, 1, 1, 2, -1, -2, -5, 0x7FFF, 0x8000, 0x8001, 0x7FF0, -0x7FFF, -0x8000]
    for seed in range(20):
        rng = random.Random(seed)
        seq, seqs = rng.randrange(0x10000), []
        for _ in range(300):
            if rng.random() < 0.03:  # a sequential run, as a live peer sends
                for _ in range(rng.randrange(20, 200)):
                    seq = (seq + 1) & 0xFFFF
                    seqs.append(seq)
            seq = (seq + rng.choice(steps)) & 0xFFFF
            seqs.append(seq)
        ep = drone(dup_window=window)
        got = []
        for s in seqs:
            _, evs = feed(ep, Message(BROADCAST_ID, 0, s, Action.WP_OFF, None))
            (ev,) = evs
            got.append("new" if isinstance(ev, MessageDelivered) else ev.rule)
        assert got == _window_model(seqs, window), seed


def test_late_copy_of_an_older_message_is_not_delivered_again():
    """MCP-DUP-4 (open): a retransmission overtaken by a newer message is discarded."""
    ep = drone()
    feed(ep, Message(1, 0, 10, Action.WP_ON, ITEM))
    feed(ep, Message(BROADCAST_ID, 0, 11, Action.WP_OFF, None))
    out, evs = feed(ep, Message(1, 0, 10, Action.WP_ON, ITEM))
    assert decode(out[0][0]).payload == 10  # still ACKed (MCP-ACK-1)
    assert [e.rule for e in evs if isinstance(e, DuplicateDiscarded)] == ["MCP-DUP-4"]
    # with dup_window=1 only the last one counts, exactly MCP-DUP-1
    ep1 = drone(dup_window=1)
    feed(ep1, Message(1, 0, 10, Action.WP_OFF, None))
    feed(ep1, Message(1, 0, 11, Action.WP_OFF, None))
    _, evs = feed(ep1, Message(1, 0, 10, Action.WP_OFF, None))
    assert any(isinstance(e, MessageDelivered) for e in evs)


def test_broadcast_is_delivered_not_acked():
    """MCP-ACK-4."""
    ep = drone()
    out, evs = feed(ep, Message(BROADCAST_ID, 0, 3, Action.WP_LIST, (ITEM,)))
    assert out == []
    assert [type(e) for e in evs] == [MessageDelivered]


def test_message_to_another_id_is_neither_acked_nor_delivered():
    """MCP-ACK-5."""
    ep = drone(1)
    out, evs = feed(ep, Message(2, 0, 3, Action.START_MISSION, None))
    assert out == []
    assert len(evs) == 1 and isinstance(evs[0], Unexpected) and evs[0].rule == "MCP-ACK-5"


def test_ack_is_never_acked_and_a_stray_ack_is_reported():
    """MCP-ACK-6 and MCP-RTX-2 (an ACK for nothing in flight)."""
    ep = drone()
    out, evs = feed(ep, Message(1, 0, 3, Action.ACK, 99))
    assert out == []
    assert len(evs) == 1 and isinstance(evs[0], Unexpected) and evs[0].rule == "MCP-RTX-2"
    assert ep.state is State.IDLE


def test_own_looped_back_message_is_ignored():
    ep = drone(1)
    out, evs = feed(ep, Message(BROADCAST_ID, 1, 3, Action.WP_OFF, None))
    assert out == [] and isinstance(evs[0], Unexpected) and evs[0].rule == "MCP-HDR-4"


# ---------------------------------------------------------------- malformed input: ROB-1..4
VALID = [
    Message(1, 0, 9, Action.START_MISSION, None),
    Message(1, 0, 9, Action.WP_LIST, (ITEM, ITEM)),
    Message(1, 0, 9, Action.WP_ON, ITEM),
    Message(1, 0, 9, Action.MISSION_READY, 0),
]


@pytest.mark.parametrize("msg", VALID, ids=lambda m: m.action.name)
def test_every_prefix_of_a_valid_datagram_is_survived(msg):
    """Fed byte by byte (each prefix as a datagram): reported as Malformed, never ACKed."""
    data = encode(msg)
    ep = drone()
    for n in range(len(data)):
        ep.receive_datagram(data[:n], ADDR, 0.0)
        out, evs = ep.datagrams_to_send(), ep.events()
        if n == HEADER_SIZE and msg.action == Action.MISSION_READY:  # empty payload is valid (D-3)
            assert len(out) == 1 and isinstance(evs[-1], MessageDelivered)
            continue
        assert out == []
        (ev,) = evs
        assert isinstance(ev, Malformed)
        assert ev.rule == ("MCP-ROB-1" if n < HEADER_SIZE else "MCP-ROB-4")
    out, evs = feed(ep, msg._replace(seq=10))  # whole: ACKed and delivered
    assert len(out) == 1 and isinstance(evs[-1], MessageDelivered)


@pytest.mark.parametrize("msg", VALID, ids=lambda m: m.action.name)
def test_trailing_garbage_is_malformed_not_acked(msg):
    """MCP-ROB-4 / D-4: "discarded without ACK and without delivery"."""
    ep = drone()
    ep.receive_datagram(encode(msg) + b"\x00garbage", ADDR, 0.0)
    assert ep.datagrams_to_send() == []
    (ev,) = ep.events()
    assert isinstance(ev, Malformed) and ev.rule == "MCP-ROB-4"


def test_bad_preamble_and_unknown_action():
    """MCP-ROB-2, MCP-ROB-3."""
    ep = drone()
    ep.receive_datagram(build_datagram(1, 0, 1, 5, preamble=b"NCSU-CM\x01\x02"), ADDR, 0.0)
    ep.receive_datagram(build_datagram(1, 0, 1, 9), ADDR, 0.0)
    assert ep.datagrams_to_send() == []
    assert [e.rule for e in ep.events()] == ["MCP-ROB-2", "MCP-ROB-3"]


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(data=st.one_of(
    st.binary(max_size=200),
    st.builds(lambda h, tail: build_datagram(1, 0, 5, h) + tail, st.integers(0, 12), st.binary(max_size=80)),
))
def test_arbitrary_bytes_never_raise_and_are_acked_only_when_well_formed(data):
    """MCP-ROB-5: the node survives anything; only a well-formed unicast to us is ACKed."""
    ep = drone()
    ep.receive_datagram(data, ADDR, 0.0)
    out = ep.datagrams_to_send()
    try:
        msg = decode(data)
    except DecodeError:
        assert out == []
        return
    acked = msg.dst == 1 and msg.action != Action.ACK and msg.src != 1
    assert len(out) == (1 if acked else 0)


def test_huge_datagram_is_survived():
    """MCP-ROB-6: up to 65 507 bytes."""
    ep = drone()
    ep.receive_datagram(build_datagram(1, 0, 1, Action.WP_LIST, b"\xff" * (SPEC.protocol["max_datagram"] - 17)), ADDR, 0.0)
    assert ep.datagrams_to_send() == []
    assert isinstance(ep.events()[0], Malformed)


# ---------------------------------------------------------------- sending: SEQ, RTX, BLK
def test_retransmits_every_timeout_same_bytes_until_retry_limit():
    """MCP-RTX-1, RTX-3 and SEQ-2: copies every ``timeout``, same bytes; then DeliveryFailed."""
    ep = drone(timeout=2.0, retries=3)
    h = ep.send(Action.MISSION_READY, None, 0, now=10.0)
    first = ep.datagrams_to_send()
    assert len(first) == 1 and first[0][1] is None
    copies, times = [first[0][0]], []
    while (t := ep.get_timer()) is not None:
        ep.handle_timer(t - 0.5)  # early: nothing happens
        assert ep.datagrams_to_send() == []
        ep.handle_timer(t)
        copies += [d for d, _ in ep.datagrams_to_send()]
        times.append(t)
    assert times == [12.0, 14.0, 16.0, 18.0]
    assert len(copies) == 4 and len(set(copies)) == 1
    evs = ep.events()
    assert [e.copy for e in evs if isinstance(e, Retransmitted)] == [2, 3, 4]
    (fail,) = [e for e in evs if isinstance(e, DeliveryFailed)]
    assert (fail.handle, fail.dst, fail.copies, fail.rule) == (h, 0, 4, "MCP-RTX-1")
    assert ep.state is State.IDLE


def test_retries_zero_sends_one_copy_and_per_send_overrides():
    ep = drone(timeout=5.0, retries=1000)
    ep.send(Action.MISSION_READY, None, 0, now=0.0, timeout=0.5, retries=0)
    assert ep.get_timer() == 0.5
    ep.handle_timer(0.5)
    assert ep.datagrams_to_send() and not ep.datagrams_to_send()
    assert isinstance(ep.events()[-1], DeliveryFailed) and ep.get_timer() is None


def test_only_the_matching_ack_from_the_destination_ends_retransmission():
    """MCP-RTX-2: wrong seq, wrong source, wrong dst do not count."""
    ep = drone(1, initial_seq=500)
    h = ep.send(Action.MISSION_READY, None, 0, now=0.0)
    ep.datagrams_to_send()
    for bad in (Message(1, 0, 1, Action.ACK, 499), Message(1, 3, 1, Action.ACK, 500),
                Message(2, 0, 1, Action.ACK, 500)):
        out, evs = feed(ep, bad)
        assert out == [] and isinstance(evs[0], Unexpected)
        assert ep.state is State.AWAITING_ACK
    _, evs = feed(ep, Message(1, 0, 1, Action.ACK, 500))
    assert [type(e) for e in evs] == [AckReceived, DeliveryConfirmed]
    assert evs[1].handle == h and evs[1].seq == 500 and evs[1].copies == 1
    assert ep.state is State.IDLE and ep.get_timer() is None
    _, evs = feed(ep, Message(1, 0, 2, Action.ACK, 500))  # a second ACK: stray now
    assert evs[0].rule == "MCP-RTX-2"


def test_stop_and_wait_queues_unicasts_and_numbers_them_on_the_wire():
    """MCP-BLK-1 and MCP-SEQ-1 (ACKs take numbers too, D-5)."""
    ep = drone(1, initial_seq=65534)
    h1 = ep.send(Action.MISSION_READY, None, 0, now=0.0)
    h2 = ep.send(Action.MISSION_READY, 1, 0, now=0.0)
    assert h1 != h2 and ep.queued == 1
    (first,) = ep.datagrams_to_send()
    assert decode(first[0]).seq == 65534
    out, _ = feed(ep, Message(1, 0, 77, Action.START_MISSION, None))  # ACKed while waiting
    assert decode(out[0][0]).seq == 65535
    ep.handle_timer(ep.get_timer())
    (again,) = ep.datagrams_to_send()
    assert again[0] == first[0]  # only a retransmission, never the queued one
    out, evs = feed(ep, Message(1, 0, 78, Action.ACK, 65534))
    assert [decode(d).seq for d, _ in out] == [0]  # the queued one, wrapped (SEQ-1/3)
    assert ep.in_flight == (h2, 0, 0) and ep.queued == 0


def test_broadcast_goes_once_at_once_even_while_a_unicast_is_in_flight():
    """MCP-RTX-4 and MCP-ACK-4 (no timer, no outcome)."""
    ep = drone(0, initial_seq=1)
    ep.send(Action.START_MISSION, None, 1, now=0.0)
    ep.send(Action.WP_OFF, None, BROADCAST_ID, now=0.0)
    out = [decode(d) for d, _ in ep.datagrams_to_send()]
    assert [(m.dst, m.seq) for m in out] == [(1, 1), (BROADCAST_ID, 2)]
    assert ep.get_timer() == SPEC.params["timeout_s"]
    b = drone(0, initial_seq=1)
    b.send(Action.WP_OFF, None, BROADCAST_ID, now=0.0)
    assert len(b.datagrams_to_send()) == 1 and b.get_timer() is None and b.events() == []


def test_defaults_come_from_the_spec():
    ep = Endpoint(1)
    assert ep.timeout == SPEC.params["timeout_s"] and ep.retries == SPEC.params["retries"]
    assert ep.broadcast_id == SPEC.protocol["broadcast_id"]
    seqs = {Endpoint(1, rng=random.Random(s)).next_seq for s in range(5)}
    assert len(seqs) > 1  # arbitrary initial seq (MCP-SEQ-4)


@pytest.mark.parametrize("call", [
    lambda ep: ep.send(Action.ACK, 1, 0, now=0.0),
    lambda ep: ep.send(Action.ANY, None, 0, now=0.0),
    lambda ep: ep.send(Action.WP_ON, "nope", 0, now=0.0),
    lambda ep: ep.send(Action.WP_OFF, None, 70000, now=0.0),
    lambda ep: ep.send(Action.WP_OFF, None, 1, now=0.0),
    lambda ep: ep.send(Action.WP_OFF, None, 0, now=0.0, timeout=0),
    lambda ep: ep.send(Action.WP_OFF, None, 0, now=0.0, retries=-1),
    lambda ep: Endpoint(BROADCAST_ID),
    lambda ep: Endpoint(1, initial_seq=65536),
])
def test_our_own_misuse_raises_local_protocol_error(call):
    ep = drone(1)
    with pytest.raises(LocalProtocolError):
        call(ep)
    assert ep.datagrams_to_send() == [] and ep.state is State.IDLE


# ---------------------------------------------------------------- the transition table
def test_every_table_handler_exists():
    for (state, kind), t in TRANSITIONS.items():
        assert callable(getattr(Endpoint, "_on_" + t.handler)), (state, kind)
        assert isinstance(t.next_state, State)


@pytest.mark.parametrize("state", list(State))
@pytest.mark.parametrize("kind", list(Input))
def test_a_pair_missing_from_the_table_is_survived_and_reported(state, kind):
    """h2-style coverage: every (state, input) pair is in the table or reported, never raised."""
    if (state, kind) in TRANSITIONS:
        return
    ep = drone(1)
    if state is State.AWAITING_ACK:
        ep.send(Action.MISSION_READY, None, 0, now=0.0)
        ep.datagrams_to_send()
    ep._step(kind, None, ADDR, 0.0, None)  # white box: force the input
    (ev,) = ep.events()
    assert isinstance(ev, Unexpected) and ev.rule == FALLBACK_RULE
    assert ep.state is state


# ---------------------------------------------------------------- two endpoints, lossy link
def test_two_endpoints_over_a_lossy_link_deliver_everything_once_in_order():
    mgr, drn = Endpoint(0, timeout=0.2, retries=50, initial_seq=65530), Endpoint(1, timeout=0.2, retries=50)
    link = Link([mgr, drn], seed=7, drop=0.3, duplicate=0.2, reorder=0.3, jitter=0.5)
    handles = [link.send(0, Action.WP_ON, ITEM._replace(seq=i), 1) for i in range(20)]
    link.send(1, Action.MISSION_READY, 1, 0)
    link.run(max_steps=20_000)
    confirmed = [e.handle for e in link.nodes[0].events_of(DeliveryConfirmed)]
    assert confirmed == handles
    got = [e.msg.payload.seq for e in link.nodes[1].events_of(MessageDelivered)]
    assert got == list(range(20))
    assert len(link.nodes[0].events_of(MessageDelivered)) == 1

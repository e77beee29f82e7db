"""The seeded impairment schedule (harness.impair, issue 22 item 1): its syntax, its
determinism, each kind of impairment, and the reference endpoints through it on the
in-memory link (exactly-once delivery of every command)."""

from __future__ import annotations

import pytest

from mcp_conform.harness.impair import DelayQueue, Impairment, ImpairmentError, parse_impairment
from mcp_conform.reference_impl import DeliveryConfirmed, Endpoint, MessageDelivered
from mcp_conform.spec.codec import Action, MissionItem, build_datagram, encode_payload
from tests.reference_impl.helpers import Link

ITEM = (MissionItem(0, 0, 0, 0, 35.0, -78.0, 10.0, 0, 16, 1, 1, 3, 0, 1),)


def _run(text: str, n: int = 2000, direction: str = "a>b", dt: float = 0.001) -> Impairment:
    imp = Impairment(parse_impairment(text))
    for i in range(n):
        imp.decide(direction, i.to_bytes(4, "big") * 8, i * dt)
    return imp


@pytest.mark.parametrize(("text", "words"), [
    ("", "empty"), ("loss", "KEY=VALUE"), ("loss=1.5", "probability"), ("loss=x", "not a number"),
    ("volume=3", "unknown key 'volume'"), ("delay=9-1ms", "LO <= HI"), ("delay=fast", "duration"),
    ("burst=0.1", "P_GB/P_BG"), ("burst=0.1/0", "never leave"), ("rate=0", "> 0"),
    ("seed=abc", "integer"), ("loss=0.1,loss=0.2", "twice"), ("copies=99", "1..10"),
])
def test_a_bad_spec_is_one_line_naming_what_is_wrong(text: str, words: str) -> None:
    with pytest.raises(ImpairmentError, match=words) as exc:
        parse_impairment(text)
    assert "\n" not in str(exc.value) and str(exc.value).startswith("--impair:")


def test_the_spec_reads_back_as_itself() -> None:
    text = "loss=0.3,dup=0.1,reorder=0.2,delay=0-50ms,corrupt=0.01,burst=0.05/0.3/1,rate=500,seed=7"
    spec = parse_impairment(text)
    assert (spec.delay_lo_s, spec.delay_hi_s, spec.rate, spec.seed) == (0.0, 0.05, 500.0, 7)
    assert parse_impairment(spec.text()) == spec
    assert parse_impairment("delay=0.1-0.2s").delay_lo_s == pytest.approx(0.1)


def test_same_seed_and_traffic_same_decisions_another_seed_others() -> None:
    text = "loss=0.3,dup=0.1,reorder=0.2,delay=0-50ms,corrupt=0.05,seed={}"

    def decisions(seed: int) -> list[object]:
        imp = Impairment(parse_impairment(text.format(seed)))
        return [imp.decide(d, bytes([i % 256]) * 20, i * 0.01) for i in range(500) for d in ("x>y", "y>x")]

    assert decisions(7) == decisions(7)
    assert decisions(7) != decisions(8)
    # one direction's decisions do not depend on the other direction's traffic
    a = Impairment(parse_impairment(text.format(7)))
    b = Impairment(parse_impairment(text.format(7)))
    only = [a.decide("x>y", b"m" * 20, i) for i in range(200)]
    mixed = []
    for i in range(200):
        b.decide("y>x", b"other", i)
        mixed.append(b.decide("x>y", b"m" * 20, i))
    assert only == mixed


def test_a_hosts_timing_does_not_shift_the_decisions_on_the_other_datagrams() -> None:
    """A retransmission timer that fires once more on a loaded host adds a copy to one
    direction and an ACK of it to the other; a node picks its initial seq at random
    (MCP-SEQ-4). Neither changes what the link does to the other datagrams, nor to the
    first copies of each message: a soak seed replays its failure whatever the timing."""
    text = "loss=0.5,dup=0.3,reorder=0.3,delay=0-50ms,corrupt=0.05,seed=4"

    def traffic(seq0: int, extra_at: int | None) -> list[tuple[str, bytes]]:
        out, seq = [], seq0
        for i in range(40):
            cmd = build_datagram(1, 0, seq, Action.WP_LIST, encode_payload(Action.WP_LIST, ITEM))
            copies = 2 + (extra_at == i)  # one copy more of the i-th command
            for _ in range(copies):
                out.append((f"cmd{i}", cmd))
            for c in range(copies):  # the drone ACKs each copy, with a seq of its own (D-5)
                out.append((f"ack{i}", build_datagram(0, 1, (seq0 + 7 * i + c) & 0xFFFF, Action.ACK,
                                                      seq.to_bytes(2, "big"))))
            seq = (seq + 1) & 0xFFFF
        out.append(("junk", b"not mcp at all"))
        return out

    def decide(datagrams: list[tuple[str, bytes]]) -> dict[tuple[str, int], tuple]:
        imp, seen, out = Impairment(parse_impairment(text)), {}, {}
        for i, (name, data) in enumerate(datagrams):
            dec = imp.decide("a>b", data, i * 0.01)
            k = seen[name] = seen.get(name, -1) + 1
            out[name, k] = (dec.dropped, tuple((d.delay_s, d.kinds) for d in dec.deliveries))
        return out

    plain = decide(traffic(100, None))
    for other in (decide(traffic(100, 5)), decide(traffic(60_000, None)), decide(traffic(9, 5))):
        assert {key: other[key] for key in plain} == plain
    # each copy is its own draw: at loss=0.5, some second copies differ from their first
    assert any(plain[f"cmd{i}", 0][0] != plain[f"cmd{i}", 1][0] for i in range(40))


def test_loss_duplication_delay_reorder_and_corruption_at_their_rates() -> None:
    c = _run("loss=0.3,dup=0.1,reorder=0.2,delay=0-50ms,corrupt=0.05,seed=3", n=10_000).counts
    kept = c["datagrams"] - c["drop:loss"]
    assert 0.27 < c["drop:loss"] / c["datagrams"] < 0.33
    assert 0.08 < c["dup"] / kept < 0.12
    assert 0.17 < c["reorder"] / (kept + c["dup"]) < 0.23
    assert 0.035 < (c.get("corrupt", 0) + c.get("cut", 0)) / (kept + c["dup"]) < 0.065


def test_delay_and_reorder_let_later_datagrams_overtake() -> None:
    imp = Impairment(parse_impairment("reorder=0.2,delay=0-50ms,seed=1"))
    arrivals = []
    for i in range(300):
        (d,) = imp.decide("a>b", bytes([i % 256]), i * 0.005).deliveries
        assert 0.0 <= d.delay_s <= 0.05 or "reorder" in d.kinds
        arrivals.append((i * 0.005 + d.delay_s, i))
    order = [i for _, i in sorted(arrivals)]
    assert order != sorted(order)


def test_corruption_flips_bits_or_cuts_and_never_grows() -> None:
    imp = Impairment(parse_impairment("corrupt=1,seed=5"))
    data = bytes(range(64))
    seen = set()
    for i in range(200):
        (d,) = imp.decide("a>b", data, i).deliveries
        assert d.data != data and len(d.data) <= len(data)
        seen.update(d.kinds)
    assert seen == {"corrupt", "cut"}


def test_gilbert_elliott_losses_come_in_bursts() -> None:
    imp = Impairment(parse_impairment("burst=0.02/0.25,seed=9"))
    lost = [bool(imp.decide("a>b", b"x", i).dropped) for i in range(20_000)]
    runs, run = [], 0
    for x in lost:
        if x:
            run += 1
        elif run:
            runs.append(run)
            run = 0
    assert sum(runs) / len(runs) > 3.0  # independent 7 % losses would average ~1.08
    assert 0.04 < sum(lost) / len(lost) < 0.12  # stationary 0.02 / (0.02 + 0.25) = 7.4 %


def test_rate_limit_per_second_per_direction() -> None:
    imp = Impairment(parse_impairment("rate=100,seed=1"))
    passed = [not imp.decide("a>b", b"x", i / 1000).dropped for i in range(3000)]  # 1000/s, 3 s
    assert sum(passed) == 300
    assert not imp.decide("b>a", b"x", 0.5).dropped  # the other direction has its own budget


@pytest.mark.parametrize("seed", range(5))
def test_reference_endpoints_deliver_every_command_once_in_order_through_it(seed: int) -> None:
    """Retransmission until ACK and duplicate discard turn the bad link into exactly-once."""
    imp = Impairment(parse_impairment(f"loss=0.3,dup=0.1,reorder=0.2,delay=0-50ms,seed={seed}"))
    mgr = Endpoint(0, timeout=0.2, retries=200, initial_seq=65530)
    drn = Endpoint(1, timeout=0.2, retries=200)
    link = Link([mgr, drn], impairment=imp)
    item = MissionItem(0, 0, 0, 0, 35.7, -78.6, 10.0, 0, 16, 1, 1, 3, 0, 1)
    handles = [link.send(0, Action.WP_ON, item._replace(seq=i), 1) for i in range(30)]
    link.run(max_steps=50_000)
    assert [e.handle for e in link.nodes[0].events_of(DeliveryConfirmed)] == handles
    assert [e.msg.payload.seq for e in link.nodes[1].events_of(MessageDelivered)] == list(range(30))
    assert imp.counts.get("drop:loss", 0) > 0 and imp.counts.get("dup", 0) > 0


def test_carry_holds_each_copy_until_its_delay_and_records_what_a_full_queue_refused() -> None:
    """``Impairment.carry``: the decision, each copy held to ``now`` + its delay, and the
    copies a full queue refused dropped and counted -- what the proxy, the soak medium and the
    simulator do with a datagram; the same decisions as :meth:`Impairment.decide`'s."""
    text = "loss=0.2,dup=0.5,reorder=0.2,delay=10-900ms,seed=4"
    plain, carried = Impairment(parse_impairment(text)), Impairment(parse_impairment(text))
    q: DelayQueue[tuple[int, bytes]] = DelayQueue()
    held = []
    for i in range(300):
        data = i.to_bytes(4, "big") * 4
        want = plain.decide("up", data, i * 0.1)
        got = carried.carry("up", data, i * 0.1, q, lambda d, i=i: (i, d.data))
        assert got == want
        held += [(i * 0.1 + d.delay_s, i, d.data) for d in got.deliveries]
    assert 0 < len(q) == len(held) < 300 * 2 and carried.counts["drop:loss"] > 0
    assert q.pop_due(1e9) == [(i, data) for _, i, data in sorted(held, key=lambda h: h[0])]
    small: DelayQueue[int] = DelayQueue(max_count=1)
    imp = Impairment(parse_impairment("dup=1,delay=50ms,seed=1"))
    d = imp.carry("up", b"hello", 2.0, small, lambda d: 1)
    assert d.dropped == "queue" and len(d.deliveries) == 1 and imp.counts["drop:queue"] == 1
    assert small.next_due() == pytest.approx(2.05)

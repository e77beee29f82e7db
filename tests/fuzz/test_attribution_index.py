"""The attributor's per-seq index of commands a reply may still name (``judge.attribution``,
``Attributor._named_by``) ties every reply as a scan of every command does.

A fuzz campaign's stateful programs send hundreds of commands with each seq near the wrap
(65535, 0, 1, ...: 637 commands with seq 65535 among 10,747 in a 20,000-case campaign), and
the receive thread scanned them all for each ACK: as much CPU as the campaign's cases. The
index drops the commands no later reply can be tied to; a drop must never change an
attribution (MCP-ACK-1/2/3 verdicts rest on them). So here the same seeded streams of sends,
the runner's link's copies (``on_wire``: drops, duplicates, delays), horizon changes, reply
times that go back, and ACKs naming seqs big- and little-endian go through the attributor and
through one that scans every command (its ``_named_by`` the whole list, as before the index);
every attribution must be equal.
"""

from __future__ import annotations

import random
import struct

import pytest

from mcp_conform.judge import attribution
from mcp_conform.judge.attribution import Attributor
from mcp_conform.spec.codec import Action, build_datagram, peek_header
from tests.judge.test_attribution import Rx as _Got
from tests.judge.test_attribution import Sent as _Sent


class _Scan(Attributor):
    """The attribution before the index: every command with the seq, each time."""

    def _named_by(self, seq, t):  # type: ignore[no-untyped-def]
        return self._by_seq.get(seq, ())


def _stream(seed: int, a: Attributor, b: Attributor) -> dict[str, int]:
    """One seeded stream through both; what it exercised."""
    rng = random.Random(seed)
    seqs = [65534, 65535, 0, 1, 2, 3]  # a campaign's near-wrap programs
    t, tx, sent = 0.0, 0, []
    seen = {"tied": 0, "back": 0, "horizon": 0, "wire": 0, "copies": 0}
    for _ in range(600):
        r = rng.random()
        t += rng.choice((0.001, 0.01, 0.05, 0.3, 1.0))
        if r < 0.35:  # a command (sometimes a copy of an earlier one, sometimes broadcast or an ACK)
            copy_of = rng.choice(sent) if sent and rng.random() < 0.25 else None
            seq = rng.choice(seqs) if rng.random() < 0.9 else rng.randrange(65536)
            dst = rng.choice((1, 1, 1, 0xFFFF, 7))
            src = rng.choice((0, 0, 0, 5))
            action = rng.choice((Action.WP_OFF, Action.START_MISSION, Action.ACK))
            payload = b"" if action != Action.ACK else struct.pack("!H", seq)
            s = _Sent(t, build_datagram(dst, src, seq, action, payload), dst, src, seq, int(action))
            for x in (a, b):
                x.sent(tx, s, copy_of)
            seen["copies"] += copy_of is not None
            sent.append(tx)
            tx += 1
        elif r < 0.42 and sent:  # the runner's own link on a copy: dropped, duplicated, delayed
            i = rng.choice(sent[-20:])
            cmd = a._by_tx.get(i)
            if cmd is not None and cmd.copies:
                when = rng.choice(cmd.copies)
                delays = rng.choice(((), (0.0,), (0.0, 0.002), (0.4,)))
                for x in (a, b):
                    x.on_wire(i, when, delays)
                seen["wire"] += 1
        elif r < 0.45:  # the session sets another horizon
            h = rng.choice((0.3, 1.0, 2.0, 5.0))
            for x in (a, b):
                x.horizon = h
            seen["horizon"] += 1
        else:  # an ACK from the node, naming a seq big- or little-endian, or nothing known
            seq = rng.choice(seqs) if rng.random() < 0.8 else rng.randrange(65536)
            if rng.random() < 0.2:
                seq = ((seq & 0xFF) << 8) | (seq >> 8)
            back = rng.random() < 0.05
            when = t - rng.choice((0.5, 2.0, 6.0)) if back else t
            seen["back"] += back
            data = build_datagram(rng.choice((0, 0, 5)), 1, rng.randrange(65536), Action.ACK, struct.pack("!H", seq))
            got = _Got(when, data, peek_header(data))
            want = b.received(got)
            assert a.received(got) == want, (seed, got)
            seen["tied"] += want is not None
    return seen


@pytest.mark.parametrize("seed", range(40))
def test_the_index_ties_every_reply_as_the_full_scan_does(seed: int, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(attribution, "MAX_COMMANDS", 120)  # the older half forgotten, index and all
    a, b = Attributor(0, horizon=1.0, peer_id=1), _Scan(0, horizon=1.0, peer_id=1)
    seen = _stream(seed, a, b)
    assert seen["tied"] > 20 and seen["wire"] and seen["copies"], seen
    assert sum(len(v) for v in a._live.values()) < sum(len(v) for v in a._by_seq.values())  # it did drop


def test_a_dropped_command_comes_back_with_a_copy_and_for_an_earlier_reply() -> None:
    """The drops the index makes are undone where a reply could name the command again."""
    a = Attributor(0, horizon=1.0, peer_id=1)
    first = _Sent(0.0, build_datagram(1, 0, 7, Action.WP_OFF), 1, 0, 7, int(Action.WP_OFF))
    a.sent(0, first)
    a.sent(1, _Sent(0.1, build_datagram(1, 0, 9, Action.WP_OFF), 1, 0, 9, int(Action.WP_OFF)))
    late = build_datagram(0, 1, 100, Action.ACK, struct.pack("!H", 7))
    got = a.received(_Got(10.0, late, peek_header(late)))  # 10 s on, beyond 3 horizons: not by seq
    assert got is not None and (got.command, got.how) == (1, attribution.BY_TIMING) and a._live[7] == []
    # an earlier reply (a reply time that went back) is still tied to it by its seq
    got = a.received(_Got(0.5, late, peek_header(late)))
    assert got is not None and (got.command, got.how) == (0, attribution.BY_SEQ)
    # a retransmission puts it back: its second copy's ACK is tied by seq
    a.sent(2, _Sent(11.0, first.data, 1, 0, 7, int(Action.WP_OFF)), copy_of=0)
    assert a._live[7] and a._live[7][0].id == 0
    got = a.received(_Got(11.1, late, peek_header(late)))
    assert got is not None and (got.command, got.how) == (0, attribution.BY_SEQ)

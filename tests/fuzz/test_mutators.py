"""fuzz.mutators: seeded, every mutation reached, never a valid End_Mission to the node."""

from __future__ import annotations

from mcp_conform.fuzz.mutators import MUTATORS, CaseGenerator
from mcp_conform.spec.codec import MAX_DATAGRAM, Action, DecodeError, decode


def _cases(seed: int, n: int) -> list:
    g = CaseGenerator(seed, 1, 0xFFFF)
    return [g.next() for _ in range(n)]


def test_same_seed_same_bytes_other_seed_other_bytes() -> None:
    assert [c.data for c in _cases(7, 300)] == [c.data for c in _cases(7, 300)]
    assert [c.data for c in _cases(7, 300)] != [c.data for c in _cases(8, 300)]


def test_every_mutator_and_kind_is_drawn_and_sizes_stay_legal() -> None:
    cases = _cases(1, 4000)
    names = {c.mutator for c in cases}
    assert {n for n, _ in MUTATORS} <= names
    assert "valid" in names and any(n.startswith("kind:") for n in names)
    assert max(len(c.data) for c in cases) <= MAX_DATAGRAM
    assert any(len(c.data) > 8192 for c in cases) and any(len(c.data) < 17 for c in cases)


def test_no_valid_end_mission_reaches_the_node_or_broadcast() -> None:
    for c in _cases(3, 4000):
        try:
            m = decode(c.data)
        except DecodeError:
            continue
        assert not (m.action == Action.END_MISSION and m.dst in (1, 0xFFFF))

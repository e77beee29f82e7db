"""The one search every protocol's triage runs (``fuzz.triage_core.search``: issue 39, a
protocol's triage keeps only its own content): over a protocol's ``replay(inputs) -> signature
| None`` (``HitTriage.shows``), the tries in order, then every suspect together, delta
debugged, then one input's parts. The targets here are models (a replay shows the hit when the
inputs hold what it needs); the protocols' campaigns are tests/fuzz/test_mavlink_fuzz.py's,
test_nsqd_fuzz.py's and test_faulty_nodes.py's."""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import pytest

from mcp_conform.fuzz.budget import Late
from mcp_conform.fuzz.triage_core import HitTriage, Parts, culprit, fewer_parts, fewest, search


class Replays:
    """A model target: a replay of ``inputs`` shows the hit (its signature, ``sig``) when they
    hold every one of ``needs`` (in any order); each replay's inputs kept."""

    def __init__(self, *needs: object, sig: str = "S") -> None:
        self.needs, self.sig = list(needs), sig
        self.seen: list[list[object]] = []

    def replay(self, inputs: list[object]) -> str | None:
        self.seen.append(list(inputs))
        return self.sig if all(n in inputs for n in self.needs) else None

    def shows(self, inputs: list[object]) -> bool:
        return self.replay(inputs) is not None


def test_the_tries_in_order_then_none_when_no_one_shows_it():
    """The newest suspect alone first (the usual culprit), then the older ones; given tries,
    those in their order; every suspect together only when it was not one of the tries."""
    m = Replays(2)
    assert culprit([1, 2, 3], m.shows) == [2]
    assert m.seen == [[3], [2]]
    m = Replays(9)
    assert culprit([1, 2, 3], m.shows) is None
    assert m.seen == [[3], [2], [1], [1, 2, 3]]  # alone each, then all: nothing
    m = Replays(9)
    assert culprit([5], m.shows) is None and m.seen == [[5]]  # one suspect: alone is all of them
    m = Replays(1)
    assert culprit([1, 2], m.shows, tries=[[], [2, 2], [1]]) == [1] and m.seen == [[], [2, 2], [1]]
    m = Replays(1, 3)
    assert culprit([1, 2, 3], m.shows, whole=False) is None and [1, 2, 3] not in m.seen


def test_every_suspect_together_is_delta_debugged_and_a_try_is_kept_as_it_is():
    """A culprit of several inputs (every suspect together) is cut to the fewest that show
    it; one a try found is the finding's input as it is (a copy after its original: two)."""
    m = Replays(3, 7)
    assert search(list(range(10)), m.shows, budget=40) == [3, 7]
    m = Replays(4)
    assert search([4, 5], m.shows, tries=[[4, 4]], budget=40) == [4, 4]  # not cut to [4]
    m = Replays(3, 7)
    assert search(list(range(10)), m.shows, budget=0) == list(range(10))  # no budget: all of them
    assert search([1, 2], Replays(9).shows, budget=40) is None


def test_a_search_replays_each_input_list_once():
    """A try asked again in one search -- MCP's vehicle flaw has its culprit as a suspect and
    as a try of its own, then delta debugging's singles ask the same single -- is answered
    by the replay that ran (a replay is a fresh node: ~0.2 CPU s, ~0.6 s); the answers, and
    so the minimal input, are the search's as before."""
    m = Replays(3, 7)
    assert search(list(range(10)), m.shows, tries=[[9], [9, 9], [9]], budget=40, singles=4) == [3, 7]
    assert m.seen[:3] == [[9], [9, 9], list(range(10))]  # the second [9] not replayed
    assert len(m.seen) == len({tuple(s) for s in m.seen})  # no list replayed twice
    assert [9] in m.seen and [8] in m.seen  # the singles that were not asked before, asked


@dataclass(frozen=True)
class Msg:
    kind: str
    parts: tuple[int, ...]


PARTS: Parts[Msg, int] = Parts(lambda m: m.parts, lambda m, ps: replace(m, parts=tuple(ps)), 16)


def test_one_input_left_is_cut_to_its_fewest_parts():
    """One input left: its fewest parts (a MAVLink case's frames, an Nsqd case's writes) that
    still show it; the input itself (the same object) when none can go."""
    bad = Msg("x", (1, 2, 3, 4))

    def needs_3(ms: list[Msg]) -> bool:
        return any(3 in m.parts for m in ms)

    assert fewer_parts(bad, needs_3, PARTS) == Msg("x", (3,))
    assert search([Msg("y", (9,)), bad], needs_3, budget=8, parts=PARTS) == [Msg("x", (3,))]
    assert fewer_parts(bad, lambda ms: ms[0].parts == bad.parts, PARTS) is bad
    one = Msg("x", (3,))
    assert fewer_parts(one, lambda ms: pytest.fail("a replay for one part"), PARTS) is one


def test_a_group_alone_first_among_many_inputs():
    """More than 8 inputs of several groups: the newest input's group alone first (one
    replay), the rest delta debugged within it; 8 or fewer: delta debugging alone."""
    many = [Msg("a" if i % 2 else "b", (i,)) for i in range(12)]
    calls: list[list[Msg]] = []

    def needs_a5(ms: list[Msg]) -> bool:
        calls.append(ms)
        return Msg("a", (5,)) in ms

    assert fewest(many, needs_a5, budget=40, group=lambda m: m.kind) == [Msg("a", (5,))]
    assert {m.kind for m in calls[0]} == {"a"}  # the newest's group (many[-1] is an "a") first
    calls.clear()
    assert fewest(many[:8], needs_a5, budget=40, group=lambda m: m.kind) == [Msg("a", (5,))]
    assert len({m.kind for m in calls[0]}) == 2  # no group step: delta debugging's first halves


@dataclass(kw_only=True, eq=False)
class Tri(HitTriage):
    pass


def test_the_predicate_counts_each_replay_and_asks_its_signature_be_the_same():
    """``HitTriage.shows``: each replay counted in the triage's replays; a replay that shows
    another signature does not show the hit; none starts after the deadline (``Late``)."""
    t = Tri()
    m = Replays(1, sig="other")
    shows = t.shows(m.replay, lambda s: s == "S")
    assert not shows([1]) and t.replays == 1
    m.sig = "S"
    assert shows([1]) and t.replays == 2
    assert not shows([2]) and t.replays == 3
    late = Tri(started=time.monotonic() - 100, duration=1.0)
    with pytest.raises(Late):
        late.shows(m.replay, share=False)([1])
    assert late.replays == 0 and len(m.seen) == 3


def _confirmer(shows, log: list[tuple[list[Msg], bool]], n: int = 3):
    """``confirm(inputs, until_miss)`` over a model: N replays (none after a miss when asked)."""
    from mcp_conform.fuzz.confirm import confirm_n

    def confirm(inputs: list[Msg], until_miss: bool):
        log.append((inputs, until_miss))
        return confirm_n(lambda: inputs if shows(inputs) else None, n, until_miss=until_miss)
    return confirm


def test_the_newest_confirmed_at_once_then_its_parts_confirmed_again():
    """The usual culprit (the newest suspect) confirmed at once: no search; its fewest parts
    kept only when confirmed N of N too; a miss of its parts keeps the whole."""
    cases = [Msg("a", (1,)), Msg("b", (2, 3, 4))]
    needs_3 = lambda ms: any(3 in m.parts for m in ms)  # noqa: E731
    log: list[tuple[list[Msg], bool]] = []
    minimal, conf = Tri().minimal(cases, needs_3, _confirmer(needs_3, log), parts=PARTS)
    assert minimal == [Msg("b", (3,))] and conf.confirmed
    assert log == [([cases[1]], True), ([Msg("b", (3,))], False)]
    flaky = iter([True] * 3 + [True, False, True])  # the cut's confirmation (all N) misses once
    log.clear()
    minimal, conf = Tri().minimal(cases, needs_3, _confirmer(lambda ms: next(flaky), log), parts=PARTS)
    assert minimal == [cases[1]] and conf.confirmed and len(log) == 2


def test_a_newest_that_does_not_confirm_is_searched_among_them_all():
    """The newest alone misses: the fewest of all the suspects that show it, confirmed all N
    times (how often it shows); none show it: None (not confirmed, no input named)."""
    cases = [Msg("a", (i,)) for i in range(6)]
    needs = lambda ms: Msg("a", (1,)) in ms and Msg("a", (4,)) in ms  # noqa: E731
    log: list[tuple[list[Msg], bool]] = []
    minimal, conf = Tri().minimal(cases, needs, _confirmer(needs, log), budget=40)
    assert minimal == [Msg("a", (1,)), Msg("a", (4,))] and conf.confirmed
    assert log[0] == ([cases[-1]], True) and log[-1] == (minimal, False)
    log.clear()
    assert Tri().minimal(cases, lambda ms: False, _confirmer(lambda ms: False, log)) is None
    assert log == [([cases[-1]], True)]
    assert Tri().minimal(cases[:1], lambda ms: pytest.fail("searched"), _confirmer(lambda ms: False, [])) is None


def test_a_lasting_hit_is_cut_to_its_shortest_prefix_first():
    """A hit that lasts once shown: the suspects' shortest prefix that shows it (a model target
    that shows it for good once item 4 reached it), its last item the culprit confirmed."""
    cases = [Msg("a", (i,)) for i in range(10)]
    culprit_4 = lambda ms: Msg("a", (4,)) in ms  # noqa: E731

    def extend(target: list[Msg], more) -> bool:
        target.extend(more)
        return culprit_4(target)

    log: list[tuple[list[Msg], bool]] = []
    minimal, conf = Tri().minimal(cases, culprit_4, _confirmer(culprit_4, log),
                                  lasting=(list, extend, lambda t: None, 0.5))
    assert minimal == [Msg("a", (4,))] and conf.confirmed and log == [([Msg("a", (4,))], True)]
    assert Tri().minimal(cases, culprit_4, _confirmer(culprit_4, []),
                         lasting=(list, lambda t, more: None, lambda t: None, 0.5)) is None  # lost: no verdict

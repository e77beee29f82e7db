"""The protocol-neutral steps of triage (``fuzz.triage_core``): the prefix search a lasting hit
(a stopped heartbeat) is found by, a repeat of a known one told in two sends, and what a hit counted, not triaged, or not confirmed
leaves in a worker's counts; a late death's culprit among every input before its cause
(bisection over prefixes); the no-input baseline, once a worker, N of N. The targets here are models: what a real vehicle does with the
search is tests/fuzz/test_mavlink_fuzz.py's."""

from __future__ import annotations

import math
import random
import time

import pytest

from mcp_conform.fuzz.budget import UNCONFIRMED_TRIES
from mcp_conform.fuzz.confirm import confirm_n
from mcp_conform.fuzz.findings import Finding
from mcp_conform.fuzz.triage_core import (
    HitTriage,
    earliest_prefix,
    known_lasting_hit,
    prefix_culprit,
)


class Model:
    """Targets that show the hit for good once every item of ``needs`` reached them."""

    def __init__(self, needs: set[int], lose_at: int | None = None, any_of: frozenset[int] = frozenset()) -> None:
        self.needs, self.lose_at, self.any_of = needs, lose_at, any_of  # or any one of ``any_of``
        self.started = self.closed = self.sends = 0

    def fresh(self) -> list[int]:
        self.started += 1
        return []

    def extend(self, target: list[int], more: list[int]) -> bool | None:
        self.sends += 1
        target.extend(more)
        if self.lose_at is not None and self.lose_at in target:
            return None
        return self.needs <= set(target) or bool(self.any_of & set(target))

    def close(self, target: list[int]) -> None:
        self.closed += 1


@pytest.mark.parametrize("n", [1, 2, 3, 7, 100, 1707, 2400])
def test_the_culprit_ends_the_shortest_prefix_in_log_n_sends(n):
    rng = random.Random(n)
    for culprit in sorted({0, n - 1, n // 2, rng.randrange(n)}):
        m = Model({culprit})
        assert earliest_prefix(list(range(n)), m.fresh, m.extend, m.close) == culprit + 1
        assert m.sends <= math.ceil(math.log2(n)) + 1, (n, culprit, m.sends)
        assert m.closed == m.started  # every target it started is closed


@pytest.mark.parametrize("n", [2, 100, 1707])
def test_a_smaller_split_sends_more_and_shows_it_less_often(n):
    for culprit in (0, n // 3, n - 1):
        m = Model({culprit})
        assert earliest_prefix(list(range(n)), m.fresh, m.extend, m.close, split=1 / 3) == culprit + 1
        assert m.sends <= math.ceil(math.log(n, 1.5)) + 1, (n, culprit, m.sends)
        assert m.closed == m.started


def test_a_target_that_did_not_show_it_is_sent_the_next_items_not_replaced():
    m = Model({90})
    assert earliest_prefix(list(range(100)), m.fresh, m.extend, m.close) == 91
    # 50 clean, then 75, 88 on the same target; 94 shows it; 91 on a fresh one, ...
    assert m.started < m.sends


def test_a_hit_that_needs_an_earlier_item_ends_with_its_last():
    m = Model({3, 40})
    assert earliest_prefix(list(range(64)), m.fresh, m.extend, m.close) == 41


def test_no_prefix_shows_it_or_a_target_is_lost():
    m = Model({1000})
    assert earliest_prefix(list(range(100)), m.fresh, m.extend, m.close) is None
    assert m.closed == m.started == 1  # every item reached one target, none showed it
    m = Model({80}, lose_at=10)
    assert earliest_prefix(list(range(100)), m.fresh, m.extend, m.close) is None
    assert m.closed == m.started
    assert earliest_prefix([], m.fresh, m.extend, m.close) is None


def _kind(item: int) -> int:
    """A model input's kind (what a known finding's confirmed input is matched by)."""
    return item % 10


def _known(items, knowns, m: Model, most: int = 3):
    return known_lasting_hit(items, knowns, _kind, m.fresh, m.extend, m.close, most=most)


def test_a_repeat_of_a_known_lasting_hit_costs_two_sends():
    """The hit the known finding's input (kind 3) makes, seen again among 2,000 suspects while
    an input of kind 8 ran: its finding in two sends to one target (the items before the first
    of kind 3, then it), where the prefix search takes 8 to 12 sends and 4 to 7 targets."""
    suspects = list(range(1404, 3404)) + [3408]
    m = Model({1413})
    assert _known(suspects, [("F", 3)], m) == "F"
    assert (m.started, m.sends, m.closed) == (1, 2, 1)
    m = Model({1423})  # the second of kind 3: two more sends
    assert _known(suspects, [("F", 3)], m) == "F" and m.sends == 4
    for culprit, sends in ((1413, 8), (1503, 11), (2003, 12)):
        m = Model({culprit})
        assert earliest_prefix(suspects, m.fresh, m.extend, m.close, split=1 / 3) == culprit - 1403
        assert m.sends == sends


def test_a_new_hit_among_known_kinds_is_not_the_known_finding():
    """A culprit of kind 7 before the first of kind 3 (or between two of them), or one that needs
    items of both: triaged, though inputs like the known one's were among the suspects and a
    kind-3 input ran when it was seen (the old key counted such a hit as the known one)."""
    suspects = list(range(30, 64))  # the last, 63, is of the known finding's kind
    for needs in ({31}, {37}, {47}, {33, 37}):
        m = Model(needs)
        assert _known(suspects, [("F", 3)], m) is None, needs
        assert m.closed == m.started == 1
    m = Model({47})
    assert earliest_prefix(suspects, m.fresh, m.extend, m.close) == suspects.index(47) + 1  # triage finds it
    # items like the known one's that show it too, alone, but after the new culprit: not masked
    m = Model({37}, any_of=frozenset({43, 53}))
    assert _known(suspects, [("F", 3)], m) is None
    assert m.extend(m.fresh(), [43, 53])  # (what sending the like items alone would have shown)


def test_a_known_finding_is_checked_on_its_first_like_items_only():
    m = Model({53})  # the third of kind 3: past ``most`` 2
    assert _known(list(range(30, 64)), [("F", 3)], m, most=2) is None and m.sends == 4
    m = Model({25})
    assert _known(list(range(20, 30)), [("A", 3), ("B", 42), ("C", 5)], m) == "C"
    assert m.started == 2  # A's target (its kind-3 item never showed it), none for B, C's
    m = Model({25})
    assert _known(list(range(20, 30)), [], m) is None and m.started == 0
    m = Model({25}, lose_at=21)
    assert _known(list(range(20, 30)), [("C", 5)], m) is None and m.closed == m.started == 1


def _finding() -> Finding:
    return Finding("MAV-MIS-4", "", "", [], "hang", "stateless", 7)


def test_a_known_hit_an_untried_key_and_a_spent_budget():
    t = HitTriage(duration=100.0)
    known = _finding()
    assert t.counted(known, "k", "hang: x") and known.occurrences == 2 and not t.untriaged
    assert not t.counted(None, "k", "hang: x")
    for _ in range(UNCONFIRMED_TRIES):
        t.not_confirmed("MAV-MIS-4", "k")
    assert t.unconfirmed == UNCONFIRMED_TRIES and t.unconfirmed_rules == {"MAV-MIS-4": UNCONFIRMED_TRIES}
    assert t.counted(None, "k", "hang: x") and t.untriaged == {"hang: x": 1}
    assert not t.counted(None, "other", "hang: y")
    t.seconds = 0.9 * 0.25 * 100.0  # triage's share spent
    assert t.counted(None, "other", "hang: y") and t.untriaged == {"hang: x": 1, "hang: y": 1}


def test_a_replay_is_counted_and_an_unconfirmed_one_named_with_why():
    t = HitTriage(duration=100.0)
    shown = iter([True, False, True])
    conf = confirm_n(lambda: t.replay(lambda: 1 if next(shown) else None), 3, until_miss=False)
    assert t.replays == 3 and conf.replays == "2 of 3"
    t.not_confirmed("MAV-MIS-4", "k", conf, shape="hang: mission-seq", actual="no HEARTBEAT", why="load")
    (entry,) = t.environment.values()
    assert entry["rule"] == "MAV-MIS-4" and entry["why"] == "reproduced 3 of 4 replays: load" and t.tries == {"k": 1}


def test_a_restart_after_a_hit_is_timed_apart_from_triage():
    t = HitTriage()
    assert t.restarted(lambda: time.sleep(0.01) or "fresh") == "fresh"
    assert t.restart_seconds >= 0.01 and t.seconds == 0.0


def _dies_of(culprits: set[int], tries: list[list[int]]):  # noqa: ANN202
    """A model replay: the target dies when any of ``culprits`` reaches it; each try noted."""
    def shows(items: list[int]) -> bool:
        tries.append(list(items))
        return bool(culprits & set(items))
    return shows


@pytest.mark.parametrize("n", [2, 16, 64])
def test_a_late_deaths_culprit_is_the_last_of_the_shortest_prefix(n):
    """The newest alone first; then all, bisection over prefixes (log2 n), the prefix's last alone."""
    culprit = n // 3
    tries: list[list[int]] = []
    assert prefix_culprit(list(range(n)), _dies_of({culprit}, tries)) == [culprit]
    assert tries[0] == [n - 1] and tries[1] == list(range(n)) and tries[-1] == [culprit]
    assert len(tries) <= 3 + math.ceil(math.log2(n))
    tries.clear()
    assert prefix_culprit(list(range(n)), _dies_of({n - 1}, tries)) == [n - 1] and tries == [[n - 1]]


def test_a_death_no_suspect_shows_and_one_two_inputs_make():
    tries: list[list[int]] = []
    assert prefix_culprit(list(range(8)), _dies_of(set(), tries)) is None and len(tries) == 2

    def needs_both(items: list[int]) -> bool:  # a death only after 2 and then 5
        return {2, 5} <= set(items)
    assert prefix_culprit(list(range(8)), needs_both) == [2, 5]  # the prefix's last alone does not: ddmin


class _Base:
    """A model baseline: what each fresh target sent nothing shows (None: nothing), in turn."""

    def __init__(self, *shows: str | None) -> None:
        self.shows, self.firsts, self.found = list(shows), [], []

    def observe(self, log: list, first: str | None) -> str | None:
        self.firsts.append(first)
        log.append(len(self.firsts))
        return self.shows.pop(0)

    def run(self, t: HitTriage, key: str = "k", same=lambda a, b: a == b) -> str | None:  # noqa: ANN001
        return t.baseline(key, self.observe, same, lambda first, last, log, replays: self.found.append(
            (first, last, log, replays)), lambda h: ("MAV-HB-1", f"shape {h}", h))


def test_a_clean_baseline_costs_one_replay_once_a_worker():
    t, b = HitTriage(duration=100.0), _Base(None)
    assert b.run(t) is None and t.replays == 1 and b.firsts == [None] and not b.found
    assert b.run(t) is None and t.replays == 1  # known: not run again, nor after an engine's turn
    assert t.carry().baselines == {"k": None}


def test_a_failing_baseline_confirmed_n_of_n_is_a_finding_with_no_input():
    t, b = HitTriage(duration=100.0), _Base("hang a", "hang b", "hang c")
    shown: list[int] = []
    assert t.baseline("k", b.observe, lambda x, y: x[:4] == y[:4], lambda *a: b.found.append(a),
                      lambda h: ("MAV-HB-1", h, h), lambda: shown.append(1)) == "hang a"
    assert t.replays == 3 and b.firsts == [None, "hang a", "hang a"] and shown == [1]
    assert b.found == [("hang a", "hang c", [3], "3 of 3")] and t.unconfirmed == 0
    assert b.run(t) == "hang a" and t.replays == 3


def test_a_baseline_shown_then_not_every_time_blames_nothing_and_is_named():
    t, b = HitTriage(duration=100.0), _Base("hang a", None, "hang a")
    assert b.run(t) is None and t.replays == 3 and not b.found  # all N run: how often it shows
    assert t.unconfirmed_rules == {"MAV-HB-1": 1}
    (entry,) = t.environment.values()
    assert entry["shape"] == "shape hang a" and entry["why"].startswith("reproduced 2 of 3 replays")
    assert _Base("hang a").run(t) is None and t.replays == 3  # once a worker: the miss is kept too


class _Target:
    """A model worker target: its restarts counted by reason (``fuzz.loop.WorkerTarget``)."""

    def __init__(self) -> None:
        self.restart_reasons: dict[str, int] = {}

    def count_restart(self, reason: str) -> None:
        self.restart_reasons[reason] = self.restart_reasons.get(reason, 0) + 1


class _Store:
    def __init__(self, *findings: Finding) -> None:
        self.order, self.added = list(findings), []

    def add(self, f: Finding, *args) -> None:  # noqa: ANN002
        self.added.append(f)
        self.order.append(f)


def _triage(*findings: Finding) -> HitTriage:
    t = HitTriage(duration=100.0, seed=7, worker=2)
    t.target, t.store = _Target(), _Store(*findings)  # type: ignore[attr-defined]  # a protocol's triage holds them
    return t


def test_a_fresh_target_is_a_triage_replay_restart_even_one_that_did_not_start():
    from mcp_conform.harness.errors import SetupError

    t = _triage()
    assert t.fresh(lambda: "target") == "target"

    def fails() -> str:
        raise SetupError("did not start")
    with pytest.raises(SetupError):
        t.fresh(fails)
    assert t.target.restart_reasons == {"triage replay": 2}  # type: ignore[attr-defined]


def test_confirming_replays_are_counted_each_with_a_log_of_its_own():
    """``HitTriage.confirm_logged``: N replays (triage's, counted), each given a new log (a
    protocol's own kind: ``log``), a hit paired with its log; until the first miss, or all N."""
    t = _triage()
    shows = iter(["a", None, "c"])

    def replay(log: list[str]) -> str | None:
        log.append(f"traffic {t.replays}")
        return next(shows)
    conf = t.confirm_logged(replay, until_miss=False)
    assert t.replays == 3 and conf.replays == "2 of 3" and conf.hits == [("a", ["traffic 1"]), ("c", ["traffic 3"])]
    assert t.missed("R", "k", conf, shape="s", actual="x", size="1 case(s)") and t.tries == {"k": 1}
    shows = iter(["a", None, "c"])
    conf = t.confirm_logged(replay, until_miss=True, log=lambda: ["own"])
    assert t.replays == 5 and len(conf.results) == 2 and conf.hits == [("a", ["own", "traffic 4"])]
    ok = t.confirm_logged(lambda log: "shown", until_miss=True)
    assert ok.confirmed and not t.missed("R", "k", ok, shape="s", actual="x", size="1 case(s)")
    assert t.tries == {"k": 1} and t.unconfirmed == 1  # a confirmed input is no miss


def test_a_target_that_did_not_start_shows_nothing_only_when_asked():
    from mcp_conform.harness.errors import SetupError

    def replay(inputs: list[int]) -> str:
        raise SetupError("did not start")
    t = _triage()
    assert t.shows(replay, unstarted=True)([1]) is False and t.replays == 1
    with pytest.raises(SetupError):
        t.shows(replay)([1])


def test_a_no_input_baseline_keeps_its_finding_with_the_triages_seed_and_worker():
    t, b = _triage(), _Base("hang a", "hang a", "hang a")
    f = _finding()
    assert t.no_input("k", b.observe, lambda x, y: True, lambda first, last, log, replays: f,
                      lambda h: ("MAV-HB-1", h, h)) == "hang a"
    assert t.store.added == [f] and (f.seed, f.worker) == (7, 2)  # type: ignore[attr-defined]
    t2, b2 = _triage(), _Base("hang a", "hang a", "hang a")
    assert t2.no_input("k", b2.observe, lambda x, y: True, lambda *a: None, lambda h: ("R", h, h)) == "hang a"
    assert t2.store.added == []  # type: ignore[attr-defined]  # none new (already a finding)


def test_a_known_lasting_hit_is_one_more_occurrence_of_its_finding():
    """``HitTriage.known_lasting``: the findings of the hit's oracle with an input, matched by
    their last input's likeness (:func:`known_lasting_hit`); a repeat counted there; none of
    that oracle, or a target that did not start: triaged."""
    from mcp_conform.harness.errors import SetupError

    hang = Finding("MAV-MIS-4", "", "", [], "hang", "stateless", 7, source="hang", cases=[13])
    crash = Finding("MAV-PRM-9", "", "", [], "crash", "stateless", 7, source="crash", cases=[23])
    t, m = _triage(crash, hang), Model({13})
    assert t.known_lasting(list(range(10, 20)), "hang", _kind, m.fresh, m.extend, m.close)
    assert hang.occurrences == 2 and crash.occurrences == 1 and m.sends == 2
    m = Model({17})
    assert not t.known_lasting(list(range(10, 20)), "hang", _kind, m.fresh, m.extend, m.close)
    assert not t.known_lasting(list(range(10, 20)), "stop", _kind, m.fresh, m.extend, m.close)

    def unstarted() -> list[int]:
        raise SetupError("did not start")
    assert not t.known_lasting(list(range(10, 20)), "hang", _kind, unstarted, m.extend, m.close)
    assert hang.occurrences == 2 and t.again(None) is False and t.again(hang) and hang.occurrences == 3

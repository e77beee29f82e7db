"""The protocol-neutral steps of triage (``fuzz.triage_core``): the prefix search a lasting hit
(a stopped heartbeat) is found by, and what a hit counted, not triaged, or not confirmed
leaves in a worker's counts. The targets here are models: what a real vehicle does with the
search is tests/fuzz/test_mavlink_fuzz.py's."""

from __future__ import annotations

import math
import random
import time

import pytest

from mcp_conform.fuzz.budget import UNCONFIRMED_TRIES
from mcp_conform.fuzz.confirm import confirm_n
from mcp_conform.fuzz.findings import Finding
from mcp_conform.fuzz.triage_core import HitTriage, earliest_prefix


class Model:
    """Targets that show the hit for good once every item of ``needs`` reached them."""

    def __init__(self, needs: set[int], lose_at: int | None = None) -> None:
        self.needs, self.lose_at = needs, lose_at
        self.started = self.closed = self.sends = 0

    def fresh(self) -> list[int]:
        self.started += 1
        return []

    def extend(self, target: list[int], more: list[int]) -> bool | None:
        self.sends += 1
        target.extend(more)
        if self.lose_at is not None and self.lose_at in target:
            return None
        return self.needs <= set(target)

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

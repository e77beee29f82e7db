"""tests/conftest.py's order under ``--dist worksteal``: the long tests dealt to the heads of the
workers' first shares, everything else kept in order after them."""

from __future__ import annotations

from pathlib import Path

from .conftest import LONG_FIRST, WAITERS, dealt

TESTS = Path(__file__).resolve().parent


def _shares(n: int, workers: int) -> list[int]:
    """worksteal's first hand-out: share i takes remaining // (workers - i) from the front."""
    sizes, left = [], n
    for i in range(workers):
        sizes.append(left // (workers - i))
        left -= sizes[-1]
    return sizes


def test_each_share_starts_with_its_long_tests_and_nothing_is_lost_or_doubled() -> None:
    items = list(range(341))
    got = dealt(items, 21, 10)
    assert sorted(got) == items
    at = 0
    for i, size in enumerate(_shares(341, 10)):
        share = got[at:at + size]
        longs = [x for x in range(21) if x % 10 == i]
        assert share[:len(longs)] == longs, (i, share[:4])
        rest = share[len(longs):]
        assert rest == sorted(rest) and all(x >= 21 for x in rest)
        at += size


def test_no_workers_or_too_few_items_keep_the_order() -> None:
    assert dealt(list(range(30)), 5, 0) == list(range(30))
    assert dealt(list(range(5)), 5, 4) == list(range(5))


def test_the_tests_that_wait_are_spread_through_every_share() -> None:
    items = list(range(60))
    got = dealt(items, 4, 3, lambda x: x >= 50)
    assert sorted(got) == items
    at = 0
    for i, size in enumerate(_shares(60, 3)):
        share = got[at:at + size]
        waiters = [k for k, x in enumerate(share) if x >= 50]
        assert [share[k] for k in waiters] == list(range(50 + i, 60, 3))  # dealt round-robin
        gaps = [b - a for a, b in zip(waiters, waiters[1:], strict=False)]
        assert gaps and min(gaps) >= 3, share  # spaced among the others, not bunched
        at += size


def test_every_test_the_order_names_still_exists() -> None:
    """A moved or renamed test would silently lose its place at the head of a share."""
    for part in LONG_FIRST:
        name, test = part.split("::")
        stem = test.split("[")[0]
        files = list(TESTS.rglob(name))
        assert any(f"def {stem}" in f.read_text() for f in files), part
    for prefix in WAITERS:
        assert (TESTS.parent / prefix.removesuffix("::")).is_file(), prefix

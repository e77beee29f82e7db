"""The test run's order: the longest tests first, as a pytest-xdist ``load`` schedule wants them.

A long test that starts last makes the run as long as itself on top of everything before it.
``tests/durations.tsv`` holds the wall seconds of the tests that take a while (measured under
CI's load: ``MCP_TEST_TIMES=FILE``, below); they go first, longest first (the greedy
longest-processing-time schedule), the rest after them in collection order. Nothing is skipped
or shortened by this; it only decides what runs first.

CI runs ``--dist load --maxschedchunk 1``: each worker holds the test it runs and the next, and
takes one more from the front of the list each time one ends. The first hand-out gives worker
``i`` the list's items ``2i`` and ``2i + 1``; so that each worker starts one of the ``n``
longest and has one of the next ``n`` waiting (not the two longest on one worker), the first
``2n`` are interleaved here (``n`` from ``PYTEST_XDIST_WORKER_COUNT``).
"""

from __future__ import annotations

import os
from pathlib import Path

import pytest

DURATIONS = Path(__file__).with_name("durations.tsv")


def _durations() -> dict[str, float]:
    """nodeid -> wall seconds, from ``DURATIONS`` ("seconds<TAB>nodeid" lines; # comments)."""
    out: dict[str, float] = {}
    if DURATIONS.is_file():
        for line in DURATIONS.read_text(encoding="utf-8").splitlines():
            if line.strip() and not line.startswith("#"):
                secs, _, nodeid = line.partition("\t")
                out[nodeid.strip()] = float(secs)
    return out


def longest_first(items: list, seconds: dict[str, float], workers: int) -> list:
    """``items`` longest first by ``seconds`` (unknown ones after, in their order), the first
    ``2 * workers`` interleaved for xdist's first hand-out of two per worker."""
    ranked = sorted(items, key=lambda it: -seconds.get(it.nodeid, -1.0))  # stable
    if workers > 1 and len(ranked) >= 2 * workers:
        head = ranked[:2 * workers]
        ranked[:2 * workers] = [x for pair in zip(head[:workers], head[workers:], strict=True) for x in pair]
    return ranked


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    items[:] = longest_first(items, _durations(), int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "0")))


#: ``MCP_TEST_TIMES=FILE``: each test's CPU seconds (the worker's and its waited-for children's,
#: user + system) and wall seconds appended to FILE as "cpu<TAB>wall<TAB>nodeid" -- where CI's
#: time goes on 2 cores. ``tests/durations.tsv`` is its wall column of the longer tests:
#: ``awk -F'\t' '$2 >= 1.5 {print $2 "\t" $3}' FILE | sort -rn``.
_CPU_FILE = os.environ.get("MCP_TEST_TIMES")


def _cpu() -> float:
    import resource

    s, c = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return s.ru_utime + s.ru_stime + c.ru_utime + c.ru_stime


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):  # type: ignore[no-untyped-def]
    if _CPU_FILE is None:
        yield
        return
    import time

    before, start = _cpu(), time.monotonic()
    yield
    with open(_CPU_FILE, "a", encoding="utf-8") as f:
        f.write(f"{_cpu() - before:.3f}\t{time.monotonic() - start:.2f}\t{item.nodeid}\n")

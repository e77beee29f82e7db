"""tests/conftest.py's order: longest first, interleaved for xdist's first hand-out of two per
worker, the tests without a measured time after the rest in their collection order."""

from __future__ import annotations

from dataclasses import dataclass

from .conftest import DURATIONS, _durations, longest_first


@dataclass
class Item:
    nodeid: str


def test_longest_first_interleaved_for_the_first_hand_out() -> None:
    items = [Item(f"t{i}") for i in range(10)]
    seconds = {"t3": 50.0, "t7": 40.0, "t1": 30.0, "t9": 20.0, "t5": 10.0}
    got = [it.nodeid for it in longest_first(items, seconds, workers=2)]
    # worker 0 gets t3 (running) and t1 (waiting), worker 1 t7 and t9; then the rest in order
    assert got == ["t3", "t1", "t7", "t9", "t5", "t0", "t2", "t4", "t6", "t8"]
    assert [it.nodeid for it in longest_first(items, seconds, workers=0)][:5] == ["t3", "t7", "t1", "t9", "t5"]
    assert [it.nodeid for it in longest_first(items[:3], seconds, workers=2)] == ["t1", "t0", "t2"]


def test_the_durations_file_reads_and_names_tests_that_exist() -> None:
    seconds = _durations()
    assert len(seconds) > 50 and all(v > 0 for v in seconds.values())
    files = {nodeid.split("::")[0] for nodeid in seconds}
    missing = [f for f in files if not (DURATIONS.parent.parent / f).is_file()]
    assert not missing, f"{DURATIONS.name} names test files that are gone: {missing}"

"""harness.clock: the real clock is the host's; the virtual one a deterministic cooperative
scheduler (one registered thread at a time, time jumps when every one is blocked)."""

from __future__ import annotations

import random
import threading
import time

import pytest

from mcp_conform.harness.clock import REAL, Deadlock, VirtualClock


def test_real_clock_reads_the_host():
    a = time.monotonic()
    assert a <= REAL.monotonic() <= time.monotonic()
    assert isinstance(REAL.condition(), threading.Condition)
    ev = REAL.event()
    ev.set()
    assert ev.wait(0)
    offset = REAL.offset_ns()
    assert abs(REAL.time_ns() - offset - time.monotonic_ns()) < 50_000_000


def test_sleep_jumps_virtual_time_at_no_wall_cost():
    clock = VirtualClock(start=0.0)
    t0 = time.monotonic()
    clock.run(lambda: clock.sleep(3600.0))
    assert clock.now == 3600.0
    assert time.monotonic() - t0 < 1.0


def _interleaving(seed: int) -> list[tuple[float, str]]:
    """Three threads sleeping seeded amounts and a condition waited on with timeouts."""
    clock = VirtualClock(start=0.0)
    log: list[tuple[float, str]] = []
    cond = clock.condition()
    box: list[int] = []

    def worker(name: str, rng: random.Random) -> None:
        for i in range(20):
            clock.sleep(rng.choice([0.0, 0.001, 0.01, 0.1]))
            log.append((clock.monotonic(), f"{name}{i}"))
            with cond:
                box.append(i)
                cond.notify_all()

    def main() -> None:
        rng = random.Random(seed)
        rngs = {n: random.Random(rng.random()) for n in "abc"}
        handles = [clock.start_thread(lambda n=n: worker(n, rngs[n]), n) for n in "abc"]
        seen = 0
        with cond:
            while seen < 60:
                if not cond.wait(0.05):
                    log.append((clock.monotonic(), "timeout"))
                seen = len(box)
        for h in handles:
            h.join()
        log.append((clock.monotonic(), "joined"))

    clock.run(main)
    return log


def test_same_seed_same_trace_and_another_seed_another():
    a, b, c = _interleaving(7), _interleaving(7), _interleaving(8)
    assert a == b
    assert a != c
    assert a[-1][1] == "joined"
    assert [t for t, _ in a] == sorted(t for t, _ in a)  # time never goes back


def test_one_thread_at_a_time():
    clock = VirtualClock()
    inside = []
    peak = []

    def worker() -> None:
        for _ in range(50):
            inside.append(1)
            peak.append(len(inside))
            time.sleep(0.0001)  # a real pause: another thread would run here if it could
            inside.pop()
            clock.sleep(0.0)

    def main() -> None:
        hs = [clock.start_thread(worker, f"w{i}") for i in range(3)]
        for h in hs:
            h.join()

    clock.run(main)
    assert max(peak) == 1


def test_notify_wakes_before_timeout_and_callbacks_run_in_time_order():
    clock = VirtualClock(start=0.0)
    ev = clock.event()
    order = []
    clock.call_at(2.0, lambda: order.append(("b", clock.now)))
    clock.call_at(1.0, lambda: order.append(("a", clock.now)))
    clock.call_at(1.5, ev.set)

    def main() -> None:
        assert ev.wait(10.0)
        order.append(("woken", clock.now))
        assert not clock.event().wait(0.25)
        order.append(("timed out", clock.now))

    clock.run(main)
    assert order == [("a", 1.0), ("woken", 1.5), ("timed out", 1.75)]


def test_deadlock_is_raised_in_the_root():
    clock = VirtualClock()
    with pytest.raises(Deadlock):
        clock.run(lambda: clock.event().wait())


def test_an_exception_in_a_thread_reaches_the_root():
    clock = VirtualClock()

    def bad() -> None:
        clock.sleep(1.0)
        raise ValueError("boom")

    def main() -> None:
        clock.start_thread(bad, "bad")
        clock.sleep(5.0)

    with pytest.raises(ValueError, match="boom"):
        clock.run(main)


def test_parked_threads_are_unwound_when_the_run_ends():
    clock = VirtualClock()
    stop = clock.event()
    hs = []

    def main() -> None:
        hs.append(clock.start_thread(lambda: stop.wait(), "parked"))
        clock.sleep(1.0)

    clock.run(main)
    hs[0].thread.join(2.0)
    assert not hs[0].thread.is_alive()

"""``harness.impair.DelayQueue`` holds copies pushed in due order in a FIFO and the others in a
heap (a speed-up for the simulated MCP-ROB-7 flood): the order out, the counts and the caps must
be exactly one heap's of ``(due, order pushed)``, as before."""

from __future__ import annotations

import heapq
import random

import pytest

from mcp_conform.harness.impair import HELD_OVERHEAD, DelayQueue


class _OneHeap:
    """The queue as it was: one heap of (due, order, cost, item)."""

    def __init__(self, max_count: int, max_bytes: int) -> None:
        self.heap: list[tuple[float, int, int, int]] = []
        self.n = self.held = self.peak_count = self.peak_bytes = self.refused = 0
        self.max_count, self.max_bytes = max_count, max_bytes

    def push(self, due: float, size: int, item: int) -> bool:
        cost = size + HELD_OVERHEAD
        if len(self.heap) >= self.max_count or self.held + cost > self.max_bytes:
            self.refused += 1
            return False
        heapq.heappush(self.heap, (due, self.n, cost, item))
        self.n += 1
        self.held += cost
        self.peak_count = max(self.peak_count, len(self.heap))
        self.peak_bytes = max(self.peak_bytes, self.held)
        return True

    def pop_due(self, now: float) -> list[int]:
        out = []
        while self.heap and self.heap[0][0] <= now:
            _, _, cost, item = heapq.heappop(self.heap)
            self.held -= cost
            out.append(item)
        return out


@pytest.mark.parametrize("seed", range(40))
def test_the_order_out_is_one_heaps(seed: int) -> None:
    rnd = random.Random(seed)
    cap = rnd.choice([5, 50, 10_000])
    q: DelayQueue[int] = DelayQueue(max_count=cap, max_bytes=rnd.choice([2_000, 60_000, 1 << 24]))
    ref = _OneHeap(q.max_count, q.max_bytes)
    now = 0.0
    for i in range(600):
        r = rnd.random()
        if r < 0.6:  # mostly in due order (a constant delay), ties included; sometimes early
            due = now + rnd.choice([0.001, 0.001, 0.0, rnd.uniform(0, 0.05), -0.0005 * rnd.random()])
            size = rnd.randrange(0, 300)
            assert q.push(due, size, i) == ref.push(due, size, i)
        elif r < 0.8:
            now += rnd.uniform(0, 0.01)
            assert q.pop_due(now) == ref.pop_due(now)
        else:
            assert q.next_due() == (ref.heap[0][0] if ref.heap else None)
        assert (len(q), q.held_bytes, q.peak_count, q.peak_bytes, q.refused) == \
            (len(ref.heap), ref.held, ref.peak_count, ref.peak_bytes, ref.refused)
    assert q.pop_due(now + 1.0) == ref.pop_due(now + 1.0)
    assert len(q) == 0 and q.held_bytes == 0 and q.next_due() is None

"""The virtual clock and the event queue of the simulator (issue 38, item 2).

Time is a float of seconds that moves only when the queue hands out the next event; nothing
reads a wall clock. Events at the same time come out in the order they were pushed (a
counter breaks ties), so a run is a function of its seed alone.
"""

from __future__ import annotations

import heapq
from typing import Any

__all__ = ["Clock", "EventQueue"]


class Clock:
    """The simulated time, seconds since the run began."""

    __slots__ = ("now",)

    def __init__(self) -> None:
        self.now = 0.0


class EventQueue:
    """A time-ordered queue of ``(t, kind, args)``; FIFO among equal times."""

    __slots__ = ("_heap", "_n", "clock")

    def __init__(self, clock: Clock) -> None:
        self._heap: list[tuple[float, int, str, tuple[Any, ...]]] = []
        self._n = 0
        self.clock = clock

    def push(self, t: float, kind: str, *args: Any) -> None:
        """Schedule ``kind`` at ``t`` (never before now: the past is not rewritten)."""
        self._n += 1
        heapq.heappush(self._heap, (max(t, self.clock.now), self._n, kind, args))

    def pop(self) -> tuple[float, str, tuple[Any, ...]]:
        """The next event; the clock moves to its time."""
        t, _, kind, args = heapq.heappop(self._heap)
        self.clock.now = t
        return t, kind, args

    def peek_time(self) -> float | None:
        return self._heap[0][0] if self._heap else None

    def __len__(self) -> int:
        return len(self._heap)

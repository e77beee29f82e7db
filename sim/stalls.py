"""Stalls of the runner's own threads on the virtual clock (issue 38, item 2: "stall any party --
the runner's own receive and send paths included"): a :class:`harness.clock.VirtualClock` whose
scheduler, seeded, leaves a runnable thread off the CPU for a while before it runs, as a loaded
host does -- the receiver reading a datagram late, the case thread sending late, the liveness
watcher probing late. A stalled thread's work is not lost, only late; time stamps are read when
it runs, but a datagram carries the time it was due at the runner's socket (the kernel's receive
time, ``sim.transport``).
"""

from __future__ import annotations

import heapq
import random
from typing import Any

from mcp_conform.harness.clock import VirtualClock

__all__ = ["StallingClock"]


class StallingClock(VirtualClock):
    """A virtual clock that stalls a thread about to run with probability ``p`` for up to
    ``max_s`` virtual seconds (uniform), by ``seed``; a thread just back from a stall runs.
    ``spare``: the names of threads never stalled (the party under test's own, when only the
    runner's are to be), by prefix; none by default."""

    def __init__(self, seed: int, p: float, max_s: float, *, spare: tuple[str, ...] = (), **kwargs: Any) -> None:
        super().__init__(**kwargs)
        self._rng = random.Random(seed)
        self.p, self.max_s, self.spare = p, max_s, spare
        self._back: set[int] = set()  # threads back from a stall (id of their record)
        self.stalls = 0

    def _next(self) -> Any:
        while True:
            v = super()._next()
            if v is self._root and self._failure is not None:
                return v
            if id(v) in self._back or v.name.startswith(self.spare) or self._rng.random() >= self.p:
                self._back.discard(id(v))
                return v
            self._back.add(id(v))
            self.stalls += 1
            v.token += 1
            heapq.heappush(self._timers, (self.now + self._rng.uniform(0.0, self.max_s), next(self._order), v, v.token))

"""Targets started ahead (issue 36 item 5): a fresh target for triage's next replay, or for the
campaign to go on with after a death, started in the background while the current one is
fuzzed or replayed, so that neither waits for a process to start (a real backend takes
1.2-1.4 s). Every protocol's target keeps its spares so (a worker's target of
``fuzz.target_core.SpareTarget``: MAVLink's vehicle, Nsqd's backend): the protocol declares how
one starts, closes and (if it can tell) whether it is still alive.

A target keeps its spares in :class:`Spares`: :meth:`Spares.next` hands on the first ready one
(or starts one then, when none is: its start's own error is then the caller's) and starts the
next ones.

Spares start on one pool of threads that lives as long as the process (:data:`_SPAWNER`): a
process is forked off the main thread by ``harness.procs``' one spawner thread, whatever
thread asks for it, so a spare's process lives on after its start.
"""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from concurrent.futures import TimeoutError as FutureTimeout
from typing import Generic, TypeVar

__all__ = ["SPARES", "Spare", "Spares"]

T = TypeVar("T")

#: how many targets a campaign starts ahead at most: two, as a replay of triage may take less
#: time than a real backend's start
SPARES = 2

#: the threads every spare is started on (they live with the process)
_SPAWNER = ThreadPoolExecutor(max_workers=SPARES, thread_name_prefix="fuzz-spare")


class Spare(Generic[T]):
    """A target being started in the background (``start()``), for the next restart or replay;
    ``close`` ends one; ``alive`` tells one that has ended since its start (never handed on)."""

    def __init__(self, start: Callable[[], T], close: Callable[[T], None],
                 alive: Callable[[T], bool] | None = None) -> None:
        self.future: Future[T] = _SPAWNER.submit(start)
        self.close, self.alive = close, alive

    def take(self, timeout: float | None = None) -> T | None:
        """The started target, once ready; None if it failed to start (the caller then starts
        one itself and reports its error), has ended since, or is not ready within ``timeout``
        s (then closed once its start ends)."""
        try:
            t = self.future.result(timeout)
        except FutureTimeout:
            self.discard()
            return None
        except Exception:  # noqa: BLE001 - see above
            return None
        if self.alive is not None and not self.alive(t):
            self.close(t)
            return None
        return t

    def discard(self) -> None:
        """Not needed: closed now, or as soon as its start ends (no wait for it)."""
        def close(f: Future[T]) -> None:
            if not f.cancelled() and f.exception() is None:
                self.close(f.result())
        self.future.add_done_callback(close)


class Spares(Generic[T]):
    """A target's spares (``n`` of them, none when ``n`` is 0: an attached target), started by
    ``start``, ended by ``close``, told alive by ``alive``; one waited for up to ``timeout`` s."""

    def __init__(self, start: Callable[[], T], close: Callable[[T], None], alive: Callable[[T], bool] | None = None,
                 *, n: int = SPARES, timeout: float | None = None) -> None:
        self.start, self.close, self.alive, self.n, self.timeout = start, close, alive, n, timeout
        self.queue: list[Spare[T]] = []

    def next(self, start: Callable[[], T] | None = None) -> T:
        """The first spare, once ready (else one started now, by ``start`` when given), and the
        next ones started."""
        first = self.queue.pop(0).take(self.timeout) if self.queue else None
        t = first if first is not None else (start or self.start)()
        while len(self.queue) < self.n:
            self.queue.append(Spare(self.start, self.close, self.alive))
        return t

    def discard(self) -> None:
        """None needed any more: each closed (now, or once started)."""
        for spare in self.queue:
            spare.discard()
        self.queue = []

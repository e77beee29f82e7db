"""A campaign's missions, one after another or side by side (``mcp-soak --jobs N``), and how
it stops (issue 38 item 6 and 7).

Mission *k* is the same whichever worker runs it and whenever (its seed, its challenge, its
own directory, ports and medium: ``soak.mission``), so ``--jobs N`` gives the missions serial
would, merged in mission order; only the wall time differs (``bench/bench_soak_jobs.py``).
A mission is mostly waiting (its nodes' start-up, then their retransmission timers), so
threads run them side by side; the nodes are processes of their own.

:class:`Stop` is the campaign's stop: set by SIGTERM or SIGINT (:func:`stopping_on_signals`),
by ``--fail-fast`` after a failure, it starts no more missions, and a signal also interrupts
the running ones (``run_mission``'s ``stop``: their nodes ended at once, their outcome
``interrupted``), so the campaign ends with what it has and nothing left running.
"""

from __future__ import annotations

import contextlib
import signal
import threading
from collections.abc import Callable, Iterator
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from typing import Any

from mcp_conform.soak.mission import MissionResult

__all__ = ["Stop", "run_missions", "stopping_on_signals"]


class Stop(threading.Event):
    """Set once, with why (``SIGTERM``, ``SIGINT``): the missions it interrupts name it."""

    why: str | None = None

    def request(self, why: str) -> None:
        if not self.is_set():
            self.why = why
            self.set()


@contextlib.contextmanager
def stopping_on_signals(stop: Stop) -> Iterator[None]:
    """SIGTERM and SIGINT set ``stop`` (a second one changes nothing: the campaign is already
    ending its nodes, in bounded time) while the block runs; the handlers before it after.
    Outside the main thread (where Python cannot take signals) it does nothing."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    before: dict[signal.Signals, Any] = {}
    try:
        for sig in (signal.SIGTERM, signal.SIGINT):
            before[sig] = signal.signal(sig, lambda n, _f: stop.request(signal.Signals(n).name))
        yield
    finally:
        for sig, handler in before.items():
            signal.signal(sig, handler)


def run_missions(plan: list[tuple[int, int, int]], run: Callable[[int, int, int, Stop], MissionResult],
                 jobs: int, stop: Stop, *, fail_fast: bool = False,
                 done: Callable[[MissionResult], None] | None = None) -> list[MissionResult]:
    """``run(index, seed, challenge, stop)`` for each mission of ``plan``, at most ``jobs`` at
    once, started in plan order; the results in plan order (every mission that ran). ``done``
    is called on the caller's thread as each ends. No mission starts once ``stop`` is set, or
    after a failure under ``fail_fast`` (the ones running then run to their end)."""
    results: dict[int, MissionResult] = {}
    todo = list(plan)
    running: dict[Future[MissionResult], int] = {}
    halted = False
    with ThreadPoolExecutor(max_workers=max(1, jobs), thread_name_prefix="mcp-soak-mission") as pool:
        while running or (todo and not halted and not stop.is_set()):
            while todo and len(running) < jobs and not halted and not stop.is_set():
                k, seed, challenge = todo.pop(0)
                running[pool.submit(run, k, seed, challenge, stop)] = k
            # a short timeout: the main thread stays where a signal's handler can run
            finished, _ = wait(list(running), timeout=0.2, return_when=FIRST_COMPLETED)
            for fut in finished:
                k = running.pop(fut)
                try:
                    r = fut.result()
                except BaseException:
                    stop.request("an error in the soak")  # the other missions end their nodes
                    raise
                results[k] = r
                if done is not None:
                    done(r)
                if fail_fast and not r.ok and r.outcome != "interrupted":
                    halted = True
    return [results[k] for k, _, _ in plan if k in results]

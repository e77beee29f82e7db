"""``mcp-fuzz --jobs N``: the worker processes both campaigns run (MCP's ``fuzz.campaign``,
Nsqd's ``fuzz.stream_jobs``), and the parent's loop over what they report.

Each worker is a spawned process given the one queue it reports on and the one event that
asks it to stop; it ignores SIGINT (the parent's to handle). The parent reads the queue until
every worker is done, all have died, or the campaign's bound has come (``until``:
``fuzz.budget.campaign_end``, ``--duration`` plus its grace, the one bound both campaigns
state); the first SIGINT sets the stop event and gives the workers :data:`STOP_GRACE` to end
their round and report what they have, a second stops waiting. What they reported by then is
handled; the workers are joined briefly (:data:`JOIN_S` once all reported, at once at the
bound), and killed if they do not end, whatever happens.
"""

from __future__ import annotations

import multiprocessing
import queue
import time
from collections.abc import Callable
from typing import Any

__all__ = ["JOIN_S", "PROGRESS_S", "STOP_GRACE", "Reporter", "run_workers"]

STOP_GRACE = 30.0  # s: after SIGINT (or a stop asked for), how long workers get to report
JOIN_S = 1.0  # s, all workers together: to exit once reported (or be killed at the bound)
PROGRESS_S = 0.25  # s: a worker reports its progress at most this often


class Reporter:
    """A worker's end of the queue, whatever its campaign: SIGINT left to the parent (it sets
    the stop event), ``("progress", worker, body)`` at most every :data:`PROGRESS_S`, and one
    ``("done", worker, body)`` at the end."""

    def __init__(self, q: Any, worker: int) -> None:
        import signal

        signal.signal(signal.SIGINT, signal.SIG_IGN)
        self.q, self.worker, self._last = q, worker, 0.0

    def progress(self, body: Callable[[], Any]) -> None:
        """Report ``body()`` unless the last report was less than PROGRESS_S ago."""
        now = time.monotonic()
        if now - self._last >= PROGRESS_S:
            self._last = now
            self.q.put(("progress", self.worker, body()))

    def done(self, body: Any) -> None:
        self.q.put(("done", self.worker, body))


def run_workers(target: Callable[..., None], args_of: Callable[[int, Any, Any], tuple[Any, ...]], jobs: int,
                until: float, handle: Callable[[str, int, Any], bool], finished: Callable[[], bool]) -> bool:
    """Run ``jobs`` processes of ``target(*args_of(i, queue, stop_event))``; hand each
    ``(kind, worker, body)`` they put on the queue to ``handle`` (True: ask the workers to
    stop) until ``finished()`` or the monotonic time ``until``. Whether SIGINT interrupted."""
    ctx = multiprocessing.get_context("spawn")
    q, stop = ctx.Queue(), ctx.Event()
    procs = [ctx.Process(target=target, args=args_of(i, q, stop), daemon=True) for i in range(jobs)]
    for p in procs:
        p.start()
    deadline = until
    interrupted = False
    try:
        while not finished() and time.monotonic() < deadline:
            try:
                try:
                    kind, worker, body = q.get(timeout=min(0.5, max(0.01, deadline - time.monotonic())))
                except queue.Empty:
                    if all(not p.is_alive() for p in procs) and q.empty():
                        break
                    continue
                if handle(kind, worker, body):
                    stop.set()
            except KeyboardInterrupt:
                if interrupted:
                    break  # a second SIGINT: stop waiting for the workers
                interrupted = True
                stop.set()  # each worker ends its round and reports what it has
                deadline = min(deadline, time.monotonic() + STOP_GRACE)
    finally:
        stop.set()
        _drain(q, handle, finished)
        # all reported: a moment to exit; at the bound, none (the campaign's promise)
        end = time.monotonic() + (JOIN_S if finished() else 0.1)
        for p in procs:
            p.join(timeout=max(0.0, end - time.monotonic()))
            if p.is_alive():
                p.kill()
    return interrupted


def _drain(q: Any, handle: Callable[[str, int, Any], bool], finished: Callable[[], bool]) -> None:
    """What the workers reported as the wait ended (a worker done just at the bound)."""
    while not finished():
        try:
            kind, worker, body = q.get_nowait()
        except (queue.Empty, OSError, ValueError, EOFError):
            return
        handle(kind, worker, body)

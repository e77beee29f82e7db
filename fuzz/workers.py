"""``mcp-fuzz --jobs N``: the worker processes both campaigns run (MCP's ``fuzz.campaign``,
Nsqd's ``fuzz.stream_jobs``), and the parent's loop over what they report.

Each worker is a spawned process given the one queue it reports on and the one event that
asks it to stop; it ignores SIGINT (the parent's to handle). The parent reads the queue until
every worker is done, all have died, or the budget is spent; the first SIGINT sets the stop
event and gives the workers :data:`STOP_GRACE` to end their round and report what they have, a
second stops waiting. The workers are joined, and killed if they do not end, whatever happens.
"""

from __future__ import annotations

import multiprocessing
import queue
import time
from collections.abc import Callable
from typing import Any

__all__ = ["STOP_GRACE", "run_workers"]

STOP_GRACE = 30.0  # s: after SIGINT (or a stop asked for), how long workers get to report


def run_workers(target: Callable[..., None], args_of: Callable[[int, Any, Any], tuple[Any, ...]], jobs: int,
                budget_s: float, handle: Callable[[str, int, Any], bool], finished: Callable[[], bool]) -> bool:
    """Run ``jobs`` processes of ``target(*args_of(i, queue, stop_event))``; hand each
    ``(kind, worker, body)`` they put on the queue to ``handle`` (True: ask the workers to
    stop) until ``finished()`` or ``budget_s`` has passed. Whether SIGINT interrupted."""
    ctx = multiprocessing.get_context("spawn")
    q, stop = ctx.Queue(), ctx.Event()
    procs = [ctx.Process(target=target, args=args_of(i, q, stop), daemon=True) for i in range(jobs)]
    for p in procs:
        p.start()
    deadline = time.monotonic() + budget_s
    interrupted = False
    try:
        while not finished() and time.monotonic() < deadline:
            try:
                try:
                    kind, worker, body = q.get(timeout=0.5)
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
        for p in procs:
            p.join(timeout=5)
            if p.is_alive():
                p.kill()
    return interrupted

"""``mcp-fuzz --jobs N``: the worker processes every campaign runs (MCP's ``fuzz.campaign``,
Nsqd's, both through ``fuzz.loop``), and the one parent over what they report (issue 37: one
jobs layer): :func:`run_jobs` shows their figures summed (:class:`~fuzz.progress.Progress`:
cases and restarts summed, judged cases/s over the longest fuzzing time, findings distinct
across workers) and keeps their findings in the campaign's store (grouped, counts summed,
``finding-N/`` written); what else a worker reported, its campaign merges.

Every report is a dict (:func:`report`): ``cases``, ``fuzz_s``, ``restarts``, ``found`` (each
finding's class, rule and shape), ``tried`` when counted; the last, ``done``, also holds the
worker's ``findings`` (``fuzz.findings.Finding``, its traffic with it).

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
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # a worker process imports this module first: it stays light
    from mcp_conform.fuzz.findings import Finding, FindingStore
    from mcp_conform.fuzz.progress import Progress

__all__ = ["JOIN_S", "PROGRESS_S", "STOP_GRACE", "Jobs", "Reporter", "report", "run_jobs", "run_workers",
           "sum_tables"]

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


def report(cases: int, fuzz_s: float, restarts: int, found: Iterable[Finding], **more: Any) -> dict[str, Any]:
    """A worker's report to :func:`run_jobs`: its figures, what it found (class, rule, shape),
    and ``more`` (its campaign's own figures, ``tried``, at the end its ``findings``)."""
    return {"cases": cases, "fuzz_s": fuzz_s, "restarts": restarts,
            "found": [(f.source, f.rule, f.shape) for f in found], **more}


@dataclass
class Jobs:
    """What the ``--jobs`` parent gathered: each worker's last report and its final one."""

    per: dict[int, dict[str, Any]]
    done: dict[int, dict[str, Any]]
    interrupted: bool


def run_jobs(child: Callable[..., None], args_of: Callable[[int, Any, Any], tuple[Any, ...]], jobs: int,
             until: float, store: FindingStore, tick: Callable[[Progress], None] | None = None,
             progress: Progress | None = None, stop_after: int | None = None) -> Jobs:
    """Run ``jobs`` workers (:func:`run_workers`); their figures summed in ``progress`` for
    ``tick`` (the live display), their findings added to ``store`` as each ends. The workers
    are asked to stop once ``stop_after`` distinct findings are known."""
    from mcp_conform.fuzz.progress import Progress

    prog = progress or Progress()
    per: dict[int, dict[str, Any]] = {}
    done: dict[int, dict[str, Any]] = {}

    def handle(kind: str, worker: int, body: dict[str, Any]) -> bool:
        if kind == "done":
            for f in body.pop("findings", []):
                store.add(f)
            done[worker] = body
        per[worker] = body
        found = {(r, sh): c for b in per.values() for c, r, sh in b.get("found", ())}
        prog.cases = sum(b["cases"] for b in per.values())
        prog.fuzz_seconds = max((b["fuzz_s"] for b in per.values()), default=0.0)
        prog.restarts = sum(b["restarts"] for b in per.values())
        prog.workers, prog.workers_judging = jobs, sum(1 for b in per.values() if b["cases"] > 0)
        prog.findings = len(found)
        prog.classes = sum_tables([{"": {c: 1}} for c in found.values() if c]).get("", {})
        prog.tried = sum_tables(b.get("tried", {}) for b in per.values())
        if tick is not None:
            tick(prog)
        return stop_after is not None and prog.findings >= stop_after

    interrupted = run_workers(child, args_of, jobs, until, handle, lambda: len(done) >= jobs)
    return Jobs(per, done, interrupted)


def sum_tables(tables: Iterable[dict[str, dict[str, int]]]) -> dict[str, dict[str, int]]:
    """Tables of counts (row -> column -> n) summed cell by cell."""
    out: dict[str, dict[str, int]] = {}
    for t in tables:
        for kind, row in t.items():
            o = out.setdefault(kind, {})
            for k, n in row.items():
                o[k] = o.get(k, 0) + n
    return out

"""``--jobs`` worker processes, as both campaigns run them (``fuzz.workers``: MCP's
``fuzz.campaign`` and Nsqd's ``fuzz.nsqd_campaign`` share the one loop, ``fuzz.workers.run_jobs``): a stop asked for
reaches every worker, which then reports; workers that die without a word do not keep the
parent waiting for the budget."""

from __future__ import annotations

import time
from typing import Any

from mcp_conform.fuzz.workers import run_workers


def _reporting_worker(worker: int, q: Any, stop: Any) -> None:
    q.put(("progress", worker, 1))
    stopped = stop.wait(60)
    q.put(("done", worker, stopped))


def _silent_worker(worker: int, q: Any, stop: Any) -> None:
    raise SystemExit(3)


def test_a_stop_asked_for_reaches_every_worker_and_each_reports():
    got: list[tuple[str, int, Any]] = []

    def handle(kind: str, worker: int, body: Any) -> bool:
        got.append((kind, worker, body))
        return kind == "progress"  # the first progress asks the workers to stop

    done = lambda: sum(k == "done" for k, _, _ in got) == 2  # noqa: E731
    interrupted = run_workers(_reporting_worker, lambda i, q, stop: (i, q, stop), 2, time.monotonic() + 120.0, handle, done)
    assert not interrupted
    assert sorted((w, b) for k, w, b in got if k == "done") == [(0, True), (1, True)]  # stop.wait saw the stop


def test_workers_that_die_without_a_word_end_the_wait():
    got: list[Any] = []
    interrupted = run_workers(_silent_worker, lambda i, q, stop: (i, q, stop), 2, time.monotonic() + 3600.0,
                              lambda *m: got.append(m) or False, lambda: False)
    assert not interrupted and got == []


def _stuck_worker(worker: int, q: Any, stop: Any) -> None:
    q.put(("progress", worker, 1))
    time.sleep(60)  # a replay that outlasts the grace: deaf to the stop


def test_the_parent_stops_waiting_at_the_campaigns_bound():
    """At ``until`` (``fuzz.budget.campaign_end``) the parent kills a worker still running,
    with no further wait (before: --duration + 120 s, then 5 s of join per worker)."""
    got: list[Any] = []
    t0 = time.monotonic()
    # a bound the workers reach on a loaded host (each is a spawned interpreter that reports
    # once, then hangs); the slack tells "stops at the bound" from the old 120 s + 5 s a worker
    run_workers(_stuck_worker, lambda i, q, stop: (i, q, stop), 2, t0 + 5.0, lambda *m: got.append(m) or False,
                lambda: False)
    took = time.monotonic() - t0
    print(f"returned {took:.2f} s after the start, bound 5 s")
    assert took < 5.0 + 10.0, took
    assert sorted(w for _, w, _ in got) == [0, 1]  # what they reported was handled

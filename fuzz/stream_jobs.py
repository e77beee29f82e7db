"""``mcp-fuzz --protocol nsqd --jobs N``: N worker processes, as ``fuzz.campaign`` runs them
for MCP (issue 21 item 5).

Each worker is a :class:`~fuzz.stream_campaign.StreamCampaign` with its own spawned backend on
its own port and its own seed stream (``seed``, worker index); the stateful engine's workers
share hypothesis's example database (``--db DIR`` or ``redis://``), so a program that failed
on one worker is replayed first by the others. Workers report progress a few times a second
and their findings at the end; the parent deduplicates them across workers by signature
(counts summed), writes ``finding-N/`` and ``summary.json`` (with a ``workers`` list), and
shows the live figures summed (judged cases/s: all workers' cases over the longest fuzzing
time). ``--duration`` counts from the parent's start for every worker, and the parent stops
waiting at the campaign's bound (``fuzz.budget.campaign_end``: ``--duration`` plus
``GRACE_S``). SIGINT: the workers end their round and report what they have.
"""

from __future__ import annotations

import time
from types import SimpleNamespace
from typing import Any

from fuzz.budget import campaign_end
from fuzz.stream_campaign import StreamCampaign
from fuzz.workers import Reporter, run_workers

__all__ = ["run_stream_jobs"]

_FIELDS = ("target", "spawn", "seed", "duration", "max_cases", "replays", "probe_every", "engine", "db")


def _snapshot(c: StreamCampaign) -> dict[str, Any]:
    return {"cases": c.cases, "fuzz_s": c.fuzz_s, "triage_s": c.triage_s, "restart_s": c.restart_s,
            "environment": c.environment.values(),
            "restarts": c.restarts,
            "unconfirmed": c.unconfirmed, "untriaged": c.untriaged, "tried": c.tried, "by_kind": c.by_kind,
            "signatures": [f.signature for f in c.findings]}


def _worker(kw: dict[str, Any], worker: int, q: Any, stop: Any) -> None:
    report = Reporter(q, worker)
    c = StreamCampaign(**kw, out=None, worker=worker, stop=stop.is_set)
    c.tick = lambda camp: report.progress(lambda: _snapshot(camp))
    error = None
    try:
        c.run()
    except Exception as exc:  # noqa: BLE001 - reported by the parent in one line
        error = f"worker {worker}: {type(exc).__name__}: {exc}"
    report.done({**_snapshot(c), "findings": c.findings, "error": error})


def run_stream_jobs(parent: StreamCampaign, jobs: int, live: Any = None) -> dict[str, Any]:
    """Run ``jobs`` workers of ``parent``'s campaign; their merged results in ``parent`` (its
    findings written to its ``out``); the summary."""
    t0 = parent.started = time.monotonic()
    kw = {**{k: getattr(parent, k) for k in _FIELDS}, "origin": t0}
    if parent.max_cases is not None:  # the budget shared: N workers run max_cases in all
        kw["max_cases"] = max(1, parent.max_cases // jobs)
    per: dict[int, dict[str, Any]] = {}
    done: dict[int, dict[str, Any]] = {}
    view = SimpleNamespace(cases=0, fuzz_s=0.0, findings=[], restarts=0, tried={}, started=t0, engine=parent.engine)

    def handle(kind: str, worker: int, body: Any) -> bool:
        per[worker] = body
        if kind == "done":
            done[worker] = body
        _merge_view(view, per)
        if live is not None:
            live.update(view)
        return parent.stop_after is not None and len(view.findings) >= parent.stop_after

    interrupted = run_workers(_worker, lambda i, q, stop: (kw, i, q, stop), jobs, campaign_end(t0, parent.duration),
                              handle, lambda: len(done) >= jobs)
    _merge(parent, per, done, jobs)
    summary = parent.summary(time.monotonic() - t0)
    if interrupted:
        summary["interrupted"] = True
    return summary


def _distinct(signatures: list[Any]) -> list[Any]:
    seen: dict[Any, Any] = {}
    for s in signatures:
        seen.setdefault(s.key, s)
    return list(seen.values())


def _merge_view(view: Any, per: dict[int, dict[str, Any]]) -> None:
    view.cases = sum(b["cases"] for b in per.values())
    view.fuzz_s = max((b["fuzz_s"] for b in per.values()), default=0.0)
    view.restarts = sum(b["restarts"] for b in per.values())
    view.findings = [SimpleNamespace(signature=s) for s in _distinct([s for b in per.values() for s in b["signatures"]])]
    view.tried = _sum_tables([b["tried"] for b in per.values()])


def _sum_tables(tables: list[dict[str, dict[str, int]]]) -> dict[str, dict[str, int]]:
    out: dict[str, dict[str, int]] = {}
    for t in tables:
        for kind, row in t.items():
            o = out.setdefault(kind, {})
            for k, n in row.items():
                o[k] = o.get(k, 0) + n
    return out


def _merge(parent: StreamCampaign, per: dict[int, dict[str, Any]], done: dict[int, dict[str, Any]], jobs: int) -> None:
    parent.cases = sum(b["cases"] for b in per.values())
    parent.fuzz_s = max((b["fuzz_s"] for b in per.values()), default=0.0)
    parent.triage_s = sum(b["triage_s"] for b in per.values())
    parent.restart_s = sum(b.get("restart_s", 0.0) for b in per.values())
    for e in (e for b in per.values() for e in b.get("environment", [])):
        parent.environment.add(e)
    parent.restarts = sum(b["restarts"] for b in per.values())
    parent.unconfirmed = sum(b["unconfirmed"] for b in per.values())
    parent.tried = _sum_tables([b["tried"] for b in per.values()])
    parent.untriaged = _sum_tables([{"": b.get("untriaged", {})} for b in per.values()]).get("", {})
    by_kind: dict[str, int] = {}
    for b in per.values():
        for k, n in b["by_kind"].items():
            by_kind[k] = by_kind.get(k, 0) + n
    parent.by_kind = by_kind
    for w in sorted(done):
        for f in done[w]["findings"]:
            known = next((g for g in parent.findings if g.signature.key == f.signature.key), None)
            if known is not None:
                known.occurrences += f.occurrences
            else:
                parent.store.add(f)
    parent.workers = [{"worker": i, "cases": per.get(i, {}).get("cases", 0),
                       "fuzz_s": round(per.get(i, {}).get("fuzz_s", 0.0), 2),
                       "findings": len(done.get(i, {}).get("findings", [])),
                       "error": done[i]["error"] if i in done else "gave no result"} for i in range(jobs)]

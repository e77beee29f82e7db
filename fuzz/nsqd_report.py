"""An Nsqd campaign's ``summary.json`` and its closing lines (issue 21 item 5; issue 36 item 5):
cases, judged cases/s (triage's replays excluded), findings by class (the oracle) and each
one, which message ids x mutation kinds were sent, where the time went (fuzzing, triage's
share against its budget, restarts; ``--duration`` and its grace)."""

from __future__ import annotations

import sys
from typing import Any

from mcp_conform.fuzz.budget import TRIAGE_SHARE
from mcp_conform.fuzz.config import FuzzConfig, exit_code
from mcp_conform.fuzz.environment import environment_lines
from mcp_conform.fuzz.findings import FindingStore
from mcp_conform.fuzz.loop import WorkerResult, common_summary, count
from mcp_conform.fuzz.progress import interrupted
from mcp_conform.fuzz.workers import sum_tables
from mcp_conform.spec.profiles import NSQD_PROFILE

__all__ = ["budget_line", "final", "summary"]

PROG = "mcp-fuzz"


def summary(cfg: FuzzConfig, store: FindingStore, results: list[WorkerResult], elapsed: float, error: str | None,
            *, interrupted: bool = False, node_lost: bool = False) -> dict[str, Any]:
    """``summary.json`` of an Nsqd campaign (``fuzz.loop.run_campaign`` writes it): the keys
    every protocol's has (``fuzz.loop.common_summary``), then Nsqd's: each finding, by class
    (the oracle), the kinds x message ids sent, fuzzing and restart seconds, the hits counted
    and not triaged by signature, the ``--duration`` bound (``duration_s``), each worker's
    figures under ``--jobs``."""
    by_class: dict[str, int] = {}
    for f in store.order:
        count(by_class, f.signature.oracle)
    s = {"protocol": NSQD_PROFILE.name, **common_summary(cfg, results, elapsed, error, interrupted),
         "elapsed_s": round(elapsed, 2),
         "fuzz_s": round(max((r.fuzz_seconds for r in results), default=0.0), 2),
         "restart_s": round(sum(r.restart_seconds for r in results), 2),
         "by_kind": sum_tables({"": r.by_mutator} for r in results).get("", {}),
         "tried": sum_tables(r.tried for r in results), "findings_by_class": by_class,
         "findings": [{"signature": f.signature.describe(), "oracle": f.signature.oracle, "rule": f.signature.rule,
                       "count": f.occurrences, "replays": f.replays, "no_input": f.no_input,
                       "engine": "stateful" if f.program is not None else "stateless"} for f in store.order],
         "untriaged": sum_tables({"": r.untriaged} for r in results).get("", {}), "db": cfg.db,
         "duration_s": cfg.duration_limit, "triage_share_max": TRIAGE_SHARE, "node_lost": node_lost}
    if cfg.jobs > 1:
        s["workers"] = [{"worker": r.worker, "cases": r.cases, "fuzz_s": round(r.fuzz_seconds, 2),
                         "findings": r.findings, "error": r.error} for r in results]
    return s


def final(store: FindingStore, summary: dict[str, Any], live: Any, strict: bool) -> int:
    """The closing lines of a campaign of ``summary`` whose findings are in ``store``: each finding, the environment-dependent ones, the hits counted and
    not triaged (``-v``), the summary and where the time went; the exit code."""
    errors = [w["error"] for w in summary.get("workers", []) if w.get("error")]
    if errors and not summary["cases"]:
        print(f"{PROG}: {budget_line(summary)}")  # where it ended: at the bound, if the workers were cut there
        print(f"{PROG}: error: {errors[0]}", file=sys.stderr)
        return 2
    for i, f in enumerate(store.order, 1):
        print(f"finding-{i}: {f.signature.describe()} ×{f.occurrences}, replays {f.replays}: {f.note}")
        if live.verbose:
            print(f"  {f.actual}")
    for line in environment_lines(summary) if not live.quiet else ():
        print(line)
    if live.verbose:
        for shape, n in sorted(summary.get("untriaged", {}).items(), key=lambda kv: -kv[1]):
            print(f"  counted, not triaged: {shape} ×{n}")
    classes = ", ".join(f"{k} {n}" for k, n in sorted(summary["findings_by_class"].items())) or "none"
    print(f"{PROG}: {summary['cases']} cases in {summary['elapsed_s']} s ({summary['judged_cases_per_s']} judged "
          f"cases/s), {len(store)} finding(s) ({classes}), {summary['unconfirmed']} unconfirmed; "
          f"engine {summary['engine']}, {summary['jobs']} job(s), seed {summary['seed']}")
    print(f"{PROG}: {budget_line(summary)}")
    if summary.get("interrupted"):
        return interrupted(summary["cases"], len(store), store.out)
    return exit_code(store.order, strict=strict)


def budget_line(s: dict[str, Any]) -> str:
    """Where the time went: fuzzing, triage's own replays (its share against its budget) and
    the restarts to go on fuzzing, the --duration bound and its grace (issue 36 items 2, 5),
    the hits counted rather than triaged."""
    bound = (f"--duration {s['duration_s']:g} s + grace {s['grace_s']:g} s" if s.get("duration_s") is not None
             else "no --duration")
    untriaged = sum(s.get("untriaged", {}).values())
    return (f"fuzzing {s['fuzz_s']:g} s, triage {s['triage_s']:g} s ({100 * s.get('triage_share', 0):.0f} %, "
            f"budget {100 * s.get('triage_share_max', 0):.0f} %), restarts {s.get('restart_s', 0):g} s "
            f"({s.get('restarts', 0)}) of {s['elapsed_s']:g} s; {bound}"
            + (f"; {untriaged} hit(s) counted, not triaged (budget or deadline spent, or not reproduced "
               "twice)" if untriaged else ""))

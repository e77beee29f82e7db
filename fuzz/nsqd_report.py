"""An Nsqd campaign's ``summary.json`` and its closing lines (issue 21 item 5; issue 36 item 5):
cases, judged cases/s (triage's replays excluded), findings by class (the oracle) and each
one, which message ids x mutation kinds were sent, where the time went (fuzzing, triage's
share against its budget, restarts; ``--duration`` and its grace)."""

from __future__ import annotations

import json
import sys
from typing import Any

from mcp_conform.fuzz.budget import GRACE_S, TRIAGE_SHARE
from mcp_conform.fuzz.config import exit_code
from mcp_conform.fuzz.environment import environment_lines
from mcp_conform.fuzz.progress import interrupted
from mcp_conform.spec.profiles import NSQD_PROFILE

__all__ = ["budget_line", "final", "summary"]

PROG = "mcp-fuzz"


def summary(c: Any, elapsed: float) -> dict[str, Any]:
    """``summary.json`` of the campaign ``c`` (``fuzz.nsqd_campaign.StreamCampaign``),
    written under its ``out``."""
    by_class: dict[str, int] = {}
    for f in c.findings:
        by_class[f.signature.oracle] = by_class.get(f.signature.oracle, 0) + 1
    s = {"protocol": NSQD_PROFILE.name, "engine": c.engine, "seed": c.seed, "cases": c.cases,
         "elapsed_s": round(elapsed, 2), "cases_per_s": round(c.cases / elapsed, 1) if elapsed else 0,
         "fuzz_s": round(c.fuzz_s, 2), "triage_s": round(c.triage_s, 2),
         "restart_s": round(c.restart_s, 2),
         "judged_cases_per_s": round(c.cases / c.fuzz_s, 1) if c.fuzz_s else 0,
         "by_kind": c.by_kind, "tried": c.tried, "findings_by_class": by_class,
         "findings": [{"signature": f.signature.describe(), "oracle": f.signature.oracle, "rule": f.signature.rule,
                       "count": f.occurrences, "replays": f.replays, "no_input": f.no_input, "engine": "stateful" if f.program is not None
                       else "stateless"} for f in c.findings],
         "unconfirmed": c.unconfirmed, "environment_dependent": c.environment.values(),
         "untriaged": c.untriaged, "restarts": c.restarts, "db": c.db,
         "duration_s": c.duration, "grace_s": GRACE_S, "triage_share_max": TRIAGE_SHARE,
         "triage_share": round(c.triage_s / elapsed, 3) if elapsed else 0.0,
         "jobs": len(c.workers) if c.workers is not None else 1, "interrupted": c.interrupted}
    if c.workers is not None:
        s["workers"] = c.workers
    if c.out is not None:
        c.store.rewrite()  # the occurrences counted since each was written
        (c.out / "summary.json").write_text(json.dumps(s, indent=2) + "\n")
    return s


def final(c: Any, summary: dict[str, Any], live: Any, strict: bool) -> int:
    """The closing lines: each finding, the environment-dependent ones, the hits counted and
    not triaged (``-v``), the summary and where the time went; the exit code."""
    errors = [w["error"] for w in summary.get("workers", []) if w.get("error")]
    if errors and not summary["cases"]:
        print(f"{PROG}: {budget_line(summary)}")  # where it ended: at the bound, if the workers were cut there
        print(f"{PROG}: error: {errors[0]}", file=sys.stderr)
        return 2
    for i, f in enumerate(c.findings, 1):
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
          f"cases/s), {len(c.findings)} finding(s) ({classes}), {summary['unconfirmed']} unconfirmed; "
          f"engine {c.engine}, {summary['jobs']} job(s), seed {c.seed}")
    print(f"{PROG}: {budget_line(summary)}")
    if summary.get("interrupted"):
        return interrupted(summary["cases"], len(c.findings), c.out)
    return exit_code(c.findings, strict=strict)


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

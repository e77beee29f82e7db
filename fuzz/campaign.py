"""A campaign: one or more workers, each with its own target, running the chosen engines
within the budget (``--duration``, ``--max-cases``), findings gathered in one store and
``summary.json`` written at the end, whatever happened.

``--jobs N`` starts N worker processes, each with its own spawned node on its own ports and
its own seed stream (``seed``, worker index); the stateful engine's workers share
hypothesis's example database (``--db``), so a failure one worker found is replayed first by
the others. Findings come back to the parent, which groups them across workers and writes
``finding-N/``.

``--duration`` counts from the campaign's start (``fuzz.budget``): a worker's deadlines are
the campaign's, its node's start included, and the ``--jobs`` parent stops waiting at the
same bound, ``--duration`` plus ``GRACE_S``.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

from mcp_conform.fuzz.budget import GRACE_S, campaign_end, engine_turns
from mcp_conform.fuzz.config import FuzzConfig, exit_code
from mcp_conform.fuzz.engine_stateless import EngineStats, StatelessEngine
from mcp_conform.fuzz.environment import merge_environment
from mcp_conform.fuzz.findings import FindingStore, write_summary
from mcp_conform.fuzz.progress import Progress, interrupted
from mcp_conform.fuzz.target_base import TargetLost
from mcp_conform.fuzz.targets import start_target
from mcp_conform.fuzz.triage import Triage
from mcp_conform.fuzz.workers import Reporter, report, run_jobs
from mcp_conform.harness.errors import SetupError
from mcp_conform.spec import SPEC

__all__ = ["DatagramCampaign", "Progress", "WorkerResult", "load_seeds", "run_campaign", "run_worker"]



@dataclass
class WorkerResult:
    worker: int
    cases: int = 0
    fuzz_seconds: float = 0.0
    restarts: int = 0
    restart_reasons: dict[str, int] = field(default_factory=dict)
    replays: int = 0
    unconfirmed: int = 0
    engines: dict[str, dict[str, Any]] = field(default_factory=dict)
    error: str | None = None
    monitor: bool = False
    node_period: float | None = None  # the node's retransmission period, measured at start
    timing: str | None = None  # it disagreed with --rto: what the campaign did about it
    interrupted: bool = False  # SIGINT (or the parent's stop) ended it early
    lost: bool = False  # attach mode: the node stopped answering (``error`` says so)
    triage_seconds: float = 0.0
    untriaged: int = 0  # flaws left untriaged at the deadline
    environment: list[dict[str, Any]] = field(default_factory=list)  # environment-dependent flaws, with why


def load_seeds(directory: str | None) -> list[bytes]:
    """The datagrams the manager side sent in the MCAP captures of ``directory`` (``--seeds``)."""
    if directory is None:
        return []
    from mcp_conform.traceio.reader import CaptureError, Datagram, open_capture

    d = Path(directory)
    if not d.is_dir():
        raise SetupError(f"--seeds: {directory!r} is not a directory")
    out: list[bytes] = []
    for p in sorted(d.rglob("*.mcap")):
        try:
            for rec in open_capture(p):
                if isinstance(rec, Datagram) and rec.direction in ("tx", None) and rec.data:
                    out.append(bytes(rec.data))
        except CaptureError as exc:
            raise SetupError(f"--seeds: {exc}") from None
    if not out:
        raise SetupError(f"--seeds: no datagrams in the MCAP files of {directory!r}")
    return out


def _record(res: WorkerResult, name: str, st: EngineStats, triage: Triage) -> None:
    """An engine's counts into its worker's result (also when it ended early)."""
    res.cases += st.cases
    res.fuzz_seconds += st.seconds
    res.engines[name] = {"cases": st.cases, "fuzz_seconds": round(st.seconds, 3),
                         "judged_cases_per_s": round(st.cases / st.seconds, 1) if st.seconds else 0.0,
                         "batches": st.batches, "flaws_seen": st.flaws,
                         "replays": triage.replays, "unconfirmed": triage.unconfirmed,
                         "unconfirmed_by_rule": dict(triage.unconfirmed_rules),
                         "triage_seconds": round(triage.seconds, 3), "untriaged": triage.untriaged}
    res.replays += triage.replays
    res.unconfirmed += triage.unconfirmed
    res.triage_seconds += triage.seconds
    res.untriaged += triage.untriaged
    res.environment = merge_environment([*res.environment, *triage.environment.values()])


def run_worker(cfg: FuzzConfig, store: FindingStore, tick: Callable[[Progress], None] | None = None,
               seeds: list[bytes] | None = None, stop_event: Any = None,
               started: float | None = None) -> WorkerResult:
    """One worker: start its target, run the engines, close the target. Whatever ends it, the
    counts so far are kept (issue 19 items 1, 6): a node lost in attach mode (``TargetLost``)
    sets ``lost`` and ``error``, SIGINT (KeyboardInterrupt) or ``stop_event`` sets
    ``interrupted``. ``--duration`` counts from ``started`` (the campaign's start; default now)."""
    start = started if started is not None else time.monotonic()
    res = WorkerResult(cfg.worker)
    target = start_target(cfg)
    res.node_period, res.timing = target.node_period, target.timing
    prog = Progress()
    stop_rule = cfg.extra.get("stop_on_rule")  # tests: stop once this rule is found

    def stop() -> bool:
        if stop_event is not None and stop_event.is_set():
            res.interrupted = True
            return True
        return stop_rule is not None and any(f.rule == stop_rule for f in store.order)

    try:
        duration = cfg.duration_limit
        base: set[str] | None = None
        for name, deadline, cap in engine_turns(cfg.engine, start, duration, cfg.max_cases):
            if stop():
                break
            budget = None if cap is None else max(0, cap - res.cases)
            triage = Triage(target, store, name, cfg.seed, cfg.worker)
            if duration is not None:
                triage.deadline = start + duration  # --duration bounds triage too (GRACE_S)
            if base is not None:  # the baseline is the worker's, whatever the engine
                triage.baseline_rules = base
            prog.engine = name

            def on_tick(st: EngineStats, base_c: int = res.cases, base_s: float = res.fuzz_seconds) -> None:
                prog.cases = base_c + st.cases
                prog.fuzz_seconds = base_s + st.seconds
                prog.findings = len(store)
                prog.restarts = target.restarts
                if tick is not None:
                    tick(prog)

            eng: Any = None
            try:
                if name == "stateless":
                    eng = StatelessEngine(target, triage, cfg.seed, worker=cfg.worker, seeds=seeds)
                    res.monitor = eng.monitor.available
                    eng.run(deadline, budget, on_tick, stop)
                else:
                    from mcp_conform.fuzz.drone_target import FuzzTarget
                    from mcp_conform.fuzz.engine_stateful import StatefulEngine

                    assert isinstance(target, FuzzTarget)  # a drone (the CLI refuses a manager)
                    eng = StatefulEngine(target, triage, cfg)
                    eng.run(deadline, budget, on_tick, stop)
            finally:
                base = triage.baseline_rules
                if eng is not None:
                    _record(res, name, eng.stats, triage)
                    if name != "stateless":
                        res.monitor = res.monitor or eng.monitor_available
    except TargetLost as exc:
        res.error, res.lost = str(exc), True
    except KeyboardInterrupt:
        res.interrupted = True
    finally:
        res.restarts = target.restarts
        res.restart_reasons = dict(target.restart_reasons)
        target.close()
    return res


def _worker_process(cfg: FuzzConfig, seeds: list[bytes], q: Any, stop_event: Any = None,
                    started: float | None = None) -> None:
    """A ``--jobs`` worker process: its result (and findings) go back on ``q``. SIGINT is the
    parent's to handle: it sets ``stop_event``, and the worker ends its round and reports.
    ``started``: the parent's start (the monotonic clock is the machine's), its deadlines'."""
    reporter = Reporter(q, cfg.worker)
    store = FindingStore(None)

    def tick(p: Progress) -> None:
        reporter.progress(lambda: report(p.cases, p.fuzz_seconds, p.restarts, list(store.order)))

    try:
        res = run_worker(cfg, store, tick, seeds, stop_event, started)
    except SetupError as exc:
        res = WorkerResult(cfg.worker, error=str(exc))
    except Exception as exc:  # noqa: BLE001 - reported by the parent in one line
        res = WorkerResult(cfg.worker, error=f"worker {cfg.worker} failed: {type(exc).__name__}: {exc}")
    reporter.done(report(res.cases, res.fuzz_seconds, res.restarts, store.order, result=asdict(res),
                         findings=list(store.order)))


def run_campaign(cfg: FuzzConfig, store: FindingStore,
                 tick: Callable[[Progress], None] | None = None) -> dict[str, Any]:
    """Run the campaign; the summary (also written to ``--out``/summary.json). SIGINT ends it
    with the counts and findings so far and ``"interrupted": true`` (issue 19 item 6); a node
    lost in attach mode with ``"node_lost": true`` and the error naming it (item 1)."""
    t0 = time.monotonic()
    seeds = load_seeds(cfg.seeds_dir)
    results: list[WorkerResult] = []
    error: str | None = None
    interrupted = False
    try:
        if cfg.jobs <= 1:
            results.append(run_worker(cfg.for_worker(0), store, tick, seeds, started=t0))
        else:
            results, error, interrupted = _run_jobs(cfg, store, seeds, tick, t0)
    except SetupError as exc:
        error = str(exc)
        raise
    except KeyboardInterrupt:  # before the worker ran (while its node started)
        interrupted = True
    finally:
        interrupted = interrupted or any(r.interrupted for r in results)
        lost = [r.error for r in results if r.lost and r.error]
        if lost:
            error = lost[0]
        elif interrupted and error is None:
            error = "interrupted (SIGINT)"
        summary = make_summary(cfg, store, results, time.monotonic() - t0, error,
                               interrupted=interrupted, node_lost=bool(lost))
        if cfg.out is not None:
            write_summary(Path(cfg.out) / "summary.json", summary)
    return summary


class DatagramCampaign:
    """``mcp-fuzz``'s campaign of a datagram protocol (MCP's profile names it,
    ``fuzz.config.FuzzCampaign``): :func:`run_campaign` over the role's target, its findings
    in one store (``--live``: also served to Foxglove, ``fuzz.live``)."""

    REFUSED: tuple[str, ...] = ()

    def __init__(self, cfg: FuzzConfig, tick: Callable[[Progress], None] | None = None) -> None:
        self.cfg, self.tick, self.served = cfg, tick, None
        if "live" in cfg.extra:  # --live: the campaign on a Foxglove WebSocket server (fuzz.live)
            from mcp_conform.fuzz.live import LiveCampaign, LiveStore
            from mcp_conform.traceio.live import LiveError

            try:
                self.served = LiveCampaign(cfg, *cfg.extra["live"])
            except LiveError as exc:
                raise SetupError(str(exc)) from None
            self.store: FindingStore = LiveStore(cfg.out, cfg.replay_args(), self.served.recorder)
            self.served.started(cfg)
        else:
            self.store = FindingStore(cfg.out, cfg.replay_args())

    @classmethod
    def from_config(cls, cfg: FuzzConfig, tick: Callable[[Progress], None] | None) -> DatagramCampaign:
        return cls(cfg, tick)

    def fuzz(self) -> dict[str, Any]:
        try:
            summary = run_campaign(self.cfg, self.store, self.tick)
            if self.served is not None:
                self.served.ended(summary)
            return summary
        finally:
            if self.served is not None:  # nothing left listening, however the campaign ended
                self.served.close()

    def abort(self) -> None:
        """(:func:`run_campaign` writes summary.json however it ends.)"""

    def final(self, summary: dict[str, Any], live: Any, strict: bool) -> int:
        live.final(summary, self.store)
        if summary.get("interrupted"):
            return interrupted(summary["cases"], summary["findings"], self.cfg.out)
        if summary.get("node_lost"):
            print(f"mcp-fuzz: error: {summary['error']}", file=sys.stderr)
            return 2
        return exit_code(self.store.order, strict=strict)

    @staticmethod
    def replay(path: str, cfg: FuzzConfig) -> int:
        from mcp_conform.fuzz.replay_cli import replay_finding

        return replay_finding(path, cfg)


def _run_jobs(cfg: FuzzConfig, store: FindingStore, seeds: list[bytes], tick: Callable[[Progress], None] | None,
              t0: float) -> tuple[list[WorkerResult], str | None, bool]:
    jobs = run_jobs(_worker_process, lambda i, q, stop: (cfg.for_worker(i), seeds, q, stop, t0), cfg.jobs,
                    campaign_end(t0, cfg.duration_limit), store, tick, Progress(started=t0))
    results = {i: WorkerResult(**b["result"]) for i, b in jobs.done.items()}
    errors = [r.error for r in results.values() if r.error]
    missing = [i for i in range(cfg.jobs) if i not in results]
    if missing:
        errors.append(f"worker(s) {', '.join(map(str, missing))} gave no result")
        for i in missing:  # what its progress said, at least
            b = jobs.per.get(i, {})
            results[i] = WorkerResult(i, cases=b.get("cases", 0), fuzz_seconds=b.get("fuzz_s", 0.0),
                                      restarts=b.get("restarts", 0), interrupted=jobs.interrupted,
                                      error="gave no result")
    if errors and not any(r.cases for r in results.values()) and not jobs.interrupted:
        raise SetupError(errors[0])
    return [results[i] for i in sorted(results)], ("; ".join(errors) or None), jobs.interrupted


def _sum_counts(counts: Iterable[dict[str, int]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for c in counts:
        for k, n in c.items():
            out[k] = out.get(k, 0) + n
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def make_summary(cfg: FuzzConfig, store: FindingStore, results: list[WorkerResult],
                 duration: float, error: str | None, *, interrupted: bool = False,
                 node_lost: bool = False) -> dict[str, Any]:
    """``summary.json``: cases, judged cases/s, findings by rule, seed, duration; whether
    SIGINT ended it (``interrupted``) or the node was lost in attach mode (``node_lost``)."""
    from mcp_conform.spec.about import tool_version

    cases = sum(r.cases for r in results)
    fuzz_s = max((r.fuzz_seconds for r in results), default=0.0)
    store.rewrite()
    return {
        "schema_version": 1,
        "tool": {"name": "mcp-fuzz", "version": tool_version()},
        "spec": {"version": SPEC.version},
        "target": {"mode": cfg.mode, "target": f"{cfg.target[0]}:{cfg.target[1]}" if cfg.target else None,
                   "spawn": cfg.spawn, "mavlink": cfg.mavlink},
        "engine": cfg.engine,
        "seed": cfg.seed,
        "jobs": cfg.jobs,
        "cases": cases,
        "duration_s": round(duration, 3),
        "cases_per_s": round(cases / duration, 1) if duration > 0 else 0.0,
        "judged_cases_per_s": round(cases / fuzz_s, 1) if fuzz_s > 0 else 0.0,
        "findings": len(store),
        "findings_by_rule": store.by_rule(),
        "restarts": sum(r.restarts for r in results),
        "restarts_by_reason": _sum_counts(r.restart_reasons for r in results),
        "replays": sum(r.replays for r in results),
        "triage_s": round(max((r.triage_seconds for r in results), default=0.0), 3),
        "triage_share": round(max((r.triage_seconds for r in results), default=0.0) / duration, 3)
        if duration > 0 else 0.0,
        "grace_s": GRACE_S,
        "duration_limit_s": cfg.duration_limit,
        "untriaged": sum(r.untriaged for r in results),
        "environment_dependent": merge_environment(e for r in results for e in r.environment),
        "unconfirmed": sum(r.unconfirmed for r in results),
        "monitor": any(r.monitor for r in results),
        "node_period_s": next((round(r.node_period, 4) for r in results if r.node_period is not None), None),
        "timing": next((r.timing for r in results if r.timing), None),
        "workers": [{"worker": r.worker, "cases": r.cases, "engines": r.engines, "error": r.error,
                     "interrupted": r.interrupted} for r in results],
        "interrupted": interrupted,
        "node_lost": node_lost,
        "error": error,
    }

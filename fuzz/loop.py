"""One campaign loop for every protocol (issue 37: the protocol a plug-in).

A campaign is one or more workers, each with its own target, running the engines ``--engine``
names (``fuzz.budget.engine_turns``: ``both`` shares the duration and the cases out) until
their budget, a stop asked for or SIGINT; its findings are gathered in one store
(``fuzz.findings``) and ``summary.json`` is written at the end, whatever happened. This module
is that loop, written once: the deadlines counted from the campaign's start (``--duration``
plus ``GRACE_S``), the engines' turns, the ``--jobs`` worker processes (``fuzz.workers``), the
live figures (``fuzz.progress``), a node lost in attach mode (``TargetLost``) or SIGINT ending
it with the counts so far, triage's time, replays, unconfirmed, untriaged and
environment-dependent flaws counted per engine, restarts by reason, and the summary's keys
both protocols share (:func:`common_summary`).

A protocol supplies its parts through a :class:`Plugin` (MCP's: ``fuzz.campaign.McpPlugin``;
Nsqd's: ``fuzz.nsqd_campaign.NsqdPlugin``): how its target starts, its triage for an engine's
turn (how a hit is replayed, minimised, confirmed and kept: ``fuzz.triage``,
``fuzz.nsqd_triage``), its engines (how a case is drawn, sent and judged by its oracles), what
else a worker records, and its own summary keys and closing lines.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Iterator
from contextlib import AbstractContextManager, contextmanager
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Protocol

from mcp_conform.fuzz.budget import GRACE_S, Late, campaign_end, engine_turns
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.environment import EnvironmentLog, merge_environment
from mcp_conform.fuzz.findings import FindingStore, write_summary
from mcp_conform.fuzz.progress import Progress
from mcp_conform.fuzz.target_base import Restarts, TargetLost
from mcp_conform.fuzz.workers import Reporter, report, run_jobs, sum_tables
from mcp_conform.harness.errors import SetupError

__all__ = ["TICK_S", "Engine", "EngineStats", "FuzzClock", "Plugin", "Target", "Triage", "WorkerResult", "WorkerTarget", "common_summary", "count",
           "note_tried", "run_campaign", "run_worker", "triage_time"]


@dataclass
class EngineStats:
    """What an engine counts, whatever its protocol."""

    cases: int = 0  # inputs sent and judged
    batches: int = 0
    flaws: int = 0
    restarts: int = 0
    seconds: float = 0.0  # time spent fuzzing (triage excluded)
    by_mutator: dict[str, int] = field(default_factory=dict)  # cases by mutation kind
    tried: dict[str, dict[str, int]] = field(default_factory=dict)  # kind -> message -> cases, when counted

    def spent(self, deadline: float, max_cases: int | None, stop: Callable[[], bool]) -> bool:
        """Whether an engine's turn is over: its ``deadline`` (time.monotonic) come, its
        ``max_cases`` judged, or a stop asked for."""
        return time.monotonic() >= deadline or (max_cases is not None and self.cases >= max_cases) or stop()


TICK_S = 0.25  # s: an engine's live figures at most this often


def count(table: dict[str, int], key: str, n: int = 1) -> None:
    """One more (``n`` more) of ``key`` in a table of counts."""
    table[key] = table.get(key, 0) + n


def note_tried(st: EngineStats, kind: str, messages: Iterable[str]) -> None:
    """A case of mutation ``kind`` sent with these ``messages`` (their names): the progress
    table of kinds x message ids, summary.json's ``tried``."""
    row = st.tried.setdefault(kind, {})
    for name in messages:
        count(row, name)


class FuzzClock:
    """An engine's turn as the loop counts it: each case drawn (:meth:`case`: cases, kinds and
    messages tried, the live figures every :data:`TICK_S`), the time spent fuzzing
    (``EngineStats.seconds``), paused while a hit is triaged (:meth:`triage`)."""

    def __init__(self, st: EngineStats, tick: Callable[[EngineStats], None] | None) -> None:
        self.st, self.tick = st, tick
        self.last_tick = 0.0
        self.t_fuzz = time.monotonic()

    def case(self, kind: str | None, messages: Iterable[str] = (), *, mutation: bool = True) -> None:
        """A case (an op of a stateful program: ``kind`` None when it sends nothing), its kind
        counted (``mutation``: as a mutation's, ``by_mutator``) and its messages tried."""
        st = self.st
        st.cases += 1
        if kind is not None:
            if mutation:
                count(st.by_mutator, kind)
            note_tried(st, kind, messages)
        now = time.monotonic()
        if now - self.last_tick >= TICK_S:
            self.last_tick = now
            st.seconds += now - self.t_fuzz
            self.t_fuzz = now
            if self.tick is not None:
                self.tick(st)

    def triage(self) -> AbstractContextManager[None]:
        """A flaw: counted; its triage's time is not fuzzing time."""
        self.st.flaws += 1
        self.stop()
        return _resume(self)

    def stop(self) -> None:
        """The fuzzing time so far into the stats (at a triage, at the turn's end)."""
        now = time.monotonic()
        self.st.seconds += now - self.t_fuzz
        self.t_fuzz = now


@contextmanager
def _resume(clock: FuzzClock) -> Iterator[None]:
    try:
        yield
    finally:
        clock.t_fuzz = time.monotonic()


class Target(Protocol):
    """A worker's node under test, as the loop sees it."""

    restarts: int
    restart_reasons: dict[str, int]

    def close(self) -> None: ...


class WorkerTarget(Restarts):
    """A worker's target as the loop sees one (:class:`Target`): the one now fuzzed
    (``current``: triage's replays and restarts replace it), whether it is attached (a death
    is then the target lost, not a finding), its restarts counted by reason
    (``fuzz.target_base.Restarts``, as MCP's targets count theirs)."""

    def __init__(self, current: Any, attached: bool = False) -> None:
        super().__init__()
        self.current, self.attached = current, attached

    def close(self) -> None:
        self.current.close()


@dataclass(kw_only=True, eq=False)
class Triage:
    """What every protocol's triage (an engine's turn's: ``fuzz.triage.Triage``,
    ``fuzz.nsqd_triage.StreamTriage``) counts, as the loop records it, and the bound it keeps:
    no replay starts after ``--duration`` counted from ``started`` (``fuzz.budget.check_late``)."""

    started: float = field(default_factory=time.monotonic)
    duration: float | None = None
    replays: int = 0  # replays run
    unconfirmed: int = 0
    unconfirmed_rules: dict[str, int] = field(default_factory=dict)  # flaws seen, then not again, by rule
    seconds: float = 0.0  # triage's own time (its replays, the processes they start)
    restart_seconds: float = 0.0  # the target restarted to go on fuzzing after a hit (not triage's)
    triage_from: float | None = None  # when the triage under way began (``fuzz.budget.over_budget``)
    untriaged: dict[str, int] = field(default_factory=dict)  # hits counted, not triaged (deadline, budget)
    environment: EnvironmentLog = field(default_factory=EnvironmentLog)  # seen, then not on every replay: why

    def count_unconfirmed(self, rule: str) -> None:
        """A hit of ``rule`` that triage could not confirm."""
        self.unconfirmed += 1
        count(self.unconfirmed_rules, rule)


class Engine(Protocol):
    stats: EngineStats

    def run(self, deadline: float, max_cases: int | None, tick: Callable[[EngineStats], None] | None,
            stop: Callable[[], bool]) -> EngineStats:
        """Fuzz until ``deadline`` (time.monotonic), ``max_cases`` judged, or ``stop()``."""


class Plugin(Protocol):
    """A protocol's parts of one worker's campaign."""

    def start(self, cfg: FuzzConfig) -> Target:
        """The worker's target, started (SetupError: it cannot)."""

    def triage(self, target: Any, store: FindingStore, name: str, cfg: FuzzConfig, started: float,
               prev: Any) -> Triage:
        """The triage of engine ``name``'s turn; ``prev``: the previous turn's (what it carries on)."""

    def engine(self, name: str, target: Any, triage: Any, cfg: FuzzConfig) -> Engine:
        """Engine ``name`` over ``target``, its hits to ``triage``."""

    def record(self, res: WorkerResult, name: str, engine: Any) -> None:
        """What else the worker's result keeps of an engine's turn."""


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
    interrupted: bool = False  # SIGINT (or the parent's stop) ended it early
    lost: bool = False  # attach mode: the node stopped answering (``error`` says so)
    triage_seconds: float = 0.0
    restart_seconds: float = 0.0  # the target restarted to go on fuzzing (when timed)
    untriaged: dict[str, int] = field(default_factory=dict)  # hits left untriaged, by what they showed
    environment: list[dict[str, Any]] = field(default_factory=list)  # environment-dependent flaws, with why
    by_mutator: dict[str, int] = field(default_factory=dict)
    tried: dict[str, dict[str, int]] = field(default_factory=dict)
    findings: int = 0  # distinct findings in the worker's own store
    extra: dict[str, Any] = field(default_factory=dict)  # the protocol's own (its Plugin.record)


def _record(res: WorkerResult, name: str, st: EngineStats, triage: Triage) -> None:
    """An engine's counts into its worker's result (also when it ended early)."""
    res.cases += st.cases
    res.fuzz_seconds += st.seconds
    untriaged = sum(triage.untriaged.values())
    res.engines[name] = {"cases": st.cases, "fuzz_seconds": round(st.seconds, 3),
                         "judged_cases_per_s": round(st.cases / st.seconds, 1) if st.seconds else 0.0,
                         "batches": st.batches, "flaws_seen": st.flaws,
                         "replays": triage.replays, "unconfirmed": triage.unconfirmed,
                         "unconfirmed_by_rule": dict(triage.unconfirmed_rules),
                         "triage_seconds": round(triage.seconds, 3), "untriaged": untriaged}
    res.replays += triage.replays
    res.unconfirmed += triage.unconfirmed
    res.triage_seconds += triage.seconds
    res.restart_seconds += triage.restart_seconds
    for k, n in triage.untriaged.items():
        count(res.untriaged, k, n)
    for k, n in st.by_mutator.items():
        count(res.by_mutator, k, n)
    res.tried = sum_tables([res.tried, st.tried])
    res.environment = merge_environment([*res.environment, *triage.environment.values()])


def run_worker(plugin: Plugin, cfg: FuzzConfig, store: FindingStore, tick: Callable[[Progress], None] | None = None,
               stop_event: Any = None, started: float | None = None,
               stop_when: Callable[[], bool] | None = None) -> WorkerResult:
    """One worker: start its target, run the engines, close the target. Whatever ends it, the
    counts so far are kept (issue 19 items 1, 6): a node lost in attach mode (``TargetLost``)
    sets ``lost`` and ``error``, SIGINT (KeyboardInterrupt) or ``stop_event`` sets
    ``interrupted``. ``--duration`` counts from ``started`` (the campaign's start; default now).
    ``cfg.extra``: ``stop_on_rule`` (stop once a finding of this rule is kept), ``stop_after``
    (once this many are); ``stop_when()``: a caller's own reason to stop (a benchmark's)."""
    start = started if started is not None else time.monotonic()
    res = WorkerResult(cfg.worker)
    target = plugin.start(cfg)
    prog = Progress(started=start)
    stop_rule, stop_after = cfg.extra.get("stop_on_rule"), cfg.extra.get("stop_after")

    def stop() -> bool:
        if stop_event is not None and stop_event.is_set():
            res.interrupted = True
            return True
        return (stop_rule is not None and any(f.rule == stop_rule for f in store.order)) or (
            stop_after is not None and len(store) >= stop_after) or (stop_when is not None and stop_when())

    triage: Any = None
    try:
        for name, deadline, cap in engine_turns(cfg.engine, start, cfg.duration_limit, cfg.max_cases):
            if stop():
                break
            budget = None if cap is None else max(0, cap - res.cases)
            prog.engine = name if cfg.engine == name else f"{cfg.engine} ({name})"  # "both (stateful)"
            eng: Any = None
            triage = None
            try:
                triage = plugin.triage(target, store, name, cfg, start, triage)

                def on_tick(st: EngineStats, base_c: int = res.cases, base_s: float = res.fuzz_seconds,
                            base_t: dict[str, dict[str, int]] = res.tried) -> None:
                    prog.cases = base_c + st.cases
                    prog.fuzz_seconds = base_s + st.seconds
                    prog.findings = len(store)
                    prog.restarts = target.restarts
                    prog.classes = {}
                    for f in store.order:
                        count(prog.classes, f.source)
                    prog.tried = sum_tables([base_t, st.tried])
                    if tick is not None:
                        tick(prog)

                eng = plugin.engine(name, target, triage, cfg)
                eng.run(deadline, budget, on_tick, stop)
            finally:
                if eng is not None:
                    _record(res, name, eng.stats, triage)
                    plugin.record(res, name, eng)
    except TargetLost as exc:
        res.error, res.lost = str(exc), True
    except KeyboardInterrupt:
        res.interrupted = True
    finally:
        res.restarts = target.restarts
        res.restart_reasons = dict(target.restart_reasons)
        res.findings = len(store)
        target.close()
    return res


def _worker_process(plugin: Plugin, cfg: FuzzConfig, q: Any, stop_event: Any = None,
                    started: float | None = None) -> None:
    """A ``--jobs`` worker process: its result (and findings) go back on ``q``. SIGINT is the
    parent's to handle: it sets ``stop_event``, and the worker ends its round and reports.
    ``started``: the parent's start (the monotonic clock is the machine's), its deadlines'."""
    reporter = Reporter(q, cfg.worker)
    store = FindingStore(None)

    def tick(p: Progress) -> None:
        reporter.progress(lambda: report(p.cases, p.fuzz_seconds, p.restarts, list(store.order), tried=p.tried))

    try:
        res = run_worker(plugin, cfg, store, tick, stop_event, started)
    except SetupError as exc:
        res = WorkerResult(cfg.worker, error=str(exc))
    except Exception as exc:  # noqa: BLE001 - reported by the parent in one line
        res = WorkerResult(cfg.worker, error=f"worker {cfg.worker} failed: {type(exc).__name__}: {exc}")
    reporter.done(report(res.cases, res.fuzz_seconds, res.restarts, store.order, tried=res.tried,
                         result=asdict(res), findings=list(store.order)))


def run_campaign(plugin: Plugin, cfg: FuzzConfig, store: FindingStore, summary: Callable[..., dict[str, Any]],
                 tick: Callable[[Progress], None] | None = None,
                 stop_when: Callable[[], bool] | None = None) -> dict[str, Any]:
    """Run the campaign; its summary (``summary(cfg, store, results, elapsed, error, interrupted=,
    node_lost=)``, also written to ``--out``/summary.json). SIGINT ends it with the counts and
    findings so far and ``"interrupted": true`` (issue 19 item 6); a node lost in attach mode
    with ``"node_lost": true`` and the error naming it (item 1). ``stop_when``: as
    :func:`run_worker`'s (one worker)."""
    t0 = time.monotonic()
    results: list[WorkerResult] = []
    error: str | None = None
    interrupted = False
    try:
        if cfg.jobs <= 1:
            results.append(run_worker(plugin, cfg.for_worker(0), store, tick, started=t0, stop_when=stop_when))
        else:
            results, error, interrupted = _run_jobs(plugin, cfg, store, tick, t0)
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
        s = summary(cfg, store, results, time.monotonic() - t0, error, interrupted=interrupted, node_lost=bool(lost))
        if cfg.out is not None:
            store.rewrite()  # the occurrences counted since each was written
            write_summary(Path(cfg.out) / "summary.json", s)
    return s


def _run_jobs(plugin: Plugin, cfg: FuzzConfig, store: FindingStore, tick: Callable[[Progress], None] | None,
              t0: float) -> tuple[list[WorkerResult], str | None, bool]:
    jobs = run_jobs(_worker_process, lambda i, q, stop: (plugin, cfg.for_worker(i), q, stop, t0),
                    cfg.jobs, campaign_end(t0, cfg.duration_limit), store, tick,
                    Progress(started=t0, engine=cfg.engine), cfg.extra.get("stop_after"))
    results = {i: WorkerResult(**b["result"]) for i, b in jobs.done.items()}
    errors = [r.error for r in results.values() if r.error]
    missing = [i for i in range(cfg.jobs) if i not in results]
    if missing:
        errors.append(f"worker(s) {', '.join(map(str, missing))} gave no result")
        for i in missing:  # what its progress said, at least
            b = jobs.per.get(i, {})
            results[i] = WorkerResult(i, cases=b.get("cases", 0), fuzz_seconds=b.get("fuzz_s", 0.0),
                                      restarts=b.get("restarts", 0), interrupted=jobs.interrupted,
                                      tried=b.get("tried", {}), findings=len(b.get("found", [])),
                                      error="gave no result")
    if errors and not any(r.cases for r in results.values()) and not jobs.interrupted:
        raise SetupError(errors[0])
    return [results[i] for i in sorted(results)], ("; ".join(errors) or None), jobs.interrupted


def _sum_counts(counts: Iterable[dict[str, int]]) -> dict[str, int]:
    out: dict[str, int] = {}
    for c in counts:
        for k, n in c.items():
            count(out, k, n)
    return dict(sorted(out.items(), key=lambda kv: -kv[1]))


def common_summary(cfg: FuzzConfig, results: list[WorkerResult], elapsed: float, error: str | None,
                   interrupted: bool) -> dict[str, Any]:
    """The keys of ``summary.json`` every protocol's campaign writes: cases, judged cases/s
    (over the longest fuzzing time), restarts and why, where the time went (triage's share,
    ``--duration``'s grace), what was not a finding (unconfirmed, environment-dependent), how
    it ended. (Each protocol adds its own; ``elapsed``: the campaign's time.)"""
    cases = sum(r.cases for r in results)
    fuzz_s = max((r.fuzz_seconds for r in results), default=0.0)
    triage_s = max((r.triage_seconds for r in results), default=0.0)
    return {
        "engine": cfg.engine,
        "seed": cfg.seed,
        "jobs": cfg.jobs,
        "cases": cases,
        "cases_per_s": round(cases / elapsed, 1) if elapsed > 0 else 0.0,
        "judged_cases_per_s": round(cases / fuzz_s, 1) if fuzz_s > 0 else 0.0,
        "restarts": sum(r.restarts for r in results),
        "restarts_by_reason": _sum_counts(r.restart_reasons for r in results),
        "replays": sum(r.replays for r in results),
        "triage_s": round(triage_s, 3),
        "triage_share": round(triage_s / elapsed, 3) if elapsed > 0 else 0.0,
        "grace_s": GRACE_S,
        "environment_dependent": merge_environment(e for r in results for e in r.environment),
        "unconfirmed": sum(r.unconfirmed for r in results),
        "interrupted": interrupted,
        "error": error,
    }


class triage_time:  # noqa: N801 - used as a ``with`` statement, as contextlib's are
    """``with triage_time(triage, key):`` one triage, timed into ``triage.seconds`` (the
    target's restarts to go on fuzzing, ``triage.restart_seconds``, excluded), its start in
    ``triage.triage_from`` while it runs (``fuzz.budget.over_budget``); past the deadline or
    the budget (:class:`~fuzz.budget.Late`) it ends, counted as untriaged under ``key``."""

    def __init__(self, triage: Any, key: str) -> None:
        self.triage, self.key = triage, key

    def __enter__(self) -> None:
        self.t0, self.r0 = time.monotonic(), self.triage.restart_seconds
        self.triage.triage_from = self.t0

    def __exit__(self, kind: type[BaseException] | None, *_: object) -> bool:
        t = self.triage
        t.seconds += time.monotonic() - self.t0 - (t.restart_seconds - self.r0)
        t.triage_from = None
        if kind is not None and issubclass(kind, Late):
            count(t.untriaged, self.key)
            return True
        return False

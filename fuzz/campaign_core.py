"""The campaign every protocol of ``mcp-fuzz --protocol NAME`` runs (issue 37: the protocol a
plug-in; issue 39: a protocol's plumbing near zero), written once: a protocol's campaign
(MAVLink's ``fuzz.mavlink_campaign``, Nsqd's ``fuzz.nsqd_campaign``) is a
:class:`ProtocolCampaign` that declares only what is its own -- its profile, the options it
refuses, its parts of the one loop (``fuzz.loop.Plugin``: target, triage, engines), how a
finding's files are written, its own keys of ``summary.json`` and how a finding and its totals
read in the closing lines, and how ``--replay`` replays one of its findings.

What every such campaign does alike is here: the store of findings (``fuzz.findings``; its
``finding.json`` names the protocol and how the target ran, for ``--replay``), the campaign
over ``fuzz.loop.run_campaign`` (``--jobs N``: ``--max-cases`` shared out among the workers),
``summary.json``'s keys beside those ``fuzz.loop.common_summary`` writes for every protocol
(:meth:`ProtocolCampaign.summary`: where the time went, the cases by kind and message, the
findings by class, what was counted and not triaged, each worker's figures), and the closing
lines with the exit code (:meth:`ProtocolCampaign.final`: each finding, the
environment-dependent flaws, the hits counted and not triaged under ``-v``, the totals and
:func:`budget_line`), and ``--replay``'s one replay of a finding on a fresh target started as
the campaign's is (:meth:`ProtocolCampaign.replay`, over ``fuzz.replay_core``).
"""

from __future__ import annotations

import random
import sys
import time
from collections import deque
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, ClassVar

from mcp_conform.fuzz import loop
from mcp_conform.fuzz.budget import TRIAGE_SHARE
from mcp_conform.fuzz.config import FuzzConfig, exit_code
from mcp_conform.fuzz.environment import environment_lines
from mcp_conform.fuzz.findings import Finding, FindingStore
from mcp_conform.fuzz.loop import EngineStats, FuzzClock, WorkerResult, common_summary, count
from mcp_conform.fuzz.progress import Progress, interrupted
from mcp_conform.fuzz.replay_core import Replayed, replay_fresh
from mcp_conform.fuzz.triage_core import HitTriage
from mcp_conform.fuzz.workers import sum_tables
from mcp_conform.spec.profiles import Profile

__all__ = ["PROG", "CaseEngine", "ProtocolCampaign", "ProtocolPlugin", "budget_line", "exit_status"]

PROG = "mcp-fuzz"


@dataclass
class ProtocolPlugin:
    """A protocol's parts of the one campaign loop (``fuzz.loop.Plugin``): how its target
    starts and its engines are made are its own; its triage is its ``TRIAGE`` (a
    ``fuzz.triage_core.HitTriage``), made once a worker (:meth:`first`: what it does before
    the first case) and carried on from one engine's turn to the next (``HitTriage.carry``)."""

    TRIAGE: ClassVar[type[HitTriage]]
    n_of_n: int = 3  # a finding's confirming replays

    def triage(self, target: Any, store: FindingStore, name: str, cfg: FuzzConfig, started: float,
               prev: HitTriage | None) -> HitTriage:
        if prev is not None:
            return prev.carry()
        triage = self.TRIAGE(target=target, store=store, seed=cfg.seed, worker=cfg.worker,  # type: ignore[call-arg]
                             n_of_n=self.n_of_n, started=started, duration=cfg.duration_limit)
        self.first(triage, cfg)
        return triage

    def start(self, cfg: FuzzConfig) -> Any:
        """The worker's target (``fuzz.loop.WorkerTarget``), started as ``cfg`` says: ``--spawn``,
        ``--target``, else the protocol's reference node (a campaign's, and ``--replay``'s)."""
        raise NotImplementedError

    def first(self, triage: Any, cfg: FuzzConfig) -> None:
        """What a worker's triage does before its first case (nothing, unless the protocol says)."""

    def record(self, res: WorkerResult, name: str, engine: Any) -> None:
        """What else the worker's result keeps of an engine's turn (nothing, unless the protocol says)."""


class CaseEngine:
    """A protocol's stateless engine (``fuzz.loop.Engine``): cases drawn from the worker's
    seeded stream (:meth:`draw`), each sent and judged at once (:meth:`send`: the hit its
    oracles saw, or None), counted by kind and message (:meth:`tried`), until the budget is
    spent; a hit goes to triage (:meth:`triage_hit`), its time not fuzzing time. ``history``:
    how many of the cases sent it keeps, each with its time (``sent``: a hit's suspects,
    :meth:`taken`); ``target``: the worker's (``fuzz.loop.WorkerTarget``), whose ``current``
    runs each case (:meth:`send`), unless the protocol sends its own way."""

    def __init__(self, triage: Any, seed: int, worker: int = 0, history: int = 0, target: Any = None) -> None:
        self.triage, self.target = triage, target
        self.stats = EngineStats()
        self.rng = random.Random(seed if not worker else hash((seed, worker)))
        self.sent: deque[tuple[float, Any]] = deque(maxlen=history)

    def run(self, deadline: float, max_cases: int | None, tick: Callable[[EngineStats], None] | None,
            stop: Callable[[], bool]) -> EngineStats:
        st = self.stats
        clock = FuzzClock(st, tick)
        try:
            while not st.spent(deadline, max_cases, stop):
                case = self.draw()
                clock.case(*self.tried(case))
                if self.sent.maxlen:
                    self.sent.append((time.monotonic(), case))
                hit = self.send(case)
                if hit is not None:
                    with clock.triage():
                        self.triage_hit(hit)
        finally:
            clock.stop()
        return st

    def draw(self) -> Any:
        """The next case."""
        raise NotImplementedError

    def tried(self, case: Any) -> tuple[str, Iterable[str]]:
        """The case's kind and the messages it sends (``summary.json``'s ``tried``)."""
        raise NotImplementedError

    def send(self, case: Any) -> Any:
        """The case sent and judged: the hit its oracles saw, or None (the target's ``current.run``)."""
        return self.target.current.run(case)

    def taken(self, since: float | None = None, until: float | None = None, last: int | None = None) -> list[Any]:
        """The cases kept (``history``) sent from ``since`` to ``until`` (time.monotonic), or
        the ``last`` ones, oldest first; the kept ones then dropped (a hit's suspects)."""
        got = [c for t, c in self.sent if (since is None or since <= t) and (until is None or t <= until)]
        self.sent.clear()
        return got[-last:] if last else got

    def triage_hit(self, hit: Any) -> None:
        """The hit to the worker's triage, with its suspects."""
        raise NotImplementedError


class ProtocolCampaign:
    """A protocol's campaign (``fuzz.plugin.FuzzCampaign``, the profile's ``fuzz_campaign``):
    ``PROFILE`` names it; ``PLUGIN`` makes its part of the one loop (``plugin``: one made
    otherwise); ``WRITE_FILES`` writes a finding's own files beside ``finding.json``
    (``fuzz.findings.FindingStore``)."""

    PROFILE: ClassVar[Profile]
    #: the options of ``mcp-fuzz`` this campaign does not take (a one-line usage error)
    REFUSED: ClassVar[tuple[str, ...]] = ()
    PLUGIN: ClassVar[type[ProtocolPlugin]]
    WRITE_FILES: ClassVar[Callable[..., None] | None] = None

    def __init__(self, cfg: FuzzConfig, tick: Callable[[Progress], None] | None = None,
                 plugin: loop.Plugin | None = None) -> None:
        self.cfg, self.tick = cfg, tick
        self.plugin: Any = plugin if plugin is not None else self.PLUGIN()
        self.stop: Callable[[], bool] = lambda: False  # a caller's own reason to stop (one worker)
        how = ["--spawn", cfg.spawn] if cfg.spawn else (["--target", f"{cfg.target[0]}:{cfg.target[1]}"]
                                                         if cfg.target else [])
        self.store = FindingStore(cfg.out, ["--protocol", self.PROFILE.name, *how], type(self).WRITE_FILES)

    @classmethod
    def from_config(cls, cfg: FuzzConfig, tick: Callable[[Progress], None] | None) -> Any:
        return cls(cfg, tick)

    @property
    def findings(self) -> list[Finding]:
        return self.store.order

    def fuzz(self) -> dict[str, Any]:
        """The campaign (``--jobs N``: ``--max-cases`` shared out, N workers run as many in
        all); its summary, summary.json written under ``--out`` however it ends."""
        cfg = self.cfg
        if cfg.jobs > 1 and cfg.max_cases is not None:
            cfg.max_cases = max(1, cfg.max_cases // cfg.jobs)
        return loop.run_campaign(self.plugin, cfg, self.store, self.summary, self.tick, self.stop)

    def abort(self) -> None:
        """(``fuzz.loop.run_campaign`` writes summary.json however it ends.)"""

    # -- summary.json -------------------------------------------------------------------
    def summary(self, cfg: FuzzConfig, store: FindingStore, results: list[WorkerResult], elapsed: float,
                error: str | None, *, interrupted: bool = False, node_lost: bool = False) -> dict[str, Any]:
        """``summary.json``: the keys every protocol's has (``fuzz.loop.common_summary``), where
        the time went (fuzzing, restarts; ``--duration`` and triage's share of it), the kinds x
        messages sent (every case under its kind), the cases of each engine that had its turn
        (``both``'s stateless turn spent starting a starved backend: 0), the findings by class (their oracle), the hits counted and not triaged,
        each worker's figures under ``--jobs``; then the protocol's own (:meth:`own_summary`)."""
        by_class: dict[str, int] = {}
        for f in store.order:
            count(by_class, f.source)
        s = {"protocol": self.PROFILE.name, **common_summary(cfg, results, elapsed, error, interrupted),
             "elapsed_s": round(elapsed, 2), "fuzz_s": round(max((r.fuzz_seconds for r in results), default=0.0), 2),
             "restart_s": round(sum(r.restart_seconds for r in results), 2),
             "by_kind": sum_tables({"": r.by_mutator} for r in results).get("", {}),
             "tried": sum_tables(r.tried for r in results),
             "cases_by_engine": sum_tables({"": {n: e["cases"] for n, e in r.engines.items()}} for r in results).get("", {}),
             "findings_by_rule": store.by_rule(),
             "findings_by_class": by_class,
             "untriaged": sum_tables({"": r.untriaged} for r in results).get("", {}),
             "duration_s": cfg.duration_limit, "triage_share_max": TRIAGE_SHARE, "node_lost": node_lost,
             **self.own_summary(cfg, store, results)}
        if cfg.jobs > 1:
            s["workers"] = [{"worker": r.worker, "cases": r.cases, "fuzz_s": round(r.fuzz_seconds, 2),
                             "findings": r.findings, "error": r.error} for r in results]
        return s

    def own_summary(self, cfg: FuzzConfig, store: FindingStore, results: list[WorkerResult]) -> dict[str, Any]:
        """The protocol's own keys of ``summary.json`` (its findings listed, its target)."""
        return {}

    # -- the closing lines --------------------------------------------------------------
    def final(self, s: dict[str, Any], live: Any, strict: bool) -> int:
        """The closing lines of a campaign of summary ``s``: each finding (:meth:`finding_lines`),
        the environment-dependent flaws, the hits counted and not triaged (``-v``), the totals
        (:meth:`totals`) and where the time went (:func:`budget_line`); the exit code (2: no
        case ran, or the attached target was lost)."""
        errors = [w["error"] for w in s.get("workers", []) if w.get("error")]
        if errors and not s["cases"]:
            print(f"{PROG}: {budget_line(s)}")  # where it ended: at the bound, if the workers were cut there
            print(f"{PROG}: error: {errors[0]}", file=sys.stderr)
            return 2
        for i, f in enumerate(self.store.order, 1):
            for line in self.finding_lines(i, f, live.verbose):
                print(line)
        for line in environment_lines(s) if not live.quiet else ():
            print(line)
        if live.verbose:
            for shape, n in sorted(s.get("untriaged", {}).items(), key=lambda kv: -kv[1]):
                print(f"  counted, not triaged: {shape} ×{n}")
        found, target = self.totals(s)
        print(f"{PROG}: {s['cases']} cases in {s['elapsed_s']} s ({s['judged_cases_per_s']} judged cases/s), "
              f"{len(self.store)} finding(s) ({found or 'none'}), {s['unconfirmed']} unconfirmed; {target}, "
              f"seed {s['seed']}")
        print(f"{PROG}: {budget_line(s)}")
        return exit_status(s, self.store, strict)

    def finding_lines(self, i: int, f: Finding, verbose: bool) -> list[str]:
        """Finding ``i``'s closing line (and, ``verbose``, what it expected)."""
        return [f"finding-{i}: {f.rule} ({f.level}) {f.shape} x{f.occurrences}, replays {f.replays}: {f.actual}"]

    def totals(self, s: dict[str, Any]) -> tuple[str, str]:
        """The totals line's findings (by rule) and what was fuzzed."""
        return ", ".join(f"{r} {n}" for r, n in s["findings_by_rule"].items()), f"engine {s['engine']}"

    # -- --replay -----------------------------------------------------------------------
    @classmethod
    def replay(cls, path: str, cfg: FuzzConfig, prog: str = PROG) -> int:
        """``--replay finding-N`` (``fuzz.replay_core.replay_fresh``): what the finding holds to
        replay (:meth:`replay_inputs`), unless the protocol declines it (:meth:`declined`: its
        line and exit code), replayed once (:meth:`replay_on`) on a fresh target started as the
        campaign's (``PLUGIN().start``), closed after; 1 it reproduced, 0 not, 2 unreadable."""
        return replay_fresh(path, cls.PROFILE.name, cls.replay_inputs, lambda: cls.PLUGIN().start(cfg), cls.replay_on,
                            cls.declined, prog)

    @staticmethod
    def replay_inputs(f: Finding) -> Any:
        """What finding ``f`` holds to replay (ValueError, KeyError, TypeError: unreadable)."""
        raise NotImplementedError

    @staticmethod
    def declined(f: Finding, inputs: Any, prog: str) -> int | None:
        """A finding the protocol's replay cannot show: its line said, its exit code (None: replay it)."""
        return None

    @staticmethod
    def replay_on(target: Any, f: Finding, inputs: Any) -> Replayed:
        """``inputs`` replayed on ``target`` (the worker's, ``PLUGIN().start``): what it showed."""
        raise NotImplementedError


def exit_status(s: dict[str, Any], store: FindingStore, strict: bool) -> int:
    """A campaign's exit code, after its closing lines (every protocol's): SIGINT's
    (``fuzz.progress.interrupted``: its line), 2 when the attached target was lost (its error
    said), else by its findings (``fuzz.config.exit_code``, ``--strict``)."""
    if s.get("interrupted"):
        return interrupted(s["cases"], len(store), store.out)
    if s.get("node_lost"):
        print(f"{PROG}: error: {s['error']}", file=sys.stderr)
        return 2
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

"""``mcp-fuzz --protocol nsqd``: a campaign against a TCP backend until it breaks (issue 21),
run by the one campaign loop (``fuzz.loop``, issue 37) with Nsqd's parts: its target
(``fuzz.nsqd_triage.StreamTarget``, a backend spawned or attached), its engines (the
stateless one, ``fuzz.nsqd_engine``; the stateful one, ``fuzz.nsqd_programs``), its triage
(``fuzz.nsqd_triage``; before the first case, worker 0 counts the backend's descriptors over
connect/close cycles: ``fuzz.nsqd_blame.leak_check``), its summary and closing lines
(``fuzz.nsqd_report``). ``mcp-fuzz --protocol nsqd --replay finding-N`` reproduces a finding
(exit 1) or not (exit 0): ``fuzz.nsqd_replay``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from mcp_conform.fuzz import loop, nsqd_report
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import Finding, FindingStore
from mcp_conform.fuzz.nsqd_backend import Backend, message_names
from mcp_conform.fuzz.nsqd_replay import replay_stream_finding
from mcp_conform.fuzz.nsqd_repro import write_finding_files
from mcp_conform.fuzz.nsqd_triage import StreamTarget, StreamTriage, nsqd_finding
from mcp_conform.fuzz.progress import Progress
from mcp_conform.spec.profiles import NSQD_PROFILE

__all__ = ["Backend", "NsqdPlugin", "StreamCampaign", "message_names", "nsqd_finding", "replay_stream_finding"]


@dataclass
class NsqdPlugin:
    """Nsqd's parts of the one campaign loop (``fuzz.loop.Plugin``)."""

    n_of_n: int = 3  # a finding's confirming replays
    probe_every: int = 40  # cases between two probe commands

    def start(self, cfg: FuzzConfig) -> StreamTarget:
        return StreamTarget(Backend(cfg.target, cfg.spawn), attached=cfg.target is not None and cfg.spawn is None)

    def triage(self, target: StreamTarget, store: FindingStore, name: str, cfg: FuzzConfig, started: float,
               prev: StreamTriage | None) -> StreamTriage:
        if prev is not None:
            return prev.carry()
        triage = StreamTriage(target, store, seed=cfg.seed, worker=cfg.worker, n_of_n=self.n_of_n, started=started,
                              duration=cfg.duration_limit)
        if cfg.worker == 0:
            from mcp_conform.fuzz.nsqd_blame import leak_check

            target.current = leak_check(triage, target.current)
        return triage

    def engine(self, name: str, target: StreamTarget, triage: StreamTriage, cfg: FuzzConfig) -> Any:
        if name == "stateful":
            from mcp_conform.fuzz.nsqd_programs import StreamStatefulEngine

            return StreamStatefulEngine(triage, cfg.db, cfg.worker)
        from mcp_conform.fuzz.nsqd_engine import StreamStatelessEngine

        return StreamStatelessEngine(triage, cfg.seed, cfg.worker, self.probe_every)

    def record(self, res: loop.WorkerResult, name: str, engine: Any) -> None:
        """(Nothing of Nsqd's own: its engines' and triage's counts are the loop's.)"""


class StreamCampaign:
    """An Nsqd campaign (``mcp-fuzz --protocol nsqd``: the profile's ``fuzz_campaign``,
    ``fuzz.plugin.FuzzCampaign``): ``fuzz.loop``'s over :class:`NsqdPlugin`, its findings in
    one store written under ``out``."""

    REFUSED: ClassVar[tuple[str, ...]] = ("--mavlink", "--seeds", "--live")

    def __init__(self, target: tuple[str, int] | None, spawn: str | None, seed: int, duration: float | None,
                 max_cases: int | None, out: Path | None, replays: int = 3, probe_every: int = 40,
                 stop_after: int | None = None, engine: str = "stateless", db: str | None = None,
                 tick: Callable[[Progress], None] | None = None, jobs: int = 1) -> None:
        self.out, self.replays, self.tick = (Path(out) if out is not None else None), replays, tick
        self.cfg = FuzzConfig(target=target, spawn=spawn, seed=seed, duration=duration, max_cases=max_cases,
                              engine=engine, db=db, jobs=jobs, out=str(out) if out is not None else None,
                              protocol=NSQD_PROFILE.name, role=NSQD_PROFILE.roles[0].name)
        if stop_after is not None:  # end the campaign once this many findings are confirmed
            self.cfg.extra["stop_after"] = stop_after
        self.plugin = NsqdPlugin(replays, probe_every)
        self.stop: Callable[[], bool] = lambda: False  # a caller's own reason to stop (one worker)
        self.cases, self.fuzz_s = 0, 0.0  # the last run's (its summary's)
        how = ["--spawn", spawn] if spawn else (["--target", f"{target[0]}:{target[1]}"] if target else [])
        self.store = FindingStore(self.out, ["--protocol", NSQD_PROFILE.name, *how], write_finding_files)

    @property
    def findings(self) -> list[Finding]:
        return self.store.order

    def run(self) -> dict[str, Any]:
        """The campaign (``--jobs`` as configured); its summary, summary.json written under ``out``."""
        s = loop.run_campaign(self.plugin, self.cfg, self.store, nsqd_report.summary, self.tick, self.stop)
        self.cases, self.fuzz_s = s["cases"], s["fuzz_s"]
        return s

    def run_jobs(self, jobs: int, tick: Callable[[Progress], None] | None = None) -> dict[str, Any]:
        """``--jobs N``: N workers, each a campaign of its own backend and seed stream,
        ``--max-cases`` shared out, ``--duration`` from this start; the summary."""
        self.cfg.jobs, self.tick = jobs, tick or self.tick
        if self.cfg.max_cases is not None and jobs > 1:  # the budget shared: N workers run max_cases in all
            self.cfg.max_cases = max(1, self.cfg.max_cases // jobs)
        return self.run()

    # -- mcp-fuzz's campaign of the protocol (fuzz.plugin.FuzzCampaign) ----------------
    @classmethod
    def from_config(cls, cfg: FuzzConfig, tick: Callable[[Progress], None] | None) -> StreamCampaign:
        return cls(cfg.target, cfg.spawn, cfg.seed, cfg.duration_limit, cfg.max_cases,
                   Path(cfg.out) if cfg.out else None, engine=cfg.engine, db=cfg.db, tick=tick, jobs=cfg.jobs)

    def fuzz(self) -> dict[str, Any]:
        return self.run_jobs(self.cfg.jobs) if self.cfg.jobs > 1 else self.run()

    def abort(self) -> None:
        """(``fuzz.loop.run_campaign`` writes summary.json however it ends.)"""

    def final(self, summary: dict[str, Any], live: Any, strict: bool) -> int:
        return nsqd_report.final(self.store, summary, live, strict)

    @staticmethod
    def replay(path: str, cfg: FuzzConfig) -> int:
        return replay_stream_finding(path, cfg.target, cfg.spawn)

"""``mcp-fuzz --protocol nsqd``: a campaign against a TCP backend until it breaks (issue 21),
run by the one campaign loop (``fuzz.loop``, issue 37) with Nsqd's parts: its target
(``fuzz.nsqd_backend.BackendTarget``, a backend spawned or attached), its engines (the
stateless one, ``fuzz.nsqd_engine``; the stateful one, ``fuzz.nsqd_programs``), its triage
(``fuzz.nsqd_triage``; before the first case, worker 0 counts the backend's descriptors over
connect/close cycles: ``fuzz.nsqd_blame.leak_check``), its summary and closing lines
(``fuzz.campaign_core``). ``mcp-fuzz --protocol nsqd --replay finding-N`` reproduces a finding
(exit 1) or not (exit 0): ``fuzz.campaign_core``'s replay over ``fuzz.nsqd_replay``'s parts.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from mcp_conform.fuzz import loop
from mcp_conform.fuzz.campaign_core import ProtocolCampaign, ProtocolPlugin
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import Finding, FindingStore
from mcp_conform.fuzz.nsqd_backend import Backend, BackendTarget, message_names
from mcp_conform.fuzz.nsqd_replay import declined, read, replay_on, replay_stream_finding
from mcp_conform.fuzz.nsqd_repro import write_finding_files
from mcp_conform.fuzz.nsqd_triage import StreamTarget, StreamTriage, nsqd_finding
from mcp_conform.fuzz.progress import Progress
from mcp_conform.spec.profiles import NSQD_PROFILE

__all__ = ["Backend", "NsqdPlugin", "StreamCampaign", "message_names", "nsqd_finding", "replay_stream_finding"]


@dataclass
class NsqdPlugin(ProtocolPlugin):
    """Nsqd's parts of the one campaign loop (``fuzz.campaign_core.ProtocolPlugin``); before
    the first case, worker 0 counts the backend's descriptors (``fuzz.nsqd_blame.leak_check``)."""

    TRIAGE = StreamTriage
    probe_every: int = 40  # cases between two probe commands

    def start(self, cfg: FuzzConfig) -> BackendTarget:
        return Backend(cfg.target, cfg.spawn).pool

    def first(self, triage: StreamTriage, cfg: FuzzConfig) -> None:
        if cfg.worker == 0:
            from mcp_conform.fuzz.nsqd_blame import leak_check

            triage.target.current = leak_check(triage, triage.target.current)

    def engine(self, name: str, target: StreamTarget, triage: StreamTriage, cfg: FuzzConfig) -> Any:
        if name == "stateful":
            from mcp_conform.fuzz.nsqd_programs import StreamStatefulEngine

            return StreamStatefulEngine(triage, cfg.db, cfg.worker)
        from mcp_conform.fuzz.nsqd_engine import StreamStatelessEngine

        return StreamStatelessEngine(triage, cfg.seed, cfg.worker, self.probe_every)


class StreamCampaign(ProtocolCampaign):
    """An Nsqd campaign (``mcp-fuzz --protocol nsqd``: the profile's ``fuzz_campaign``):
    ``fuzz.campaign_core``'s over :class:`NsqdPlugin`, its findings' files written by
    ``fuzz.nsqd_repro``; ``stop_after``: the campaign ends once this many are confirmed."""

    PROFILE, PLUGIN, WRITE_FILES = NSQD_PROFILE, NsqdPlugin, write_finding_files
    replay_inputs, declined, replay_on = staticmethod(read), staticmethod(declined), staticmethod(replay_on)
    REFUSED: ClassVar[tuple[str, ...]] = ("--mavlink", "--seeds", "--live")

    def __init__(self, target: tuple[str, int] | None, spawn: str | None, seed: int, duration: float | None,
                 max_cases: int | None, out: Path | None, replays: int = 3, probe_every: int = 40,
                 stop_after: int | None = None, engine: str = "stateless", db: str | None = None,
                 tick: Callable[[Progress], None] | None = None, jobs: int = 1) -> None:
        cfg = FuzzConfig(target=target, spawn=spawn, seed=seed, duration=duration, max_cases=max_cases,
                         engine=engine, db=db, jobs=jobs, out=str(out) if out is not None else None,
                         protocol=NSQD_PROFILE.name, role=NSQD_PROFILE.roles[0].name)
        if stop_after is not None:
            cfg.extra["stop_after"] = stop_after
        super().__init__(cfg, tick, NsqdPlugin(replays, probe_every))
        self.out, self.replays = (Path(out) if out is not None else None), replays
        self.cases, self.fuzz_s = 0, 0.0  # the last run's (its summary's)

    @classmethod
    def from_config(cls, cfg: FuzzConfig, tick: Callable[[Progress], None] | None) -> StreamCampaign:
        return cls(cfg.target, cfg.spawn, cfg.seed, cfg.duration_limit, cfg.max_cases,
                   Path(cfg.out) if cfg.out else None, engine=cfg.engine, db=cfg.db, tick=tick, jobs=cfg.jobs)

    def fuzz(self) -> dict[str, Any]:
        s = super().fuzz()
        self.cases, self.fuzz_s = s["cases"], s["fuzz_s"]
        return s

    run = fuzz

    def run_jobs(self, jobs: int, tick: Callable[[Progress], None] | None = None) -> dict[str, Any]:
        """``--jobs N``: N workers, each a campaign of its own backend and seed stream."""
        self.cfg.jobs, self.tick = jobs, tick or self.tick
        return self.fuzz()

    def own_summary(self, cfg: FuzzConfig, store: FindingStore, results: list[loop.WorkerResult]) -> dict[str, Any]:
        """Each finding (its signature), the stateful engine's database."""
        return {"findings": [{"signature": f.signature.describe(), "oracle": f.signature.oracle,
                              "rule": f.signature.rule, "count": f.occurrences, "replays": f.replays,
                              "no_input": f.no_input, "engine": "stateful" if f.program is not None else "stateless"}
                             for f in store.order], "db": cfg.db}

    def finding_lines(self, i: int, f: Finding, verbose: bool) -> list[str]:
        return [f"finding-{i}: {f.signature.describe()} ×{f.occurrences}, replays {f.replays}: {f.note}",
                *([f"  {f.actual}"] if verbose else [])]

    def totals(self, s: dict[str, Any]) -> tuple[str, str]:
        return (", ".join(f"{k} {n}" for k, n in sorted(s["findings_by_class"].items())),
                f"engine {s['engine']}, {s['jobs']} job(s)")

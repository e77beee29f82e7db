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

from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcp_conform.fuzz import loop
from mcp_conform.fuzz.campaign_core import exit_status
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import FindingStore
from mcp_conform.fuzz.loop import WorkerResult
from mcp_conform.fuzz.progress import Progress
from mcp_conform.fuzz.targets import start_target
from mcp_conform.fuzz.triage import Triage
from mcp_conform.harness.errors import SetupError
from mcp_conform.spec import SPEC

__all__ = ["DatagramCampaign", "McpPlugin", "Progress", "WorkerResult", "load_seeds", "run_campaign", "run_worker"]


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


@dataclass
class McpPlugin:
    """MCP's parts of the one campaign loop (``fuzz.loop``): the role's target
    (``fuzz.targets``), a triage per engine (``fuzz.triage``: the worker's baseline carried
    on), the stateless and stateful engines, and what a worker records of them (the
    monitor, the node's measured period)."""

    seeds: list[bytes] = field(default_factory=list)  # --seeds: the stateless engine's

    def start(self, cfg: FuzzConfig) -> Any:
        return start_target(cfg)

    def triage(self, target: Any, store: FindingStore, name: str, cfg: FuzzConfig, started: float,
               prev: Any) -> Triage:
        triage = Triage(target, store, name, cfg.seed, cfg.worker)
        triage.started, triage.duration = started, cfg.duration_limit  # --duration bounds triage too (GRACE_S)
        if prev is not None:  # the baseline is the worker's, whatever the engine
            triage.baseline_rules = prev.baseline_rules
        return triage

    def engine(self, name: str, target: Any, triage: Any, cfg: FuzzConfig) -> Any:
        if name == "stateless":
            from mcp_conform.fuzz.engine_stateless import StatelessEngine

            return StatelessEngine(target, triage, cfg.seed, worker=cfg.worker, seeds=self.seeds)
        from mcp_conform.fuzz.drone_target import FuzzTarget
        from mcp_conform.fuzz.engine_stateful import StatefulEngine

        assert isinstance(target, FuzzTarget)  # a drone (the CLI refuses a manager)
        return StatefulEngine(target, triage, cfg)

    def record(self, res: WorkerResult, name: str, engine: Any) -> None:
        """The monitor's availability, the node's retransmission period measured at start and
        what the campaign did when it disagreed with --rto (``res.extra``)."""
        target = engine.target
        monitor = engine.monitor.available if name == "stateless" else engine.monitor_available
        res.extra.update(node_period=target.node_period, timing=target.timing,
                         monitor=res.extra.get("monitor", False) or monitor)


def run_worker(cfg: FuzzConfig, store: FindingStore, tick: Callable[[Progress], None] | None = None,
               seeds: list[bytes] | None = None, stop_event: Any = None,
               started: float | None = None) -> WorkerResult:
    """One MCP worker (``fuzz.loop.run_worker``)."""
    return loop.run_worker(McpPlugin(seeds or []), cfg, store, tick, stop_event, started)


def run_campaign(cfg: FuzzConfig, store: FindingStore,
                 tick: Callable[[Progress], None] | None = None) -> dict[str, Any]:
    """An MCP campaign (``fuzz.loop.run_campaign``); its summary (:func:`make_summary`), also
    written to ``--out``/summary.json, however it ends."""
    return loop.run_campaign(McpPlugin(load_seeds(cfg.seeds_dir)), cfg, store, make_summary, tick)


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
        return exit_status(summary, self.store, strict)

    @staticmethod
    def replay(path: str, cfg: FuzzConfig) -> int:
        from mcp_conform.fuzz.replay_cli import replay_finding

        return replay_finding(path, cfg)


def make_summary(cfg: FuzzConfig, store: FindingStore, results: list[WorkerResult],
                 duration: float, error: str | None, *, interrupted: bool = False,
                 node_lost: bool = False) -> dict[str, Any]:
    """``summary.json``: cases, judged cases/s, findings by rule, seed, duration; whether
    SIGINT ended it (``interrupted``) or the node was lost in attach mode (``node_lost``)."""
    from mcp_conform.spec.about import tool_version

    common = loop.common_summary(cfg, results, duration, error, interrupted)
    return {
        "schema_version": 1,
        "tool": {"name": "mcp-fuzz", "version": tool_version()},
        "spec": {"version": SPEC.version},
        "target": {**cfg.target_summary(), "mavlink": cfg.mavlink},
        **common,
        "duration_s": round(duration, 3),
        "findings": len(store),
        "findings_by_rule": store.by_rule(),
        "duration_limit_s": cfg.duration_limit,
        "untriaged": sum(n for r in results for n in r.untriaged.values()),
        "monitor": any(r.extra.get("monitor") for r in results),
        "node_period_s": next((round(r.extra["node_period"], 4) for r in results
                               if r.extra.get("node_period") is not None), None),
        "timing": next((r.extra["timing"] for r in results if r.extra.get("timing")), None),
        "workers": [{"worker": r.worker, "cases": r.cases, "engines": r.engines, "error": r.error,
                     "interrupted": r.interrupted} for r in results],
        "node_lost": node_lost,
    }

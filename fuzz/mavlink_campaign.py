"""``mcp-fuzz --protocol mavlink``: a campaign against a MAVLink vehicle (issue 39 item 4), run
by the one campaign loop (``fuzz.loop``) with MAVLink's parts: its target (the vehicle,
``fuzz.mavlink_vehicle``: spawned, ``--spawn CMD`` with ``{target_host}`` ``{target_port}``
``{mavlink}``, the reference vehicle by default, or attached at ``--target tcp:HOST:PORT``),
its engine (:class:`MavlinkEngine`: the cases of ``fuzz.mavlink_cases``, each judged by the
probe behind it and the oracles of ``fuzz.mavlink_vehicle``), its triage
(``fuzz.mavlink_triage``: replays on a fresh vehicle, ddmin, N of N), its summary and closing
lines. ``mcp-fuzz --protocol mavlink --replay finding-N`` replays a finding's cases on a
fresh vehicle: exit 1 when it shows again, 0 when not (a stopped heartbeat after a case that
asked for it, ``fuzz.mavlink_cases.asks_heartbeat_stop``: 0, not replayed).
"""

from __future__ import annotations

import random
import sys
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

from mcp_conform.fuzz import loop
from mcp_conform.fuzz.budget import TRIAGE_SHARE
from mcp_conform.fuzz.config import FuzzConfig, exit_code
from mcp_conform.fuzz.environment import environment_lines
from mcp_conform.fuzz.findings import FindingStore, load_finding
from mcp_conform.fuzz.loop import (
    EngineStats,
    FuzzClock,
    WorkerResult,
    common_summary,
    count,
)
from mcp_conform.fuzz.mavlink_cases import (
    Case,
    CaseMaker,
    Vehicle,
    asks_heartbeat_stop,
    case_from_json,
)
from mcp_conform.fuzz.mavlink_triage import MavTriage, replay_cases, write_repro
from mcp_conform.fuzz.mavlink_vehicle import BEAT_S, MavTarget, Signature, VehicleSpec
from mcp_conform.fuzz.progress import Progress, interrupted
from mcp_conform.fuzz.workers import sum_tables
from mcp_conform.spec.profiles import MAVLINK_PROFILE

__all__ = ["MavlinkCampaign", "MavlinkEngine", "MavlinkPlugin", "summary"]

PROG = "mcp-fuzz"
WINDOW = 16  # the cases before a hit that are its suspects (a stopped heartbeat: those since its last beat)


class MavlinkEngine:
    """Cases on the worker's vehicle until the budget is spent; a hit goes to triage."""

    def __init__(self, target: MavTarget, triage: MavTriage, seed: int, worker: int = 0) -> None:
        self.target, self.triage = target, triage
        self.stats = EngineStats()
        self.rng = random.Random(seed if not worker else hash((seed, worker)))
        self.maker = CaseMaker(self.rng, target.info)

    def run(self, deadline: float, max_cases: int | None, tick: Callable[[EngineStats], None] | None,
            stop: Callable[[], bool]) -> EngineStats:
        st = self.stats
        sent: deque[tuple[float, Case]] = deque(maxlen=5000)
        clock = FuzzClock(st, tick)
        vehicle = self.target.current
        try:
            while not st.spent(deadline, max_cases, stop):
                case = self.maker.draw()
                clock.case(case.kind, case.messages or ("-",))
                sent.append((time.monotonic(), case))
                hit = vehicle.run(case)
                if hit is None:
                    continue
                with clock.triage():
                    if hit.signature.oracle == "hang":  # the cases about its last beat, before the first it missed
                        since, until = vehicle.last_beat - BEAT_S, vehicle.last_beat + 1.5 * BEAT_S
                        suspects = [c for t, c in sent if since <= t <= until]
                    else:
                        suspects = [c for _, c in list(sent)[-WINDOW:]]
                    vehicle = self.triage.consider(hit, suspects)
                    sent.clear()
        finally:
            clock.stop()
        return st


@dataclass
class MavlinkPlugin:
    """MAVLink's parts of the one campaign loop (``fuzz.loop.Plugin``)."""

    n_of_n: int = 3  # a finding's confirming replays

    def start(self, cfg: FuzzConfig) -> MavTarget:
        return MavTarget(VehicleSpec.of(cfg.target, cfg.spawn))

    def triage(self, target: MavTarget, store: FindingStore, name: str, cfg: FuzzConfig, started: float,
               prev: MavTriage | None) -> MavTriage:
        return MavTriage(target=target, store=store, seed=cfg.seed, worker=cfg.worker, n_of_n=self.n_of_n,
                         started=started, duration=cfg.duration_limit, tries=prev.tries if prev else {},
                         quiet_hangs=prev.quiet_hangs if prev else None)

    def engine(self, name: str, target: MavTarget, triage: MavTriage, cfg: FuzzConfig) -> MavlinkEngine:
        return MavlinkEngine(target, triage, cfg.seed, cfg.worker)

    def record(self, res: WorkerResult, name: str, engine: Any) -> None:
        """The vehicle's IDs and the probe's parameter (``res.extra``)."""
        info = engine.target.info
        res.extra.update(vehicle=f"{info.sysid}/{info.compid}", parameters=len(info.params),
                         probe=info.probe.decode(errors="replace"))


def summary(cfg: FuzzConfig, store: FindingStore, results: list[WorkerResult], elapsed: float, error: str | None,
            *, interrupted: bool = False, node_lost: bool = False) -> dict[str, Any]:
    """``summary.json`` of a MAVLink campaign: the keys every protocol's has
    (``fuzz.loop.common_summary``), then its findings by rule and by oracle, each finding, the
    kinds x messages sent, where the time went, the vehicle's IDs and the probe's parameter."""
    by_oracle: dict[str, int] = {}
    for f in store.order:
        count(by_oracle, f.source)
    extra = next((r.extra for r in results if r.extra), {})
    s = {"protocol": MAVLINK_PROFILE.name, **common_summary(cfg, results, elapsed, error, interrupted),
         "elapsed_s": round(elapsed, 2), "fuzz_s": round(max((r.fuzz_seconds for r in results), default=0.0), 2),
         "restart_s": round(sum(r.restart_seconds for r in results), 2),
         "target": {"mode": cfg.mode, "spawn": cfg.spawn,
                    "target": f"{cfg.target[0]}:{cfg.target[1]}" if cfg.target else None, **extra},
         "by_kind": sum_tables({"": r.by_mutator} for r in results).get("", {}),
         "tried": sum_tables(r.tried for r in results), "findings": len(store), "findings_by_rule": store.by_rule(),
         "findings_by_class": by_oracle,
         "finding_list": [{"rule": f.rule, "level": f.level, "shape": f.shape, "count": f.occurrences,
                           "replays": f.replays, "cases": len(f.cases)} for f in store.order],
         "untriaged": sum_tables({"": r.untriaged} for r in results).get("", {}),
         "duration_s": cfg.duration_limit, "triage_share_max": TRIAGE_SHARE, "node_lost": node_lost}
    if cfg.jobs > 1:
        s["workers"] = [{"worker": r.worker, "cases": r.cases, "fuzz_s": round(r.fuzz_seconds, 2),
                         "findings": r.findings, "error": r.error} for r in results]
    return s


class MavlinkCampaign:
    """A MAVLink campaign (the profile's ``fuzz_campaign``, ``fuzz.plugin.FuzzCampaign``)."""

    REFUSED: ClassVar[tuple[str, ...]] = ("--mavlink", "--seeds", "--live", "--listen", "--target-id", "--db",
                                          "--rto", "--ack-window", "--broadcast-id")

    def __init__(self, cfg: FuzzConfig, tick: Callable[[Progress], None] | None = None) -> None:
        self.cfg, self.tick = cfg, tick
        how = ["--spawn", cfg.spawn] if cfg.spawn else (["--target", f"{cfg.target[0]}:{cfg.target[1]}"]
                                                         if cfg.target else [])
        self.store = FindingStore(cfg.out, ["--protocol", MAVLINK_PROFILE.name, *how], write_repro)
        self.plugin = MavlinkPlugin()

    @classmethod
    def from_config(cls, cfg: FuzzConfig, tick: Callable[[Progress], None] | None) -> MavlinkCampaign:
        return cls(cfg, tick)

    def fuzz(self) -> dict[str, Any]:
        cfg = self.cfg
        if cfg.jobs > 1 and cfg.max_cases is not None:  # the budget shared out
            cfg.max_cases = max(1, cfg.max_cases // cfg.jobs)
        return loop.run_campaign(self.plugin, cfg, self.store, summary, self.tick)

    def abort(self) -> None:
        """(``fuzz.loop.run_campaign`` writes summary.json however it ends.)"""

    def final(self, s: dict[str, Any], live: Any, strict: bool) -> int:
        from mcp_conform.fuzz.nsqd_report import budget_line

        errors = [w["error"] for w in s.get("workers", []) if w.get("error")]
        if errors and not s["cases"]:
            print(f"{PROG}: error: {errors[0]}", file=sys.stderr)
            return 2
        for i, f in enumerate(self.store.order, 1):
            print(f"finding-{i}: {f.rule} ({f.level}) {f.shape} x{f.occurrences}, replays {f.replays}: {f.actual}")
            if live.verbose:
                print(f"  expected: {f.expected}\n  {f.note}")
        for line in environment_lines(s) if not live.quiet else ():
            print(line)
        rules = ", ".join(f"{r} {n}" for r, n in s["findings_by_rule"].items()) or "none"
        print(f"{PROG}: {s['cases']} cases in {s['elapsed_s']} s ({s['judged_cases_per_s']} judged cases/s), "
              f"{s['findings']} finding(s) ({rules}), {s['unconfirmed']} unconfirmed; vehicle "
              f"{s['target'].get('vehicle', '?')}, probe {s['target'].get('probe', '?')}, seed {s['seed']}")
        print(f"{PROG}: {budget_line(s)}")
        if s.get("interrupted"):
            return interrupted(s["cases"], len(self.store), self.store.out)
        if s.get("node_lost"):
            print(f"{PROG}: error: {s['error']}", file=sys.stderr)
            return 2
        return exit_code(self.store.order, strict=strict)

    @staticmethod
    def replay(path: str, cfg: FuzzConfig) -> int:
        """``--replay finding-N``: its cases on a fresh vehicle (``--spawn``/``--target``, else
        the reference vehicle); 1 when its signature shows again, 0 when not, 2 unreadable."""
        try:
            f = load_finding(path, MAVLINK_PROFILE.name)
            cases = [case_from_json(c) for c in f.doc.get("cases", [])]
            probe = bytes.fromhex(str(f.doc.get("probe_hex", "")))
        except ValueError as exc:
            print(f"{PROG}: error: {exc}", file=sys.stderr)
            return 2
        asked = next((i for i, c in enumerate(cases, 1) if asks_heartbeat_stop(c)), None)
        if f.doc.get("oracle") == "hang" and asked is not None:
            print(f"{PROG}: finding {f.rule} ({f.shape}) is no finding: its case {asked} asks the vehicle to "
                  "stop its HEARTBEAT (MAV_CMD_SET_MESSAGE_INTERVAL), which it may do; not replayed")
            return 0
        target = MavTarget(VehicleSpec.of(cfg.target, cfg.spawn))
        try:
            info = target.info
            if probe and probe in info.params:
                target.info = Vehicle(info.sysid, info.compid, info.params, probe)
            sig = Signature(str(f.doc.get("oracle", "answer")), f.rule, str(f.doc.get("kind", "")))
            h = replay_cases(target.fresh, cases, sig)
        finally:
            target.close()
        shown = h is not None
        print(f"{PROG}: finding {f.rule} ({f.shape}) {'reproduced' if shown else 'not reproduced'}"
              + (f": {h.actual}" if h is not None else ""))
        return 1 if shown else 0


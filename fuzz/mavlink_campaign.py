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

from dataclasses import dataclass, replace
from typing import Any, ClassVar

from mcp_conform.fuzz.campaign_core import CaseEngine, ProtocolCampaign, ProtocolPlugin
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import Finding, FindingStore
from mcp_conform.fuzz.loop import WorkerResult
from mcp_conform.fuzz.mavlink_cases import (
    Case,
    CaseMaker,
    asks_heartbeat_stop,
    case_from_json,
)
from mcp_conform.fuzz.mavlink_triage import MavTriage, replay_cases, write_repro
from mcp_conform.fuzz.mavlink_vehicle import BEAT_S, Hit, MavTarget, Signature, vehicle_spec
from mcp_conform.fuzz.replay_core import Replayed
from mcp_conform.spec.profiles import MAVLINK_PROFILE

__all__ = ["MavlinkCampaign", "MavlinkEngine", "MavlinkPlugin"]

WINDOW = 16  # the cases before a hit that are its suspects (a stopped heartbeat: those since its last beat)


class MavlinkEngine(CaseEngine):
    """Cases on the worker's vehicle until the budget is spent (``fuzz.campaign_core``)."""

    triage: MavTriage

    def __init__(self, target: MavTarget, triage: MavTriage, seed: int, worker: int = 0) -> None:
        super().__init__(triage, seed, worker, history=5000, target=target)
        self.maker = CaseMaker(self.rng, target.info)

    def draw(self) -> Case:
        return self.maker.draw()

    def tried(self, case: Case) -> tuple[str, tuple[str, ...]]:
        return case.kind, case.messages or ("-",)

    def triage_hit(self, hit: Hit) -> None:
        beat = self.target.current.last_beat  # a hang: the cases about its last beat, before the first it missed
        self.triage.consider(hit, self.taken(beat - BEAT_S, beat + 1.5 * BEAT_S) if hit.signature.oracle == "hang"
                             else self.taken(last=WINDOW))


@dataclass
class MavlinkPlugin(ProtocolPlugin):
    """MAVLink's parts of the one campaign loop (``fuzz.campaign_core.ProtocolPlugin``)."""

    TRIAGE = MavTriage

    def start(self, cfg: FuzzConfig) -> MavTarget:
        return MavTarget(vehicle_spec(cfg.target, cfg.spawn))

    def engine(self, name: str, target: MavTarget, triage: MavTriage, cfg: FuzzConfig) -> MavlinkEngine:
        return MavlinkEngine(target, triage, cfg.seed, cfg.worker)

    def record(self, res: WorkerResult, name: str, engine: Any) -> None:
        """The vehicle's IDs and the probe's parameter (``res.extra``)."""
        info = engine.target.info
        res.extra.update(vehicle=f"{info.sysid}/{info.compid}", parameters=len(info.params),
                         probe=info.probe.decode(errors="replace"))


class MavlinkCampaign(ProtocolCampaign):
    """A MAVLink campaign (the profile's ``fuzz_campaign``): ``fuzz.campaign_core``'s over
    :class:`MavlinkPlugin`, its findings' ``repro.mcap`` written by ``fuzz.mavlink_triage``."""

    PROFILE, PLUGIN, WRITE_FILES = MAVLINK_PROFILE, MavlinkPlugin, write_repro
    REFUSED: ClassVar[tuple[str, ...]] = ("--mavlink", "--seeds", "--live", "--listen", "--target-id", "--db",
                                          "--rto", "--ack-window", "--broadcast-id")

    def own_summary(self, cfg: FuzzConfig, store: FindingStore, results: list[WorkerResult]) -> dict[str, Any]:
        """The target (how it ran, the vehicle's IDs, the probe's parameter) and each finding."""
        extra = next((r.extra for r in results if r.extra), {})
        return {"target": {**cfg.target_summary(), **extra}, "findings": len(store),
                "finding_list": [{"rule": f.rule, "level": f.level, "shape": f.shape, "count": f.occurrences,
                                  "replays": f.replays, "cases": len(f.cases)} for f in store.order]}

    def finding_lines(self, i: int, f: Finding, verbose: bool) -> list[str]:
        return super().finding_lines(i, f, verbose) + ([f"  expected: {f.expected}\n  {f.note}"] if verbose else [])

    def totals(self, s: dict[str, Any]) -> tuple[str, str]:
        return (super().totals(s)[0],
                f"vehicle {s['target'].get('vehicle', '?')}, probe {s['target'].get('probe', '?')}")

    @staticmethod
    def replay_inputs(f: Finding) -> list[Case]:
        return [case_from_json(c) for c in f.doc.get("cases", [])]

    @staticmethod
    def declined(f: Finding, cases: list[Case], prog: str) -> int | None:
        """A stopped heartbeat after a case that asked for it: no finding, not replayed, 0."""
        asked = next((i for i, c in enumerate(cases, 1) if asks_heartbeat_stop(c)), None)
        if f.doc.get("oracle") != "hang" or asked is None:
            return None
        print(f"{prog}: finding {f.rule} ({f.shape}) is no finding: its case {asked} asks the vehicle to "
              "stop its HEARTBEAT (MAV_CMD_SET_MESSAGE_INTERVAL), which it may do; not replayed")
        return 0

    @staticmethod
    def replay_on(target: MavTarget, f: Finding, cases: list[Case]) -> Replayed:
        """A finding's cases on a fresh vehicle, the probe its campaign's."""
        probe = bytes.fromhex(str(f.doc.get("probe_hex", "")))
        if probe and probe in target.info.params:
            target.info = replace(target.info, probe=probe)
        h = replay_cases(target.fresh, cases, Signature(str(f.doc.get("oracle", "answer")), f.rule,
                                                        str(f.doc.get("kind", ""))))
        return Replayed(h is not None, h.actual if h is not None else "")

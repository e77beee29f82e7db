"""A schedule: everything one simulated mission is a function of (issue 38, item 3) -- the
seed, the mission's shape, the link's impairment per direction (an ``--impair`` spec, written
in seed files as its one-string form: what the runner's ``--impair`` takes), the stalls and
the fault model -- and :func:`run_schedule`, which replays it: the same schedule always gives the same
trace and the same verdicts (``tests/sim/seeds/*.json`` are schedules).
"""

from __future__ import annotations

import random
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from mcp_conform.harness.impair import ImpairSpec, parse_impairment
from mcp_conform.sim.faults import FAULTS, Fault, fault_endpoint
from mcp_conform.sim.judges import Judged, judge_world
from mcp_conform.sim.link import check_spec
from mcp_conform.sim.models import DroneModel, ManagerModel, mission_items
from mcp_conform.sim.world import StallParams, World
from mcp_conform.spec.codec import MANAGER_ID
from mcp_conform.spec.profiles import pick

#: the protocol the simulator runs (its roles' IDs: ``spec.profiles``)
PROTOCOL = "mcp"

__all__ = ["Outcome", "Schedule", "run_schedule"]


@dataclass(frozen=True)
class Schedule:
    """One mission's schedule. Times in seconds of virtual time; ``retries``: every node's retry
    limit (MCP-RTX-1: "its retry limit", configurable; 20 lets a manager give a lost drone up
    and end its mission well inside the run); ``max_rtos``: the run ends after this many
    timeouts (a sender that never gives up is cut there, its view with it). ``down`` and
    ``up``: each direction's ``--impair`` spec (its ``seed`` unused: the links' seed is drawn
    from ``seed``)."""

    seed: int
    rto: float = 1.0
    drones: int = 1
    challenge: int = 1
    items: int = 2
    down: ImpairSpec = field(default_factory=ImpairSpec)
    up: ImpairSpec = field(default_factory=ImpairSpec)
    stalls: StallParams = field(default_factory=StallParams)
    fault: str | None = None
    retries: int = 20
    max_rtos: float = 400.0

    def __post_init__(self) -> None:
        if self.fault is not None and self.fault not in FAULTS:
            raise ValueError(f"unknown fault {self.fault!r}; known: {', '.join(FAULTS)}")
        if self.challenge not in (1, 2, 3) or not 1 <= self.drones <= 8 or self.items < 1 or self.rto <= 0:
            raise ValueError(f"bad mission shape: {self}")
        check_spec(self.down)
        check_spec(self.up)

    @property
    def faulty(self) -> Fault | None:
        return FAULTS[self.fault] if self.fault else None

    @property
    def faulty_party(self) -> int | None:
        """The faulty model's MCP ID: the manager, or drone 1."""
        f = self.faulty
        if f is None:
            return None
        fixed = pick(PROTOCOL, f.role)[1].fixed_id  # the role's ID, where the spec fixes it
        return fixed if fixed is not None else 1

    def to_json(self) -> dict[str, Any]:
        """The schedule as JSON; each link as its ``--impair`` text, which must read back as
        itself (a drawn delay is whole milliseconds)."""
        doc = asdict(self)
        for side in ("down", "up"):
            spec: ImpairSpec = getattr(self, side)
            text = spec.text()
            if parse_impairment(text) != spec:
                raise ValueError(f"link {side} {spec} does not read back from {text!r}")
            doc[side] = text
        return doc

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> Schedule:
        d = dict(doc)
        d["down"] = parse_impairment(d.get("down", "seed=0"))
        d["up"] = parse_impairment(d.get("up", "seed=0"))
        d["stalls"] = StallParams(**d.get("stalls", {}))
        return cls(**d)

    def but(self, **changes: Any) -> Schedule:
        return replace(self, **changes)


@dataclass
class Outcome:
    """A replayed schedule: the world after the run (views, links, parties) and the verdicts."""

    schedule: Schedule
    world: World
    items: tuple[Any, ...]
    judged: Judged | None

    @property
    def deviations(self) -> list[tuple[float, str]]:
        """What the fault model did that the correct one would not have (empty: no fault)."""
        pid = self.schedule.faulty_party
        if pid is None:
            return []
        return list(getattr(self.world.parties[pid].ep, "deviations", []))


def build_world(s: Schedule) -> tuple[World, tuple[Any, ...]]:
    rng = random.Random(s.seed)
    items = mission_items(s.items, rng.getrandbits(32))
    fault = s.faulty
    ids = tuple(range(1, s.drones + 1))
    faulty = s.faulty_party
    mgr_ep = fault_endpoint(fault, s.retries) if fault and faulty == MANAGER_ID else None
    manager = ManagerModel(ids, s.challenge, items, s.rto, s.retries, random.Random(rng.getrandbits(64)),
                           endpoint=mgr_ep)
    drones = []
    for d in ids:
        ep = fault_endpoint(fault, s.retries) if fault and faulty == d else None
        drones.append(DroneModel(d, s.rto, s.retries, random.Random(rng.getrandbits(64)),
                                 ready_at=rng.uniform(0.0, 2 * s.rto), endpoint=ep))
    world = World(manager, drones, s.down, s.up, rng.getrandbits(64), stalls=s.stalls,
                  max_time=s.max_rtos * s.rto)
    return world, items


def run_schedule(s: Schedule, *, judge: bool = True, explain: bool = True, monitor: bool = True) -> Outcome:
    """Run ``s`` from scratch and judge it (``judge=False``: the run alone, for the bench;
    ``explain`` / ``monitor`` False: that judge left out, :func:`sim.judges.judge_world`)."""
    world, items = build_world(s)
    world.run()
    judged = (judge_world(world, rto=s.rto, challenge=s.challenge, items=items, explain=explain, monitor=monitor)
              if judge else None)
    return Outcome(s, world, items, judged)

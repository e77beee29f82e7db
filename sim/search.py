"""The search over schedules (issue 38, item 3): the two properties, a seeded sweep that draws
schedules -- seeds, link parameters up to several ``--rto``, stalls, mission shapes, fault
models -- a shrinker for what fails, and the regression seeds kept from it.

The properties, on one replayed schedule (:func:`check`):

1. a correct model (every party correct, or every party but the faulty one) gets no failed
   MUST verdict from the monitor and no ``proven`` from ``judge.explain``; warned verdicts
   (SHOULD rules) are counted, not failed;
2. a faulty model gets its rule where its fault is observable (:mod:`sim.oracles`): the
   monitor fails it and ``judge.explain`` proves it or a disjunction that names it where it
   decides that rule -- and no other MUST rule from either.

A counterexample is shrunk (:func:`shrink`: each impairment removed, the mission made
smaller, while the property still fails) and written as a seed file (:func:`save_seed`):
JSON, the schedule and what was found, replayed by :func:`replay` -- one call, the same
trace and verdicts.
"""

from __future__ import annotations

import hashlib
import json
import random
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from mcp_conform.harness.impair import ImpairSpec
from mcp_conform.sim.faults import FAULTS
from mcp_conform.sim.oracles import observable
from mcp_conform.sim.schedule import Outcome, Schedule, run_schedule
from mcp_conform.sim.world import StallParams

__all__ = ["Problem", "Stats", "check", "digest", "draw_schedule", "load_seed", "replay", "save_seed", "shrink", "sweep"]

#: The rules ``judge.explain`` decides (the others it leaves to the monitor).
EXPLAINED = frozenset({"MCP-ACK-1", "MCP-ACK-2", "MCP-RTX-1", "MCP-RTX-2"})


@dataclass(frozen=True)
class Problem:
    """A property that failed: which judge (``monitor`` / ``explain``), which party, what."""

    judge: str
    party: int
    rule: str
    why: str

    def text(self) -> str:
        return f"{self.judge}: node {self.party} {self.rule}: {self.why}"


def _names(rule: str, found: str) -> bool:
    """``found`` is ``rule`` or a disjunction naming it (``MCP-RTX-1 or MCP-RTX-2``)."""
    return rule in found.split(" or ")


def check(o: Outcome, judges: tuple[str, ...] = ("monitor", "explain")) -> list[Problem]:
    """The properties on ``o`` (see the module docstring) by ``judges``; empty when they hold.
    Each of ``judges`` must have judged ``o`` (``run_schedule``'s ``monitor`` / ``explain``): a
    judge left out has no verdicts, and its property must not read as held."""
    j = o.judged
    assert j is not None, "check needs a judged outcome"
    unjudged = [name for name in judges if name not in j.judges]
    if unjudged:
        raise ValueError(f"check by {', '.join(unjudged)}: that judge did not judge this outcome (judged by {j.judges})")
    s = o.schedule
    faulty = s.faulty_party
    fault = s.faulty
    out: list[Problem] = []
    for pid in o.world.parties:
        rule = fault.rule if fault is not None and pid == faulty else None
        viol = {v.rule: v.actual for v in j.violations.get(pid, [])}
        for r in sorted(j.failed(pid)):
            if r != rule:
                out.append(Problem("monitor", pid, r, f"failed: {viol.get(r, '(no violation text)')}"))
        for r in sorted(j.proven(pid)):
            if rule is None or not _names(rule, r):
                out.append(Problem("explain", pid, r, f"proven: {j.explained[pid][r].evidence[:300]}"))
        if rule is None:
            continue
        seen, why = observable(o)
        if seen is not True:
            continue
        if rule not in j.failed(pid):
            verdict = j.verdicts.get(pid, {}).get(rule, "not_observed")
            out.append(Problem("monitor", pid, rule, f"{verdict}, not failed, where observable: {why}"))
        if rule in EXPLAINED and not any(_names(rule, r) for r in j.proven(pid)):
            out.append(Problem("explain", pid, rule, f"not proven where observable: {why}"))
    return [p for p in out if p.judge in judges]


# ------------------------------------------------------------------ drawing schedules
RTOS = (0.3, 1.0, 5.0)


def draw_link(rng: random.Random, rto: float) -> ImpairSpec:
    """An ``--impair`` spec: clean a fifth of the time, else each impairment drawn -- loss,
    duplication into 1-2 extra copies, reordering, a delay range up to 3 x rto (a reordered
    copy waits up to 3 times its top: ``harness.impair``), and now and then Gilbert-Elliott
    bursts and a rate limit; delays in whole milliseconds, so a seed file's text is exact."""
    if rng.random() < 0.2:
        return ImpairSpec()
    hi_ms = round(rng.choice((0.0, 0.1, 0.5, 1.0, 2.0, 3.0)) * rto * 1000)
    lo_ms = round(rng.uniform(0.0, hi_ms))
    dup = rng.choice((0.0, 0.1, 0.3))
    burst = rng.random() < 0.1
    return ImpairSpec(loss=rng.choice((0.0, 0.05, 0.2, 0.4)), dup=dup,
                      copies=rng.choice((1, 1, 2)) if dup else 1, reorder=rng.choice((0.0, 0.1, 0.3)),
                      delay_lo_s=lo_ms / 1000, delay_hi_s=hi_ms / 1000,
                      burst_gb=rng.choice((0.05, 0.2)) if burst else 0.0,
                      burst_bg=rng.choice((0.3, 0.6)) if burst else 0.0,
                      rate=rng.choice((2.0, 5.0, 20.0)) if rng.random() < 0.1 else None)


def draw_schedule(rng: random.Random, fault: str | None = None) -> Schedule:
    rto = rng.choice(RTOS)
    down = draw_link(rng, rto)
    up = down if rng.random() < 0.5 else draw_link(rng, rto)
    stalls = (StallParams() if rng.random() < 0.6 else
              StallParams(count=rng.randint(1, 3), max_len=rng.choice((0.5, 1.0, 3.0)) * rto, span=20 * rto))
    return Schedule(seed=rng.getrandbits(32), rto=rto, drones=rng.randint(1, 3), challenge=rng.randint(1, 3),
                    items=rng.randint(1, 3), down=down, up=up, stalls=stalls, fault=fault)


@dataclass
class Stats:
    """What a sweep ran and found."""

    schedules: int = 0
    per_fault: dict[str, int] = field(default_factory=dict)
    observable: dict[str, int] = field(default_factory=dict)
    warned: dict[str, int] = field(default_factory=dict)
    failures: list[tuple[Schedule, list[Problem]]] = field(default_factory=list)


def sweep(n: int, seed: int, faults: tuple[str | None, ...] = (None, *FAULTS),
          on_failure: Callable[[Schedule, list[Problem]], None] | None = None,
          stop: Callable[[], bool] | None = None,
          judges: tuple[str, ...] = ("monitor", "explain")) -> Stats:
    """``n`` schedules drawn from ``seed``, the fault models in turn, each run, judged, checked
    (``stop()`` true: no more; a caller's wall-time bound, the schedules the same first ones)
    by ``judges`` alone (the other judge not run; ``warned`` counts the monitor's verdicts)."""
    rng = random.Random(seed)
    st = Stats()
    for i in range(n):
        if stop is not None and stop():
            break
        fault = faults[i % len(faults)]
        s = draw_schedule(rng, fault)
        o = run_schedule(s, monitor="monitor" in judges, explain="explain" in judges)
        key = fault or "correct"
        st.schedules += 1
        st.per_fault[key] = st.per_fault.get(key, 0) + 1
        if fault is not None and observable(o)[0] is True:
            st.observable[key] = st.observable.get(key, 0) + 1
        assert o.judged is not None
        for pid in o.world.parties:
            for r in o.judged.warned(pid):
                st.warned[r] = st.warned.get(r, 0) + 1
        problems = check(o, judges)
        if problems:
            st.failures.append((s, problems))
            if on_failure is not None:
                on_failure(s, problems)
    return st


# ------------------------------------------------------------------ shrinking
def _simpler(s: Schedule) -> Iterator[Schedule]:
    """Smaller neighbours of ``s``: fewer drones and items, each impairment gone or halved."""
    if s.drones > 1:
        yield s.but(drones=s.drones - 1)
    if s.items > 1:
        yield s.but(items=s.items - 1)
    if s.challenge != 1:
        yield s.but(challenge=1)
    if s.stalls.count:
        yield s.but(stalls=StallParams())
    for side in ("down", "up"):
        p: ImpairSpec = getattr(s, side)
        for name, changes in SIMPLER_LINK:
            if getattr(p, name):
                yield s.but(**{side: replace(p, **changes)})
    if s.up != s.down:
        yield s.but(up=s.down)


#: each impairment of a link, and the spec without it (``_simpler``)
SIMPLER_LINK: tuple[tuple[str, dict[str, Any]], ...] = (
    ("dup", {"dup": 0.0, "copies": 1}), ("reorder", {"reorder": 0.0}), ("loss", {"loss": 0.0}),
    ("burst_gb", {"burst_gb": 0.0, "burst_bg": 0.0, "burst_loss": 1.0}), ("rate", {"rate": None}),
    ("delay_hi_s", {"delay_lo_s": 0.0, "delay_hi_s": 0.0}), ("delay_lo_s", {"delay_lo_s": 0.0}),
)


def shrink(s: Schedule, fails: Callable[[Schedule], bool], budget: int = 200) -> Schedule:
    """The simplest neighbour of ``s`` found, greedily, on which ``fails`` still holds."""
    tries = 0
    improved = True
    while improved and tries < budget:
        improved = False
        for t in _simpler(s):
            tries += 1
            if fails(t):
                s, improved = t, True
                break
    return s


def same_problems(problems: list[Problem]) -> Callable[[Schedule], bool]:
    """A shrink predicate: the schedule still shows a problem of the same judge, party role and rule."""
    keys = {(p.judge, p.party == 0, p.rule) for p in problems}

    def fails(s: Schedule) -> bool:
        return any((p.judge, p.party == 0, p.rule) in keys for p in check(run_schedule(s)))

    return fails


# ------------------------------------------------------------------ regression seeds
def digest(o: Outcome) -> str:
    """A hash of everything a replay must reproduce: every view, every link record, every verdict."""
    h = hashlib.sha256()
    for pid, view in sorted(o.world.views.items()):
        for r in view:
            h.update(repr((pid, r.t_ns, r.tx, r.run_delay, r.data)).encode())
    for key, link in sorted(o.world.links.items()):
        h.update(repr((key, [(r.index, r.copy, r.t_sent, r.t_arrive, r.kinds) for r in link.records])).encode())
    if o.judged is not None:
        h.update(json.dumps(o.judged.summary(), sort_keys=True).encode())
        h.update(repr(sorted((p, r, v.status) for p, e in o.judged.explained.items() for r, v in e.items())).encode())
    return h.hexdigest()


def save_seed(path: Path, s: Schedule, problems: list[Problem], *, reason: str, xfail: bool,
              explain_reason: str | None = None, open_reason: str | None = None) -> None:
    """A regression seed: the schedule, what was found, why (``reason``: the monitor's false
    verdict, ``xfail``: the monitor's test is its strict xfail; ``explain_reason``: so is
    judge.explain's), the failures judge.explain's veto dropped (``vetoed``: what the monitor
    without the veto said), ``open_reason``: a false verdict on a correct party the judge still
    gives (``open``, a strict xfail too), and the digest its replay must give."""
    o = run_schedule(s)
    doc: dict[str, Any] = {"schedule": s.to_json(), "found": [p.text() for p in problems], "reason": reason,
                           "xfail": xfail, "digest": digest(o)}
    assert o.judged is not None
    vetoed = [f"node {pid} {v.rule}: {v.actual}" for pid, vs in sorted(o.judged.vetoed.items()) for v in vs]
    if vetoed:  # the old judge's failures, which judge.explain's veto drops
        doc["vetoed"] = vetoed
    if explain_reason:
        doc["explain_reason"] = explain_reason
    if open_reason:
        doc["open"] = open_reason
    path.write_text(json.dumps(doc, indent=1, sort_keys=True) + "\n", encoding="utf-8")


def load_seed(path: str | Path) -> dict[str, Any]:
    doc: dict[str, Any] = json.loads(Path(path).read_text(encoding="utf-8"))
    doc["schedule"] = Schedule.from_json(doc["schedule"])
    return doc


def replay(path: str | Path) -> tuple[Outcome, list[Problem]]:
    """One call: a seed file's schedule run again, judged, and the properties checked."""
    o = run_schedule(load_seed(Path(path))["schedule"])
    return o, check(o)

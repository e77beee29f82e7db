"""The MAVLink roles' simulated runs that more than one test reads (issue 38: one run's record
answers every test that asserts something of it). A seed gives the same run
(test_a_seed_gives_the_same_run in tests/sim/test_mavlink_vehicle_sim.py and
test_mavlink_gcs_sim.py), so a run made once in a worker serves each test that asks for it:

- the reference vehicle and ground station over TCP at seed 1: their passes-every-case tests and
  tests/sim/test_report_schema.py's reports (and its merge);
- a faulty vehicle or ground station at seed 2: its fails-its-rule test, and the schema test of
  that fault's report (the merge's faulty half too).

Each caller gets its own deep copy of the report, so no test sees what another did to it. Only the
runs in :data:`SHARED` are kept (a worker's memory holds what a later test can read, no more);
any other is run afresh. Under xdist each worker makes its own: never more runs than before.
"""

from __future__ import annotations

import copy
import dataclasses
import functools

from mcp_conform.sim.gcs_role import run_gcs_cases
from mcp_conform.sim.runner import SimRun
from mcp_conform.sim.vehicle_role import run_vehicle_cases

__all__ = ["SHARED", "gcs_run", "vehicle_run"]

#: (role, fault, seed): the runs read by more than one test (module docstring), over TCP
SHARED = frozenset({
    ("vehicle", None, 1), ("vehicle", "no-unsupported-ack", 2), ("vehicle", "double-ack", 2),
    ("gcs", None, 1), ("gcs", "no-heartbeat", 2),
})


@functools.cache
def _kept(role: str, fault: str | None, seed: int) -> SimRun:
    run = run_vehicle_cases if role == "vehicle" else run_gcs_cases
    return run(fault, seed=seed)


def _run(role: str, fault: str | None, seed: int, transport: str) -> SimRun:
    if transport == "tcp" and (role, fault, seed) in SHARED:
        kept = _kept(role, fault, seed)
        return dataclasses.replace(kept, report=copy.deepcopy(kept.report))
    run = run_vehicle_cases if role == "vehicle" else run_gcs_cases
    return run(fault, seed=seed, transport=transport)


def vehicle_run(fault: str | None, seed: int, transport: str = "tcp") -> SimRun:
    """``run_vehicle_cases(fault, seed=seed, transport=transport)``, made once where shared."""
    return _run("vehicle", fault, seed, transport)


def gcs_run(fault: str | None, seed: int, transport: str = "tcp") -> SimRun:
    """``run_gcs_cases(fault, seed=seed, transport=transport)``, made once where shared."""
    return _run("gcs", fault, seed, transport)

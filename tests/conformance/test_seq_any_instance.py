"""MCP-SEQ-1's drone case (conformance/cases/test_seq.py) is not bound to the observed startup:
under ``mcp-conform --parallel`` it runs on every node instance, each on its own node's
traffic, and an instance that ran the quick startup (no part of the observed one) judges it
as the one that observed the startup does (``conformance.schedule.shard_plan``)."""

from __future__ import annotations

import pytest

from mcp_conform.conformance.cases import test_seq as seq_cases
from mcp_conform.conformance.drone_case import CaseContext
from mcp_conform.conformance.schedule import EVERY, STARTUP_BOUND, plan_cases, shard_plan
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import TargetDriver
from mcp_conform.harness.drone_session import Session, Startup
from mcp_conform.harness.errors import Inconclusive

SEQ_1 = "SEQ/test_successive_messages_take_successive_numbers"
CASE = seq_cases.test_successive_messages_take_successive_numbers
#: the startup's parts each on an instance of its own at --rto 5 (the copies' part alone)
STARTUP = [("BLK/test_nothing_new_while_mission_ready_awaits_its_ack", "startup"),
           ("BLK/test_no_mission_ready_without_a_gps_fix", "startup"),
           ("RTX/test_only_the_right_ack_ends_retransmission", "startup")]


def _phase() -> str:
    return next(m.args[0] for m in CASE.pytestmark if m.name == "mcp_phase")


def test_it_runs_on_every_instance_not_with_the_startup():
    """Judged on the whole run's traffic: a step on every instance (``shard`` None), like the
    HDR cases, and no startup part of its own (it was a step on one instance, which under
    ``--parallel`` need not be one that observed the startup)."""
    assert SEQ_1 not in STARTUP_BOUND
    cases = [*STARTUP, ("ACK/test_every_command_type_is_acked", "main"), (SEQ_1, _phase())]
    plan = shard_plan(plan_cases(cases), 3, 5.0, 2.0)
    step = next(s for s in plan.steps if s.case == SEQ_1)
    assert step.shard is None and step.why == EVERY, step
    assert plan.shards == 3 and any(not plan.observes_startup(k) or "copies" not in plan.startup_parts(k)
                                    for k in range(3))
    assert all(SEQ_1 in plan.of_shard(k) for k in range(plan.shards)), plan.lines()


def _context(startup: Startup) -> CaseContext:
    session = Session(RunConfig(target=("127.0.0.1", 9), rto=0.2, ack_window=0.25))
    session.driver = TargetDriver(("127.0.0.1", 9), ("127.0.0.1", 0))
    session.target_id = 1
    session.startup = startup
    return CaseContext(session, SEQ_1, ("MCP-SEQ-1",))


@pytest.mark.parametrize("startup", [Startup(), Startup(observed=True)], ids=["quick-startup", "observed-startup"])
def test_the_verdict_does_not_depend_on_the_startup(startup):
    """The same outcome on an instance that observed the startup and on one that did not: the
    spec's reason (a drone sends one new non-ACK message per mission), never "not observed"."""
    with pytest.raises(Inconclusive) as exc:
        CASE(_context(startup))
    assert "MCP-SEQ-1 is not observable on a drone node" in str(exc.value)
    assert "startup" not in str(exc.value)

"""A drone that gives up its Mission_Ready short of MCP-RTX-1's copies and exits gets MCP-RTX-1's
verdict, not a setup error (issue 38; ``harness.drone_giveup``).

A retry limit of 0 or 1 (one or two copies; spec/mcp.yaml's ``min_copies`` asks for 3, a limit
of 2 the least allowed), exiting when it gives up as the C++ drone does (exit 1), got exit 2,
"the node exited with code 1 before Start_Mission was sent": the startup had observed what
MCP-RTX-1 needs -- fewer than 3 copies while the ACK was withheld -- and hid it. Now the runner
keeps that observation, restarts the node with its Mission_Ready ACKed at once and runs the
cases on it: MCP-RTX-1 fails, naming the copies and the exit; MCP-RTX-2 is skipped ("see
MCP-RTX-1"); no other MUST rule fails, the run monitor's included (the restart's new
Mission_Ready is no renumbered retransmission, MCP-SEQ-2).

A node that ends otherwise keeps the setup error: one killed by a signal, one that exits as it
sends its copy (a crash, not a timer's give-up), one whose restart cannot start either (the
error then names the first instance's MCP-RTX-1 observation).
"""

from __future__ import annotations

import random

import pytest

from mcp_conform.sim.models import DroneModel, ExitingDrone
from mcp_conform.sim.runner import ModelFactory, drone_factory, run_cases
from mcp_conform.spec import RULES

RTO = 0.2


def must_failed(rules: dict[str, str]) -> set[str]:
    return {r for r, o in rules.items() if o == "failed" and RULES[r].level == "MUST"}


@pytest.mark.parametrize("retries", [0, 1])
@pytest.mark.parametrize("mavlink", [False, True], ids=["no-vehicle", "vehicle"])
def test_a_drone_that_gives_up_short_and_exits_fails_rtx1_and_no_other(retries: int, mavlink: bool) -> None:
    run = run_cases(drone_factory(rto=RTO, seed=5, retries=retries, exits_on_give_up=True), seed=5,
                    mavlink=mavlink)
    assert run.report.get("error") is None and run.rc == 1, run.explain()
    assert must_failed(run.rules) == {"MCP-RTX-1"}, run.explain()
    assert [f["rule"] for f in run.report.get("failures", []) if f.get("source") == "monitor"] == [], run.explain()
    assert run.models == 2, run.explain()  # the first instance gone, the cases on its restart
    cases = {c["id"]: c for c in run.report["cases"]}
    rtx1 = cases["RTX/test_mission_ready_is_retransmitted_until_acked"]
    n = retries + 1
    assert rtx1["actual"].startswith(f"{n} cop{'y' if n == 1 else 'ies'} while withheld, then exited with code 1"), rtx1
    rtx2 = cases["RTX/test_only_the_right_ack_ends_retransmission"]
    assert rtx2["outcome"] == "skipped" and "(see MCP-RTX-1)" in rtx2["reason"], rtx2
    # the cases ran on the restarted node: the end of its mission judged
    assert cases["BLK/test_end_mission_then_rtl"]["outcome"] in ("passed", "skipped"), run.explain()


def exiting(code: int, after: float, *, on: int = 2, then: ModelFactory | None = None) -> ModelFactory:
    """The reference drone (retry limit 20) ending with ``code`` ``after`` s after its ``on``-th
    Mission_Ready copy (``sim.models.ExitingDrone``); its restarts ``then`` (None: the same)."""
    spawns = random.Random(5)
    made: list[DroneModel] = []

    def make(now: float) -> DroneModel:
        if made and then is not None:
            return then(now)
        model = ExitingDrone(1, RTO, 20, random.Random(spawns.getrandbits(64)), ready_at=now + 0.05)
        model.exit_on, model.exit_after, model.exit_code = on, after, code
        made.append(model)
        return model

    return make


@pytest.mark.parametrize(("code", "after", "how"), [
    (3, 0.01, "exited with code 3"),  # as it sends its second copy: a crash, not a timer
    (-11, RTO, "killed by SIGSEGV"),  # at its timer's time, but by a signal
], ids=["exit-as-it-sends", "signal"])
def test_a_node_that_ends_otherwise_keeps_the_setup_error(code: int, after: float, how: str) -> None:
    run = run_cases(exiting(code, after), seed=5, select=["RTX"])
    error = run.report.get("error") or ""
    assert run.rc == 2, run.explain()
    assert error.startswith("the node ") and "before Start_Mission was sent" in error, error
    assert run.models == 1, run.explain()


def test_a_restart_that_cannot_start_is_a_setup_error_naming_rtx1() -> None:
    """The first instance gives up after two copies (exit 1 a period after the second); its restart
    exits at once, before any Mission_Ready: exit 2, the error naming MCP-RTX-1's observation."""
    def dead(now: float) -> DroneModel:
        model = ExitingDrone(1, RTO, 20, random.Random(1), ready_at=now + 10.0)
        model.exit_on, model.exit_code = 0, 5
        model.exit_at = now + 0.01
        return model

    run = run_cases(exiting(1, RTO, then=dead), seed=5, select=["RTX"])
    error = run.report.get("error") or ""
    assert run.rc == 2, run.explain()
    assert error.startswith("the node exited with code 5 before sending Mission_Ready on its restart after "
                            "MCP-RTX-1's observation (it stopped after 2 copies of its Mission_Ready without the "
                            "ACK, then exited with code 1"), error
    assert run.models == 2, run.explain()

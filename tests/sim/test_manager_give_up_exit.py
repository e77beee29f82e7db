"""A conformant retry limit of 2 (3 copies: spec/mcp.yaml ``min_copies``, "a retry limit of 2 is
the rule's 'configurable' limit, no violation") in a manager that ends every mission when it
gives up on one drone (the Go manager's ``-retries 2 -exit-on-give-up``, issue 38), in the
simulator (sim.manager_runner).

The runner's main mission withheld the first Start_Mission's ACK past its third copy: the wrong
ACKs after it, then a wait for a fourth copy, then the right ACK -- after such a manager's
give-up (the third copy plus its timeout). It exited there and MCP-FLOW-2/3 and the challenge's
FLOW rule failed as MUST, though the give-up was the runner's doing and what a manager does
after one is not specified (MCP-FLOW-7). MCP-RTX-1 is "Observed: at least 3 copies while the ACK
is withheld": the runner now answers the third copy as it arrives, and MCP-RTX-2 is judged on
the next new unicast (``DronePlayers.arm_again``: the wrong ACKs after its second copy, its third
copy answered as it arrives too). So the manager gives up on nothing and passes every rule; the
faults beside it keep their verdicts (a manager that never retransmits, or whose retry limit is
1, fails MCP-RTX-1; one that takes a wrong ACK fails MCP-RTX-2; each no other MUST rule).
"""

from __future__ import annotations

import random
from typing import Any

import pytest

from mcp_conform.sim.faults import Fault, GiveUpAfterTwo, fault_endpoint
from mcp_conform.sim.manager_runner import run_manager_cases
from mcp_conform.sim.models import ManagerModel
from mcp_conform.spec import load

SHORT = {"rto": 0.2, "ack_window": 0.25}
FLOW = {1: "MCP-FLOW-4", 2: "MCP-FLOW-5", 3: "MCP-FLOW-6"}
MUST = {r.id for r in load().rules if r.level == "MUST"}


class ExitsOnGiveUp(ManagerModel):
    """Correct (a retry limit of 2; what follows a give-up is not specified, MCP-FLOW-7): at its
    first give-up it ends every mission, exiting with code 1 (the Go manager's
    ``-exit-on-give-up``)."""

    def _outcome(self, ev: Any, now: float) -> None:
        super()._outcome(ev, now)
        if self.failed and not self.closed:
            self.close(now, "exit:1")


def _exits_on_give_up(seed: int) -> Any:
    endpoint = fault_endpoint(Fault("give-up-after-three", "manager", None, GiveUpAfterTwo, 2), 2)
    spawns = random.Random(seed)

    def make(drones: tuple[int, ...], challenge: int, items: tuple[Any, ...], now: float) -> ExitsOnGiveUp:
        return ExitsOnGiveUp(drones, challenge, items, SHORT["rto"], 2, random.Random(spawns.getrandbits(64)),
                             endpoint=endpoint)

    make.__name__ = "exits-on-give-up"
    return make


def _case(run: Any, rule: str) -> dict[str, Any]:
    return next(c for c in run.report["cases"] if c["rules"] == [rule])


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_a_retry_limit_of_two_that_exits_on_give_up_is_not_made_to_give_up(challenge):
    run = run_manager_cases(_exits_on_give_up(challenge), seed=challenge, challenge=challenge, serial=True, **SHORT)
    bad = set(run.rules_with("failed", "warned"))
    assert run.rc == 0 and not bad, run.explain()
    w = run.missions["main"].withheld
    # MCP-RTX-1 observed as its rule says: 3 copies while the ACK was withheld, the third answered
    assert len(w.copies) == 3 and w.right_ack is not None, run.explain()
    assert 0 <= w.right_ack.t - w.copies[-1].t < SHORT["rto"] / 2, (w.right_ack.t, w.copies[-1].t)
    main, silent = run.managers  # --serial: the main scenario's manager, then the silent one's
    assert not main.failed and main.outcome == "end_mission", "the runner made the manager give up"
    assert silent.failed and silent.outcome == "exit:1"  # the silent drone's give-up: MCP-FLOW-7, INFO
    assert _case(run, "MCP-FLOW-7")["outcome"] == "info"
    for rule in ("MCP-RTX-1", "MCP-RTX-2", "MCP-FLOW-2", "MCP-FLOW-3", FLOW[challenge]):
        assert run.rules[rule] == "passed", (rule, run.explain())
    # MCP-RTX-2 judged (not skipped) on the next new unicast: its third copy came after the wrong ACKs
    a = run.missions["main"].withheld_again
    assert a.wrong_acks and a.copy_after_wrong_acks is not None and a.right_ack is not None, run.explain()


@pytest.mark.parametrize(("fault", "rule"), [("manager-rtx-none", "MCP-RTX-1"), ("give-up-after-two", "MCP-RTX-1"), ("wrong-seq-ack", "MCP-RTX-2")])
def test_the_faults_beside_it_keep_their_rule_and_no_other(fault, rule):
    run = run_manager_cases(fault, seed=5, serial=True, **SHORT)
    assert run.rules[rule] == "failed", run.explain()
    assert set(run.rules_with("failed")) & MUST == {rule}, run.explain()

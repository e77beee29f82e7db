"""A drone that gives up its Mission_Ready short of MCP-RTX-1's copies and announces again under a
new number is judged by its copies counted by number (issue 38; the independent Node.js drone's
``--retries 1 --reannounce``, tests/examples/test_js_drone.py).

"Retransmissions of the same message are identified by repeating sequence number": two copies of
seq N, then (its retry limit reached, a timeout later) a new Mission_Ready, seq N+1, are two
messages. Seq N had 2 copies while its ACK was withheld -- MCP-RTX-1's fault, as the same node
that exits on give-up is judged (tests/sim/test_give_up_short.py) -- and every copy of N repeats
its number and bytes (MCP-SEQ-2 kept). The suite said MCP-SEQ-2 failed ("repeats unACKed seq N
with a new number"; SEQ/test_retransmission_repeats_seq_and_bytes "1 of 2 copies differ") and
MCP-RTX-1 passed, counting N+1 as N's third copy: a pass of RTX-1 on copies with different
numbers. A drone whose every retransmission takes a new number (the ``rtx-new-seq`` fault: one
copy of each) keeps MCP-SEQ-2's failure, and MCP-RTX-1 does not pass on its renumbered copies.
"""

from __future__ import annotations

import random

import pytest

from mcp_conform.reference_impl.events import DeliveryConfirmed, DeliveryFailed
from mcp_conform.sim.models import DroneModel
from mcp_conform.sim.mutants import mutant_factory
from mcp_conform.sim.runner import ModelFactory, run_cases
from mcp_conform.spec import RULES

RTO = 0.2


class ReannouncingDrone(DroneModel):
    """The reference drone at retry limit 1 that, when its Mission_Ready is given up, sends a new
    one (the endpoint's next number) and goes on serving: the Node.js drone's ``--reannounce``."""

    exits_on_give_up = False

    def _outcome(self, ev: DeliveryConfirmed | DeliveryFailed, now: float) -> None:
        super()._outcome(ev, now)
        if isinstance(ev, DeliveryFailed) and not self.ready_acked and not self.closed:
            self.send_ready(now)


def reannouncing(retries: int) -> ModelFactory:
    spawns = random.Random(5)

    def make(now: float) -> DroneModel:
        return ReannouncingDrone(1, RTO, retries, random.Random(spawns.getrandbits(64)), ready_at=now + 0.05)

    return make


def must_failed(rules: dict[str, str]) -> set[str]:
    return {r for r, o in rules.items() if o == "failed" and RULES[r].level == "MUST"}


@pytest.mark.parametrize("mavlink", [False, True], ids=["no-vehicle", "vehicle"])
def test_a_drone_that_gives_up_short_and_announces_again_fails_rtx1_not_seq2(mavlink: bool) -> None:
    run = run_cases(reannouncing(1), seed=5, mavlink=mavlink)
    assert run.report.get("error") is None and run.rc == 1, run.explain()
    assert must_failed(run.rules) == {"MCP-RTX-1"}, run.explain()
    assert run.rules["MCP-SEQ-2"] == "passed", run.explain()
    cases = {c["id"]: c for c in run.report["cases"]}
    rtx1 = cases["RTX/test_mission_ready_is_retransmitted_until_acked"]
    assert rtx1["outcome"] == "failed" and rtx1["actual"].startswith("2 copies"), rtx1
    # the monitor counts by number too: seq N's two copies, then a new message (one judge)
    mon = run.report["monitor"]
    assert [(v["rule"], v["node"]) for v in mon["violations"]] == [("MCP-RTX-1", 1)], run.explain()


def test_at_the_least_retry_limit_announcing_again_is_correct() -> None:
    """Retry limit 2 (3 copies, the rule's configurable least): the new Mission_Ready after the
    give-up breaks nothing."""
    run = run_cases(reannouncing(2), seed=5)
    assert run.report.get("error") is None and run.rc == 0, run.explain()
    assert run.rules_with("failed", "warned") == {}, run.explain()


def test_a_drone_whose_retransmissions_take_new_numbers_keeps_seq2() -> None:
    """The ``rtx-new-seq`` fault (one copy of each number): MCP-SEQ-2 failed, and neither MCP-RTX-1
    nor MCP-RTX-3 (copies of one message) passed on its renumbered copies."""
    run = run_cases(mutant_factory("rtx-new-seq", rto=RTO, seed=5), seed=5)
    assert run.rules_with("failed", "warned") == {"MCP-SEQ-2": "failed"}, run.explain()
    assert run.rules["MCP-RTX-1"] != "passed", run.explain()
    assert run.rules["MCP-RTX-3"] != "passed", run.explain()

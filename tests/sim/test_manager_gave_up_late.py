"""A correct manager whose command the runner answered only after the manager's retry limit
(issue 38: no verdict under any schedule). Under ``preempt=(0.5, 0.5)`` the runner's receiver
falls seconds behind: the manager sends a command its 13 copies and gives the drone up, and the
runner's answer comes after the next copy was due -- the right ACK 0.98 s after, MCP-RTX-2's
deliberate wrong ACKs (second observation) 26 ms after the 13th copy (seed 58); or the right ACK
4 ms after the next copy was due, inside the clocks' 15 ms (seed 108). Giving the drone up at
that timer is one explanation of the trace, so the flow rules do not count the drone as
answered (``conformance.manager_case.gave_up``): on the head before this test, the four seeds
failed MCP-FLOW-3 ("no End_Mission to drone(s) [2]") and MCP-FLOW-5 (10 runs of 600 at seeds
0-199, challenges 1-3)."""

from __future__ import annotations

import pytest

from mcp_conform.sim.manager_runner import run_manager_cases

PREEMPT = (0.5, 0.5)


@pytest.mark.parametrize(("seed", "challenge"), [(58, 1), (68, 2), (108, 2), (193, 3)])
def test_a_drone_given_up_before_the_late_answer_is_excused(seed, challenge):
    run = run_manager_cases(None, seed=seed, challenge=challenge, preempt=PREEMPT, rto=0.2, ack_window=0.25)
    assert run.preemptions > 0
    assert run.rc == 0 and not run.rules_with("failed", "warned"), run.explain()

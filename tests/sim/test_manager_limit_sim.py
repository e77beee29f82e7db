"""Two correct managers the manager role's suite judged wrong (H-cmanager's C manager, issue 38),
and the faults beside them that must keep their verdicts, in the simulator (sim.manager_runner).

- A retry limit of 2 (3 copies: spec ``min_copies``, "no violation"). The first Start_Mission's
  copies stop right after the runner's wrong ACKs, as those of a manager that takes a wrong ACK
  do; MCP-RTX-2 failed ("no copy after them") and the drone it gave up was not excused from
  MCP-FLOW-3/4. Then a second observation told them apart by what the manager does, not when:
  the next new unicast withheld, the same wrong ACKs after its second copy -- a third copy
  passes RTX-2, none fails it (wrong-seq-ack). Since session 34 that observation is RTX-2's
  only one: the first Start_Mission's third copy is answered as it arrives, no drone given up.
- A pause mid-mission longer than the runner's idle window (max(2.5 rto, 2 ack-window, 1 s)):
  the record was ended "idle" and MCP-FLOW-3 and the challenge's flow rule failed on the
  commands not yet sent, though no rule asks a manager to go on at any pace. Now a live manager
  mid-mission is waited for up to the record's cap; one stalled for ever still fails them there.
"""

from __future__ import annotations

import random

import pytest

from mcp_conform.sim.manager_faults import PausesMidMission, StallsMidMission
from mcp_conform.sim.manager_runner import run_manager_cases

SHORT = {"rto": 0.2, "ack_window": 0.25}
FLOW = {1: "MCP-FLOW-4", 2: "MCP-FLOW-5", 3: "MCP-FLOW-6"}


def _case(run, rule):
    return next(c for c in run.report["cases"] if c["rules"] == [rule])


def _bad(run):
    return set(run.rules_with("failed", "warned"))


@pytest.mark.parametrize(("challenge", "serial"), [(1, False), (2, True)], ids=["1-side-by-side", "2-serial"])
def test_a_retry_limit_of_two_passes_rtx_2_and_its_given_up_drone_is_excused(challenge, serial):
    """(Since session 34 the main mission answers the first Start_Mission's third copy as it
    arrives, and judges MCP-RTX-2 on the next new unicast alone: the limit of 2 is no longer
    made to give up there -- tests/sim/test_manager_give_up_exit.py -- and RTX-2 is judged on
    the observation that told it apart before.)"""
    run = run_manager_cases("give-up-after-three", seed=challenge, challenge=challenge, serial=serial, **SHORT)
    assert run.rc == 0 and not _bad(run), run.explain()
    rtx2 = _case(run, "MCP-RTX-2")
    assert rtx2["outcome"] == "passed", rtx2  # judged, not skipped
    assert any("a copy after the wrong ACKs sent after its second copy" in n for n in rtx2["notes"]), rtx2
    w = run.missions["main"].withheld
    assert len(w.copies) == 3 and not w.wrong_acks and w.right_ack is not None  # answered at the third
    flow3 = _case(run, "MCP-FLOW-3")
    assert flow3["outcome"] == "passed" and not any("gave up on drone(s)" in n for n in flow3["notes"]), flow3
    assert run.rules[FLOW[challenge]] == "passed", run.explain()


def test_a_manager_that_takes_a_wrong_ack_fails_rtx_2_by_the_second_observation():
    """wrong-seq-ack's first Start_Mission stops after the wrong ACKs as the limit of 2 does; its
    second withheld message stops after them too: the case fails it (not only the monitor)."""
    run = run_manager_cases("wrong-seq-ack", seed=2, **SHORT)
    assert _bad(run) == {"MCP-RTX-2"}, run.explain()
    rtx2 = _case(run, "MCP-RTX-2")
    assert rtx2["outcome"] == "failed", rtx2
    assert "its ACK withheld: 2 copies, the same wrong ACKs, no copy within" in rtx2["actual"], rtx2


@pytest.mark.parametrize("seed", [1, 2])
def test_a_retry_limit_of_two_with_the_runners_threads_stalled(seed):
    """The runner's threads left off the CPU at random (up to half an --rto): late, never wrong."""
    run = run_manager_cases("give-up-after-three", seed=seed, challenge=1 + seed, stalls=(0.05, 0.1), **SHORT)
    assert run.rc == 0 and not _bad(run), run.explain()


@pytest.mark.parametrize("challenge", [2, 3])  # 1: test_manager_sim's controls
def test_a_pause_mid_mission_past_the_idle_window_is_waited_for(challenge):
    run = run_manager_cases("pauses-mid-mission", seed=challenge, challenge=challenge, **SHORT)
    assert run.rc == 0 and not _bad(run), run.explain()
    assert all(m.pauses for m in run.managers)  # it paused, past the idle window
    assert PausesMidMission.HOLD > max(2.5 * SHORT["rto"], 2 * SHORT["ack_window"], 1.0)
    assert run.missions["main"].ended_by == "end_mission"
    assert {r: run.rules[r] for r in ("MCP-FLOW-3", FLOW[challenge], "MCP-BLK-6")} == dict.fromkeys(
        ("MCP-FLOW-3", FLOW[challenge], "MCP-BLK-6"), "passed"), run.explain()


def test_a_manager_stalled_mid_mission_still_fails_at_the_cap():
    """Alive, quiet for ever where the pausing one pauses: MCP-FLOW-3 and FLOW-5 fail as they did
    at the idle window, the record ended at its cap (virtual time: no wall time)."""
    rng = random.Random(1)

    def stalled(drones, challenge, items, now):
        return StallsMidMission(drones, challenge, items, SHORT["rto"], 12, random.Random(rng.getrandbits(64)))

    run = run_manager_cases(stalled, seed=3, challenge=2, **SHORT)
    assert run.rc == 1 and _bad(run) == {"MCP-FLOW-3", "MCP-FLOW-5"}, run.explain()
    assert run.missions["main"].ended_by == "cap"
    assert "(the mission record ended: cap," in _case(run, "MCP-FLOW-3")["actual"]

"""The sample node's mutants (tests/conformance/test_mutants.py) as drone models in the simulator
(sim.mutants, issue 38 item 4): the runner's cases and its trace monitor, on virtual time, catch
each with its rule (failed for a MUST, warned for a SHOULD) and nothing else fails or warns --
test_mutants' property, without a process, a socket or a real timer."""

from __future__ import annotations

import pytest

from mcp_conform.sim.mutants import MUTANTS, NEEDS_VEHICLE, mutant_factory
from mcp_conform.sim.runner import run_cases
from mcp_conform.spec import RULES

SHORT = {"rto": 0.2, "ack_window": 0.25}


def _expected(mutant: str) -> dict[str, str]:
    rule = MUTANTS[mutant]
    return {rule: "failed" if RULES[rule].level == "MUST" else "warned"}


def test_every_mutant_of_the_real_matrix_is_here_or_needs_the_vehicle():
    from tests.conformance.test_mutants import MUTANTS as REAL

    assert {m: r for m, r in REAL if m not in NEEDS_VEHICLE} == MUTANTS
    assert {m for m, _ in REAL} >= set(NEEDS_VEHICLE)


@pytest.mark.parametrize("mutant", sorted(MUTANTS))
def test_each_mutant_is_caught_with_its_rule_and_nothing_else(mutant):
    run = run_cases(mutant_factory(mutant, rto=SHORT["rto"], seed=7), seed=7, **SHORT)
    assert run.rules_with("failed", "warned") == _expected(mutant), run.explain()
    assert not [c for c in run.report["cases"] if c["outcome"] == "error"
                and not run.rules_with("failed", "warned").keys() & set(c["rules"])], run.explain()


@pytest.mark.parametrize("mutant", ["bad-preamble", "ack-zero", "slow-ack", "rtx-new-seq", "source-port-filter"])
def test_mutants_at_the_descriptions_timings(mutant):
    """MCP_MUTANTS_TIMING=real's matrix (node --rto 5, the runner's defaults), which takes 30-130 s
    a run on real timers: here the waits are virtual."""
    run = run_cases(mutant_factory(mutant, rto=5.0, seed=8), seed=8, rto=5.0, ack_window=2.0)
    assert run.rules_with("failed", "warned") == _expected(mutant), run.explain()


def _schedule_folded() -> list[str]:
    """The mutants whose serial and scheduled runs test_schedule_verdicts folds into the real
    matrix (the real runs of those moved here: test_mutants.SIM_COVERS)."""
    from tests.conformance.test_mutants import SIM_COVERS
    from tests.conformance.test_schedule_verdicts import FOLDED

    return sorted(a[1] for a in FOLDED if len(a) > 1 and a[0] == "--fault" and a[1] in SIM_COVERS)


@pytest.mark.parametrize("mutant", _schedule_folded())
def test_a_mutants_verdicts_do_not_depend_on_the_schedule(mutant):
    """test_schedule_verdicts' property (issue 23) for the mutants whose real runs moved here: the
    default schedule (the batch's cases in threads on the virtual clock) gives every case the
    ``--serial`` run's outcome, and both catch the mutant with its rule and nothing else."""
    runs = [run_cases(mutant_factory(mutant, rto=SHORT["rto"], seed=9), seed=9, serial=serial, **SHORT)
            for serial in (True, False)]
    outcomes = [{c["id"]: c["outcome"] for c in r.report["cases"]} for r in runs]
    assert outcomes[0] == outcomes[1], (runs[0].explain(), runs[1].explain())
    for r in runs:
        assert r.rules_with("failed", "warned") == _expected(mutant), r.explain()

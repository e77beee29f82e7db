"""The sample node's mutants (tests/conformance/test_mutants.py) as drone models in the simulator
(sim.mutants, issue 38 item 4): the runner's cases and its trace monitor, on virtual time, catch
each with its rule (failed for a MUST, warned for a SHOULD) and nothing else fails or warns --
test_mutants' property, without a process, a socket or a real timer. Every mutant runs with the
runner's vehicle (``mavlink=True``: sim.vehicle), as test_mutants runs each with ``--mavlink``;
those observed on the vehicle's link (``NEEDS_VEHICLE``) need it.

For the mutants whose real runs moved here (test_mutants.SIM_COVERS) the checks those runs made
are made here too: the report's diagnosis (test_mutants.DIAGNOSIS, in the JSON report's case texts and
evidence, where the real run reads the terminal's), a case's expected and actual (CASE_SAYS), the trace
monitor's violations (MONITOR_SEES), and the live monitor against ``mcp-capture check``'s
judgement of the run's capture."""

from __future__ import annotations

from pathlib import Path

import pytest

from mcp_conform.sim.mutants import MUTANTS, NEEDS_VEHICLE, mutant_factory
from mcp_conform.sim.runner import run_cases
from mcp_conform.spec import RULES

SHORT = {"rto": 0.2, "ack_window": 0.25}


def _expected(mutant: str) -> dict[str, str]:
    rule = MUTANTS[mutant]
    return {rule: "failed" if RULES[rule].level == "MUST" else "warned"}


def _run(mutant: str, seed: int, rto: float = SHORT["rto"], **kwargs):
    """``mutant``'s run at ``rto`` (the node's and the runner's), with the vehicle."""
    kwargs.setdefault("ack_window", SHORT["ack_window"] if rto == SHORT["rto"] else 2.0)
    return run_cases(mutant_factory(mutant, rto=rto, seed=seed), seed=seed, rto=rto, mavlink=True, **kwargs)


def test_every_mutant_of_the_real_matrix_is_here():
    from tests.conformance.test_mutants import MUTANTS as REAL

    assert dict(REAL) == MUTANTS
    assert set(MUTANTS) >= set(NEEDS_VEHICLE)


@pytest.mark.parametrize("mutant", ["bad-preamble", "ack-zero", "slow-ack", "rtx-new-seq", "source-port-filter",
                                    "dup-ignores-src", "arm-before-start", "no-rtl", "passthrough-corrupt"])
def test_mutants_at_the_descriptions_timings(mutant):
    """MCP_MUTANTS_TIMING=real's matrix (node --rto 5, the runner's defaults), which takes 30-130 s
    a run on real timers: here the waits are virtual."""
    run = _run(mutant, 8, rto=5.0)
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
    runs = [_run(mutant, 9, serial=serial) for serial in (True, False)]
    outcomes = [{c["id"]: c["outcome"] for c in r.report["cases"]} for r in runs]
    assert outcomes[0] == outcomes[1], (runs[0].explain(), runs[1].explain())
    for r in runs:
        _caught(r, mutant)


def _moved_with_checks() -> list[str]:
    from tests.conformance.test_mutants import CASE_SAYS, DIAGNOSIS, MONITOR_SEES, SIM_COVERS

    return sorted(SIM_COVERS & (set(DIAGNOSIS) | set(CASE_SAYS) | set(MONITOR_SEES) | set(NEEDS_VEHICLE)))


def _caught(run, mutant: str) -> None:
    """The mutant's rule fails (warns, for a SHOULD) and nothing else does; no case errs but
    one of that rule."""
    assert run.rules_with("failed", "warned") == _expected(mutant), run.explain()
    assert not [c for c in run.report["cases"] if c["outcome"] == "error"
                and not run.rules_with("failed", "warned").keys() & set(c["rules"])], run.explain()


def _caught_elsewhere() -> set[str]:
    """The mutants whose whole-suite runs below (test_a_mutants_verdicts_do_not_depend_on_the_schedule's
    two, test_a_moved_mutants_report_monitor_and_capture's one) check :func:`_caught` already, on
    the same clean link at another seed: a third run of theirs here proved nothing more (issue
    38: 22 of the 41 suite runs, ~9 of the tier's CPU s)."""
    return set(_schedule_folded()) | set(_moved_with_checks())


def _caught_here() -> list[str]:
    return sorted(set(MUTANTS) - _caught_elsewhere())


@pytest.mark.parametrize("mutant", _caught_here())
def test_each_mutant_is_caught_with_its_rule_and_nothing_else(mutant):
    """Each mutant by one test or another (:func:`_caught_elsewhere`): its rule and nothing else."""
    _caught(_run(mutant, 7), mutant)


def test_every_mutant_is_caught_by_one_test_or_another():
    assert set(_caught_here()) | _caught_elsewhere() == set(MUTANTS)
    assert _caught_elsewhere() <= set(MUTANTS)


@pytest.mark.parametrize("mutant", _moved_with_checks())
def test_a_moved_mutants_report_monitor_and_capture(mutant, tmp_path: Path):
    """What test_mutant_is_caught_with_its_rule checks of a real run, on this one: the diagnosis
    in the report, the case's expected and actual, the monitor's violations of the mutant's rule
    alone, and the live monitor's verdicts and violations equal to the capture's judgement
    (``same_verdicts_offline``, by default and ``--complete``)."""
    from tests.conformance.test_mutants import (
        CASE_SAYS,
        DIAGNOSIS,
        MONITOR_SEES,
        same_verdicts_offline,
    )

    capture = tmp_path / "run.mcap"
    run = _run(mutant, 10, extra=("--capture", str(capture)))
    rule = MUTANTS[mutant]
    _caught(run, mutant)
    if mutant in DIAGNOSIS:
        says = DIAGNOSIS[mutant]
        texts = [f"{c.get('expected')} {c.get('actual')} {c.get('reason')} {c.get('evidence')}"
                 for c in run.report["cases"]]
        assert any(w in t for t in texts for w in ((says,) if isinstance(says, str) else says)), run.explain()
    if mutant in CASE_SAYS:
        (case,) = [c for c in run.report["cases"] if rule in c["rules"]]
        assert CASE_SAYS[mutant][0] in case["expected"] and CASE_SAYS[mutant][1] in case["actual"], case
    if mutant in MONITOR_SEES:
        mon = run.report["monitor"]
        assert {(v["rule"], v["node"]) for v in mon["violations"]} == {(rule, 1)}, mon["violations"]
    same_verdicts_offline(run, capture)


@pytest.mark.parametrize("seed", [25, 31, 36])
def test_dup_ignores_src_is_found_through_the_runners_impaired_link(seed):
    """``--impair`` retries a case whose attempt the link spoiled; MCP-DUP-3's second attempt set
    the other src's numbers afresh, so it repeated that src's own seqs of the first, a node
    with one window for every src discarded them as duplicates of its own, and the case was
    skipped as "the node does not accept commands from src 2" (3 of these 15 seeds, 25-39,
    found it before; all 15 since). The reference drone passes it on the same links."""
    imp = ("--impair", f"loss=0.1,dup=0.05,reorder=0.1,seed={seed}")
    run = _run("dup-ignores-src", seed, extra=imp, select=("DUP",))
    assert run.rules_with("failed", "warned") == _expected("dup-ignores-src"), run.explain()
    ref = run_cases(None, seed=seed, rto=SHORT["rto"], ack_window=SHORT["ack_window"], mavlink=True, extra=imp,
                    select=("DUP",))
    assert ref.rules_with("failed", "warned") == {}, ref.explain()
    assert [c["outcome"] for c in ref.report["cases"] if "MCP-DUP-3" in c["rules"]] == ["passed"], ref.explain()


@pytest.mark.parametrize("mutant", ["ack-previous-seq", "ack-zero"])
@pytest.mark.parametrize("seed", [41, 42])
def test_a_wrong_ack_payload_is_found_through_the_runners_impaired_link(mutant, seed):
    """Through ``--impair`` these passed MCP-ACK-2 (or skipped it): their wrong ACKs were
    explained as late answers of commands the link had made look open -- a copy it dropped
    on the way out (owed no reply: ``Attributor.on_wire``), an ACK it dropped on the way in
    (an answer all the same: ``Driver._lost``) -- or a passed attempt judged only the ACK of a
    copy the link duplicated, leaving the others unjudged (now repeated, as a spoiled failure
    is: ``conformance._impaired``)."""
    imp = ("--impair", f"loss=0.1,dup=0.05,reorder=0.1,seed={seed}")
    run = _run(mutant, seed, extra=imp, select=("ACK",))
    assert run.rules_with("failed", "warned") == _expected(mutant), run.explain()


#: test_impair_conform.SPEC: the runner's link (``--impair``) of its end-to-end runs
IMPAIR = "loss=0.1,dup=0.05,reorder=0.1"


@pytest.mark.parametrize("seed", [2, 3, 4, 5])
def test_the_reference_drone_through_the_runners_impaired_link_has_no_failure(seed):
    """test_impair_conform's embedded reference drone at the runner's defaults (--rto 5,
    --ack-window 2, the vehicle on) through ``--impair SPEC,seed=N``: seeds 2-5 moved here (seed 1
    stays real there). No case failed, warned or in error, exit 0; the monitor told the link is
    lossy (not complete); the report names the impairment."""
    spec = f"{IMPAIR},seed={seed}"
    run = run_cases(None, seed=seed, rto=5.0, ack_window=2.0, mavlink=True, extra=("--impair", spec))
    assert run.rc == 0, run.explain()
    assert not [c for c in run.report["cases"] if c["outcome"] in ("failed", "warned", "error")], run.explain()
    assert run.report["monitor"]["complete"] is False
    assert run.report["parameters"]["impair"] == spec


@pytest.mark.parametrize("mutant", ["no-dup-discard", "ack-broadcast"])
def test_a_mutant_fails_the_same_rule_through_the_runners_impaired_link(mutant):
    """test_impair_conform's faulty nodes (issue 22 item 3) through ``--impair SPEC,seed=11``:
    the rule each fails on a clean link (test_each_mutant_is_caught_with_its_rule_and_nothing_else)
    failed, nothing else failed or warned. The real runs: there (ack-broadcast through the link)
    and test_mutants (ack-broadcast clean)."""
    run = _run(mutant, 11, extra=("--impair", f"{IMPAIR},seed=11"))
    assert run.rules_with("failed") == {MUTANTS[mutant]: "failed"}, run.explain()
    assert not run.rules_with("warned"), run.explain()

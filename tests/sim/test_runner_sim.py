"""The runner's own drone cases in the simulator (sim.runner, issue 38 item 2): the conformance
suite and its trace monitor against node models on a virtual clock, through the runner's link.

Correct: the reference drone model passes every case it can be judged by (the vehicle's cases
are skipped: these runs have no ``--mavlink``; with it: test_runner_vehicle_sim.py) at the short
timings and at the description's 5 s ones (which cost no wall time here), with nothing failed or
warned by the monitor either.
Faulty: each drone fault of sim.faults fails its rule and no other rule.
"""

from __future__ import annotations

import pytest

from mcp_conform.sim.faults import FAULTS
from mcp_conform.sim.runner import run_cases

SHORT = {"rto": 0.2, "ack_window": 0.25}
DESCRIPTION = {"rto": 5.0, "ack_window": 2.0}  # the runner's defaults, the description's timeout
#: the cases observed on the vehicle's link (these runs have no vehicle)
VEHICLE_RULES = {"MCP-BLK-4", "MCP-BLK-5", "MCP-BLK-7", "MCP-DUP-1", "MCP-DUP-2", "MCP-DUP-3",
                 "MCP-DUP-4", "MCP-PAY-8", "MCP-SEQ-3"}
#: judged by a case against the reference drone, without a vehicle
JUDGED = {"MCP-HDR-1", "MCP-HDR-2", "MCP-HDR-3", "MCP-HDR-4", "MCP-HDR-5", "MCP-ACK-1", "MCP-ACK-2",
          "MCP-ACK-3", "MCP-ACK-4", "MCP-ACK-5", "MCP-ACK-6", "MCP-ACK-7", "MCP-SEQ-2", "MCP-RTX-1",
          "MCP-RTX-2", "MCP-RTX-3", "MCP-ROB-2", "MCP-ROB-3", "MCP-ROB-4", "MCP-ROB-5", "MCP-ROB-6",
          "MCP-ROB-7", "MCP-FLOW-1", "MCP-TRN-2", "MCP-BLK-1", "MCP-PAY-2"}


def _bad(run):
    return {c["id"]: c["outcome"] for c in run.report["cases"] if c["outcome"] in ("failed", "warned", "error")}


@pytest.mark.parametrize("timing", [SHORT, DESCRIPTION], ids=["short", "description-5s"])
def test_the_reference_drone_passes_every_case(timing):
    run = run_cases(None, seed=1, **timing)
    assert run.rc == 0, run.explain()
    assert not _bad(run), run.explain()
    assert not run.rules_with("failed", "warned"), run.explain()  # the monitor's included
    passed = {r for r, o in run.rules.items() if o == "passed"}
    assert JUDGED <= passed, sorted(JUDGED - passed)
    skipped = [c for c in run.report["cases"] if c["outcome"] == "skipped"]
    assert all("no simulated vehicle" in c["reason"] or "not observable on a drone" in c["reason"]
               for c in skipped), [c["reason"] for c in skipped]
    assert run.models == 1  # never restarted
    if timing is DESCRIPTION:
        assert run.virtual_s > 30.0  # the waits of a 5 s timeout, on the virtual clock


DRONE_FAULTS = sorted(name for name, f in FAULTS.items() if f.role == "drone")
#: faults the runner cannot observe without the vehicle (docs/spec.md: on the autopilot link)
UNOBSERVED = {"no-dup-discard": "MCP-DUP-1 is observed on the vehicle link (test_runner_vehicle_sim)"}


@pytest.mark.parametrize("fault", DRONE_FAULTS)
def test_each_drone_fault_fails_its_rule_and_no_other(fault):
    rule = FAULTS[fault].rule
    run = run_cases(fault, seed=2, **SHORT)
    failed = run.rules_with("failed", "warned")
    if fault in UNOBSERVED or rule is None:  # ack-twice breaks no rule (D-9): no verdict
        assert not failed, run.explain()
        return
    assert failed == {rule: "failed"}, run.explain()


@pytest.mark.parametrize("fault", ["rtx-none", "rtx-stop-on-any-ack", "ack-first-copy-only"])
def test_faults_are_found_at_the_description_timings(fault):
    run = run_cases(fault, seed=3, **DESCRIPTION)
    assert run.rules_with("failed", "warned") == {FAULTS[fault].rule: "failed"}, run.explain()


def test_a_seed_gives_the_same_run():
    """The virtual clock and the seeded link make a run a function of its seed: the same
    cases' verdicts, the same monitor section, the same length in virtual time."""
    spec = "loss=0.1,dup=0.05,reorder=0.1,seed=4"
    a, b = (run_cases(None, seed=4, extra=("--impair", spec)) for _ in range(2))
    assert a.report["cases"] == b.report["cases"]
    assert a.report["monitor"] == b.report["monitor"]
    assert (a.virtual_s, a.switches) == (b.virtual_s, b.switches)


def test_the_runners_impaired_link_runs_on_the_virtual_clock():
    """``--impair`` (harness.impair_link: its timer thread on the session's clock): the correct
    drone gets no failed or warned verdict; an observation the link spoiled is skipped."""
    run = run_cases(None, seed=5, extra=("--impair", "loss=0.1,dup=0.05,reorder=0.1,seed=5"))
    assert not run.rules_with("failed", "warned"), run.explain()
    assert not [c for c in _bad(run).values() if c != "skipped"], run.explain()


@pytest.mark.parametrize("model", [None, "ack-previous-seq", "rtx-none", "ack-first-copy-only"])
def test_the_schedule_gives_the_serial_verdicts(model):
    """The default schedule (its batch's cases in threads of their own, on the virtual clock:
    conformance._batch) gives every case the ``--serial`` run's outcome (test_schedule_verdicts'
    property, issue 23), kept batch or thrown away."""
    serial = run_cases(model, seed=6, **SHORT)
    scheduled = run_cases(model, seed=6, serial=False, **SHORT)
    assert scheduled.cases() == serial.cases(), scheduled.explain()
    assert scheduled.rules == serial.rules
    if model is None:
        assert scheduled.virtual_s < serial.virtual_s  # the batch's windows were watched once


def test_a_copy_delayed_by_the_runners_link_never_reaches_the_next_node():
    """Found by a sweep of --impair schedules over the reference drone: an End_Mission copy the
    runner's link held 0.16 s past the restart before MCP-BLK-7's case reached the fresh node,
    which ended its mission before Start_Mission (an error: 'the node exited with code 0 after
    Start_Mission'). The session drops what the link holds as it replaces the node."""
    spec = "loss=0.2,dup=0.05,reorder=0.1,delay=0-250ms,seed=986724"
    run = run_cases(None, seed=986724, extra=("--impair", spec))
    assert run.rc == 0, run.explain()
    assert not _bad(run), run.explain()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_runners_own_threads_stalled(seed):
    """sim.stalls: the runner's receiver, case and watcher threads left off the CPU for up to
    0.3 s at one handoff in ten (a loaded host); a datagram keeps the time it reached the
    runner's socket (the kernel's receive time). The correct drone gets no failed or warned
    verdict, scheduled or serial; without the kernel's time, copies read late warned MCP-RTX-3."""
    for serial in (True, False):
        run = run_cases(None, seed=seed, serial=serial, stalls=(0.1, 0.3))
        assert not run.rules_with("failed", "warned"), run.explain()
        assert not _bad(run), run.explain()

"""The runner's own manager-role cases in the simulator (sim.manager_runner, issue 38 item 2):
the conformance suite of ``--role manager``, its drone players and its trace monitor against
manager models on a virtual clock.

Correct: the reference manager model gets no failed or warned verdict, from a case or the
monitor, at the short timings for every challenge and at the description's 5 s ones (which
cost no wall time here), serial and with the silent drone's scenario beside the main one --
and both schedules decide every case and every monitor verdict alike; the runner's own threads
stalled at random too; so do correct managers unlike ours. Faulty: each manager fault of
sim.manager_faults (the sample manager's list, and sim.faults' manager faults) fails its rule
and no other rule. A seed gives the same report.

What stays on real sockets and processes: tests/conformance/test_manager_role.py (its
docstring says which runs and why).
"""

from __future__ import annotations

import functools

import pytest

from mcp_conform.sim.manager_faults import MANAGER_FAULTS
from mcp_conform.sim.manager_runner import run_manager_cases
from mcp_conform.spec import SPEC

SHORT = {"rto": 0.2, "ack_window": 0.25}
DESCRIPTION = {"rto": 5.0, "ack_window": 2.0}  # the runner's defaults, the description's timeout
#: judged by a case against the reference manager at challenge 1 (the rest: other challenges,
#: or not observable on a manager: skipped or INFO, as in a real run)
JUDGED = {"MCP-HDR-1", "MCP-ACK-1", "MCP-ACK-2", "MCP-ACK-4", "MCP-ACK-5", "MCP-ACK-6", "MCP-SEQ-2",
          "MCP-RTX-1", "MCP-RTX-2", "MCP-RTX-3", "MCP-BLK-1", "MCP-BLK-2", "MCP-BLK-3", "MCP-BLK-6",
          "MCP-ROB-1", "MCP-ROB-2", "MCP-ROB-3", "MCP-ROB-4", "MCP-ROB-5", "MCP-ROB-6", "MCP-ROB-7",
          "MCP-FLOW-2", "MCP-FLOW-3", "MCP-FLOW-4", "MCP-TRN-2", "MCP-PAY-3"}
FLOW = {1: "MCP-FLOW-4", 2: "MCP-FLOW-5", 3: "MCP-FLOW-6"}


def _bad(run):
    return {c["id"]: c["outcome"] for c in run.report["cases"] if c["outcome"] in ("failed", "warned", "error")}


def _monitor(run) -> dict[str, str]:
    return dict(run.report["monitor"]["rules"].get("0", {}))


def _clean(run) -> None:
    """No failed, warned or error verdict: from a case, the run's rules or its monitor."""
    assert run.rc == 0, run.explain()
    assert not _bad(run), run.explain()
    assert not run.rules_with("failed", "warned"), run.explain()
    assert not {r: o for r, o in _monitor(run).items() if o in ("failed", "warned")}, run.report["monitor"]
    assert run.report["monitor"]["complete"], run.report["monitor"]


def _decided(run):
    return run.cases(), _monitor(run)


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_the_reference_manager_passes_serial_and_side_by_side(challenge):
    side = run_manager_cases(None, seed=challenge, challenge=challenge, **SHORT)
    serial = run_manager_cases(None, seed=challenge, challenge=challenge, serial=True, **SHORT)
    for run in (side, serial):
        _clean(run)
        assert run.rules[FLOW[challenge]] == "passed", run.explain()
        assert run.models == 2  # the main mission's manager and the silent drone's
    assert _decided(side) == _decided(serial)
    if challenge == 1:
        passed = {r for r, o in side.rules.items() if o == "passed"}
        assert JUDGED <= passed, sorted(JUDGED - passed)


@pytest.mark.parametrize("serial", [False, True], ids=["side-by-side", "serial"])
def test_the_reference_manager_passes_at_the_descriptions_5_s(serial):
    run = run_manager_cases(None, seed=5, challenge=2, serial=serial, **DESCRIPTION)
    _clean(run)
    assert run.rules["MCP-RTX-1"] == "passed" and run.rules["MCP-FLOW-5"] == "passed", run.explain()
    assert run.virtual_s > 30.0  # the waits of a 5 s timeout, on the virtual clock


#: seeds of runner-thread stalls up to 5 x --rto (p 0.2, 1 s) that gave the reference manager
#: false verdicts: a Start_Mission of the main mission read late into the silent drone's session
#: (MCP-BLK-2, SEQ-1), a mission cut short as "idle" while the receiver was behind (FLOW-2/3/4),
#: a copy after the wrong ACKs arrived in time and was read late (MCP-RTX-2); the runner's ACKs
#: of the withheld Start_Mission sent past the manager's retry limit (12): 107, the wrong ACKs
#: 1.8 s after its last copy, MCP-RTX-2 failed where nothing could be seen (now inconclusive),
#: 118, the right ACK after it gave the drone up, the wrong ones (which it retransmitted after)
#: taken for its answer, MCP-FLOW-3/5 failed on the drone it gave up (now excused)
STALL_SEEDS = [102, 107, 111, 118]


@pytest.mark.parametrize("seed", STALL_SEEDS)
def test_a_receiver_behind_is_waited_for_not_taken_for_silence(seed):
    run = run_manager_cases(None, seed=seed, challenge=1 + seed % 3, serial=bool(seed % 2), stalls=(0.2, 1.0),
                            **SHORT)
    _clean(run)


def test_the_reference_manager_passes_with_the_runners_threads_stalled():
    """The runner's receiver, drone players and case thread left off the CPU at random (up to
    half an --rto, issue 38 item 2's "stall any party"): late, never wrong."""
    for seed in (1, 2):
        run = run_manager_cases(None, seed=seed, challenge=1 + seed, stalls=(0.05, 0.1), **SHORT)
        _clean(run)


#: the monitor misses it: a manager's command sent once, its ACK withheld, never sent again --
#: the issue's capture (its second verdict); the case proves it (judge/, not the simulator)
MONITOR_MISSES = {"manager-rtx-none"}
FAULTY = sorted(name for name, f in MANAGER_FAULTS.items() if f.rule is not None)
CONTROLS = sorted(name for name, f in MANAGER_FAULTS.items() if f.rule is None)


@functools.cache  # a seed gives the same run: each fault's is run once per worker
def _fault_run(fault, serial=False):
    return run_manager_cases(fault, seed=2, challenge=MANAGER_FAULTS[fault].challenge, serial=serial, **SHORT)


@pytest.mark.parametrize("fault", FAULTY)
def test_each_manager_fault_fails_its_rule(fault):
    rule = MANAGER_FAULTS[fault].rule
    run = _fault_run(fault)
    want = "failed" if SPEC.rule(rule).level == "MUST" else "warned"
    assert run.rules.get(rule) == want, run.explain()
    assert run.rc == 1, run.explain()
    assert "error" not in run.cases().values(), run.explain()
    if fault not in MONITOR_MISSES:
        assert _monitor(run).get(rule) == want, run.report["monitor"]
    assert _decided(_fault_run(fault, serial=True)) == _decided(run)  # serial and side by side alike


def test_a_manager_that_never_acks_mission_ready_is_judged_on_what_it_did():
    """no-ready-ack goes on with the mission without ACKing: MCP-ACK-1's evidence names the
    Mission_Ready (seq, copies, no ACK) and what the manager sent meanwhile; the cases whose
    inputs need an ACKed Mission_Ready are skipped with the reason; the rest is judged."""
    run = _fault_run("no-ready-ack")
    case = next(c for c in run.report["cases"] if c["id"].endswith("test_every_mission_ready_is_acked"))
    ev = "\n".join(case["evidence"])
    assert "Mission_Ready of drone 1: seq" in ev and "copies, no ACK" in ev, case
    assert "went on with the mission" in ev and "START_MISSION to 1" in ev, case
    rob = next(c for c in run.report["cases"] if "MCP-ROB-2" in c["rules"])
    assert rob["outcome"] == "skipped" and "did not ACK drone 1's Mission_Ready" in rob["reason"], rob
    assert run.report.get("error") is None, run.explain()
    assert run.rules["MCP-FLOW-4"] == "passed" and run.rules["MCP-RTX-1"] == "passed", run.explain()


@pytest.mark.parametrize("fault", FAULTY)
def test_each_manager_fault_fails_no_other_rule(fault):
    """rtx-new-seq too: its WP_List to the silent drone, again under a new number while
    unACKed, is MCP-SEQ-2's and not also "a second WP_List" (MCP-FLOW-4: the monitor took it
    for both; the sample manager's rtx-new-seq never showed it, dying at its first list
    retransmission)."""
    rule = MANAGER_FAULTS[fault].rule
    run = _fault_run(fault)
    assert set(run.rules_with("failed", "warned")) == {rule}, run.explain()
    assert set(r for r, o in _monitor(run).items() if o in ("failed", "warned")) <= {rule}, run.report["monitor"]


@pytest.mark.parametrize("control", CONTROLS)
def test_a_correct_manager_unlike_ours_gets_no_verdict(control):
    """give-up-never (retries without limit: a configurable limit), acks-copies-late (a copy
    ACKed again 0.3 s late, past the 0.2 s --rto), give-up-after-three (a retry limit of 2:
    tests/sim/test_manager_limit_sim.py), pauses-mid-mission (quiet past the idle window),
    serial and side by side."""
    for serial in (False, True):
        run = run_manager_cases(control, seed=3, serial=serial, **SHORT)
        _clean(run)
    if control == "acks-copies-late":
        assert sum(m.late_acks for m in run.managers) >= 1  # the late ACK was made


@pytest.mark.xfail(reason="issue 38 item 7: the monitor does not prove MCP-RTX-1 of a command sent once, "
                          "its ACK withheld and never sent again (the case does): a lone copy's next one is "
                          "not due before 1.5 x the description's 5 s (judge/_monitor_rtx.py, issue 18 item 10), "
                          "and the case's withholding ends after 1.9 s at --rto 0.2; judging a lone copy by "
                          "--rto needs the run to declare it to its monitors and its capture (harness/"
                          "manager_session.py's SessionMonitors, judge/run_monitor.py, judge/judging.py), "
                          "which no other consumer does", strict=True)
def test_the_monitor_proves_a_manager_that_never_retransmits():
    run = run_manager_cases("manager-rtx-none", seed=2, **SHORT)
    assert _monitor(run).get("MCP-RTX-1") == "failed", run.report["monitor"]


def test_a_seed_gives_the_same_report():
    a, b = (run_manager_cases(None, seed=4, challenge=2, **SHORT) for _ in range(2))
    for run in (a, b):
        run.report["summary"].pop("duration_s")  # the wall time the computation took
    assert a.report == b.report
    assert (a.virtual_s, a.switches) == (b.virtual_s, b.switches)


def test_a_fault_of_another_role_is_refused():
    with pytest.raises(ValueError, match="not a manager fault"):
        run_manager_cases("no-ack")

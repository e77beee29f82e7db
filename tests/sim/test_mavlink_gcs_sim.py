"""The MAVLink gcs role in the simulator (sim.gcs_role, issue 38 item 4): the whole
``mcp-conform --protocol mavlink --role gcs`` suite, its session, its runner's vehicle and its
trace monitor, against the reference ground station's own code (sim.gcs) on a virtual clock --
the matrix that ran on real processes and timers (60-75 s a run) until now.

Correct: the reference GCS passes every case over every transport the runner offers (tcp,
udp/udpin, udpout); with the runner's threads stalled (the ground station's are spared: its
lateness is its own), through a lossy, duplicating, reordering, delaying TCP link (a stream:
bytes late, in order) or a delaying UDP one, it gets no failed or warned verdict, and a case
it cannot observe there is skipped with its reason. Faulty: each fault of sim.gcs_faults (the
classes tests/mavlink/faulty_gcs.py runs as processes) fails, or warns for a SHOULD, exactly
its rule and no other, over the whole suite, also on a lossy link with stalls. The live
monitor judges as ``mcp-capture check`` of the run's capture does. A seed gives the same run.

What stays on real sockets: tests/mavlink/test_conform_gcs.py (its docstring says which runs and
why), whose reference and fault runs must give the simulator's verdicts case by case.
"""

from __future__ import annotations

import contextlib
import inspect
import io
import json
import re

import pytest

from mcp_conform.reference_impl import mavlink_gcs
from mcp_conform.sim.gcs import GcsProcess, SimGcsSeam
from mcp_conform.sim.gcs_faults import BROKEN, FAULTS, RULES, Fault
from mcp_conform.sim.gcs_role import run_gcs_cases
from mcp_conform.spec import RULES as SPEC_RULES
from tests.sim.shared_runs import gcs_run

#: a lossy TCP link: what the impairment loses TCP sends again, what it duplicates TCP discards
LOSSY = "loss=0.1,dup=0.05,reorder=0.1,delay=0-50ms"
#: what a case may say when it cannot observe its rule on a late runner (its threads stalled,
#: its link lossy): the runner's vehicle, its ticker stalled past the ground station's 1.5 s
#: resend, re-requests the item it dropped only after the ground station sent it again of its
#: own accord; a runner that read nothing for 2 s took the ground station as done before its
#: work; a PARAM_VALUE the runner sent after the PARAM_SET came, or one answering a request it
#: read late or sent just before the ground station's last request for it came (the next then
#: reaching the ground station after its PARAM_SET), answered it for the ground station; a
#: parameter list sent late, after the ground station moved on
LATE_SKIPS = ("the upload ended before the vehicle requested item 1 again", "(it never exercised the rule)",
              "went out after the PARAM_SET came", "answered a request the runner read late",
              "may have crossed that request", "the runner sent the list late")


def failed(doc: dict) -> tuple[set[str], set[str]]:
    """The failed, warned or errored rules, and the cases that did not pass (nor skip)."""
    rules = {r for r, o in doc["rules"].items() if o in ("failed", "warned", "error")}
    cases = {c["id"] for c in doc["cases"] if c["outcome"] not in ("passed", "skipped")}
    return rules, cases


def skipped(doc: dict) -> dict[str, str]:
    return {c["id"]: c["reason"] for c in doc["cases"] if c["outcome"] == "skipped"}


def monitor_failures(doc: dict) -> set[str]:
    return {f["rule"] for f in doc["failures"] if f.get("source") == "monitor"}


def expect_reference(run, late: bool = False) -> None:
    """Nothing failed or warned, by the cases or the monitor; no case skipped (``late``: only
    for a reason of :data:`LATE_SKIPS`, and most cases judged)."""
    doc, out = run.report, run.explain()
    assert run.rc == 0 and failed(doc) == (set(), set()), out
    assert not monitor_failures(doc), doc["failures"]
    skips = skipped(doc)
    allowed = LATE_SKIPS if late else ()
    assert all(any(why in reason for why in allowed) for reason in skips.values()), skips
    assert len(doc["cases"]) - len(skips) >= 20, skips


def test_the_fault_tables_agree():
    """Every fault the models have is judged here with its rule (a rule of the gcs role), read
    from the fault's own declaration (``Fault.breaks``); what a fault breaks besides by its
    nature is a SHOULD (warned: the run still exits 0 on a SHOULD fault)."""
    assert set(FAULTS) == {"none", *RULES} == {"none", *BROKEN}
    assert all(issubclass(c, Fault) for n, c in FAULTS.items() if n != "none")
    assert all(SPEC_RULES[r].level in ("MUST", "SHOULD") for r in RULES.values())
    for fault, cls in FAULTS.items():
        if issubclass(cls, Fault):
            assert all(SPEC_RULES[r].level == "SHOULD" for r in cls.breaks.also), (fault, cls.breaks)


def test_the_seams_run_the_references_code():
    """sim.gcs runs ``ReferenceGcs``'s own methods, its clock the seam (``ReferenceGcs.now``),
    none restated; its ``main`` runs the reference's steps in the reference's order."""
    own = {n for n, v in vars(SimGcsSeam).items() if callable(v) and not n.startswith("__")}
    assert own <= {"now"}, own
    steps = re.compile(r"gcs\.(\w+)\(")
    ref_steps = [s for s in steps.findall(inspect.getsource(mavlink_gcs.main)) if s != "close"]
    assert [s for s in steps.findall(inspect.getsource(GcsProcess._main)) if s != "close"] == ref_steps


@pytest.mark.parametrize("transport", ["tcp", "udp", "udpin", "udpout"])
def test_the_reference_gcs_passes_every_case(transport):
    run = gcs_run(None, 1, transport)  # over TCP, test_report_schema's too (tests/sim/shared_runs.py)
    expect_reference(run)
    doc = run.report
    assert doc["role"] == "gcs" and doc["spec"]["protocol"] == "MAV"
    assert {c["outcome"] for c in doc["cases"]} == {"passed"} and len(doc["cases"]) >= 28, run.explain()
    assert 30 < run.virtual_s < 300 and run.models >= 10, (run.virtual_s, run.models)  # a ground station a behaviour


@pytest.mark.parametrize("fault", sorted(RULES))
def test_each_faulty_gcs_fails_its_rule_and_no_other(fault):
    """The whole suite against the ground station with the fault: its rule and nothing else
    fails (warned, for a SHOULD: exit 0), the case naming it with what was expected and seen;
    the monitor fails nothing but that rule."""
    run = gcs_run(fault, 2)  # some test_report_schema's too
    rule = RULES[fault]
    rules, cases = failed(run.report)
    assert rules == BROKEN[fault], run.explain()
    assert run.rc == (0 if SPEC_RULES[rule].level == "SHOULD" else 1), run.explain()
    assert monitor_failures(run.report) <= {rule}, run.report["failures"]
    case = next(c for c in run.report["cases"] if c["id"] in cases)
    assert case["failed_rule"] == rule and case["expected"] and case["actual"], case


@pytest.mark.parametrize(("seed", "stalls"), [(3, (0.1, 0.3)), (11, (0.2, 0.5)), (10, (0.1, 1.0)), (12, (0.1, 1.0))])
def test_the_reference_gcs_with_the_runners_threads_stalled(seed, stalls):
    """sim.stalls: the runner's threads (its vehicle's ticker, its link's reader, its cases)
    left off the CPU for up to ``max_s`` at a handoff in ``1/p``: late, never a false verdict."""
    run = run_gcs_cases(None, seed=seed, stalls=stalls)
    expect_reference(run, late=True)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_the_reference_gcs_through_a_lossy_tcp_link(seed):
    expect_reference(run_gcs_cases(None, seed=seed, link=LOSSY), late=True)


@pytest.mark.parametrize("seed", [0, 3, 12, 14, 22, 23, 31, 34, 39])
def test_the_reference_gcs_through_a_lossy_tcp_link_with_the_runners_threads_stalled(seed):
    """Both at once, the runner late by up to 1 s (past the reference's own 1 s and 1.5 s
    timeouts with a lost segment's 0.2 s): each seed a false verdict on the reference before
    the cases read a request's answer as one (MAV-MIS-20, MAV-MIS-24: an item that answers the
    vehicle's re-request of it, both read by the ground station before its answer, came after a
    later request -- seed 39 -- or after the error MISSION_ACK -- seeds 12, 31 -- ``_owed``),
    waited for the answer to the vehicle's re-request past the ground station's settling (22),
    and took a PARAM_VALUE the runner sent after the PARAM_SET came as a possible answer to it
    (MAV-PRM-16, 14). Seeds 0 and 23 (3 and 34 as the reference runs since it goes on after
    an INVALID_SEQUENCE NACK) warned MAV-PRM-16 and MAV-PRM-14 on it before ``_answered_late``
    (cases_mavlink_gcs/test_prm.py): the runner read the PARAM_REQUEST_LIST from a backlog, a
    later frame of the ground station with it, and sent the list after the ground station had
    given up on it -- the list's entry then answered its read by name, the read's answer its
    PARAM_SET (0, 3), or its gaps were never seen (23, 34)."""
    expect_reference(run_gcs_cases(None, seed=seed, link=LOSSY, stalls=(0.1, 1.0)), late=True)


def test_an_invalid_sequence_nack_leaves_the_reference_uploading():
    """ArduPilot's MAV_MISSION_INVALID_SEQUENCE (the runner's vehicle's answer to a late copy of
    an item, E-1) does not end the reference's upload: it answers the vehicle's next requests,
    and the vehicle serves the download after it (seed 12: the reference ended the upload on the
    NACK, the vehicle stayed mid-upload and denied the download, MIS/test_download_handshake
    skipped: 'the runner's vehicle sent no MISSION_COUNT'). tests/mavlink/test_reference_gcs.py
    holds the upload itself to it."""
    run = run_gcs_cases(None, seed=12, link=LOSSY, stalls=(0.1, 1.0))
    expect_reference(run, late=True)
    outcome = {c["id"]: c["outcome"] for c in run.report["cases"]}
    assert outcome["MIS/test_download_handshake"] == "passed", skipped(run.report)


def test_a_resend_that_crossed_its_command_ack_is_no_new_command():
    """A COMMAND_LONG the ground station resent (confirmation 1) while its COMMAND_ACK was on
    the way is a resend, not a new command's first transmission: the monitor failed MAV-CMD-7
    on it once the ACK had answered the first (seed 6; judge/_mavlink_link.py's
    ``CommandService._numbering``, tests/judge/test_mavlink_command_crossing.py)."""
    run = run_gcs_cases(None, seed=6, link=LOSSY, stalls=(0.1, 1.0))
    expect_reference(run, late=True)
    assert run.report["monitor"]["rules"]["MAV-CMD-8"] == "passed", run.report["monitor"]["rules"]


@pytest.mark.parametrize(("transport", "seed"), [("udpout", 1), ("udp", 2)])
def test_the_reference_gcs_through_a_delaying_udp_link(transport, seed):
    """A fixed delay each way (a varying one reorders datagrams, which MAV-HB-11's count of
    sequence numbers reads as a ground station's, as it does on loopback)."""
    expect_reference(run_gcs_cases(None, seed=seed, transport=transport, link="delay=30ms"), late=True)


@pytest.mark.parametrize("fault", ["mavlink1-start", "items-out-of-order", "ignores-error-ack", "accepts-any-ack",
                                   "ignores-in-progress"])
def test_a_faulty_gcs_through_a_lossy_link_with_stalls(fault):
    """A fault is found with its rule, and no other, when the link is lossy and the runner late too."""
    run = run_gcs_cases(fault, seed=4, link=LOSSY, stalls=(0.05, 0.5))
    assert failed(run.report)[0] == {RULES[fault]}, run.explain()


def test_a_seed_gives_the_same_run():
    a, b = (run_gcs_cases("accepts-any-ack", seed=5, link=LOSSY, stalls=(0.05, 0.5)) for _ in range(2))
    assert a.report["cases"] == b.report["cases"]
    assert a.report["monitor"] == b.report["monitor"]
    assert (a.virtual_s, a.switches, a.models) == (b.virtual_s, b.switches, b.models)


def test_the_live_monitor_judges_as_the_capture_check_does(tmp_path):
    """Each case's run of the ground station is a session of the capture
    (``McapRecorder.begin_segment``), and ``mcp-capture check`` judges each party anew there --
    a new ground station numbers its frames from 0 and its first command has confirmation 0
    (judged as one session, the reference's capture failed MAV-HB-11 and warned MAV-CMD-8).
    The run's live monitor judges each run so too: every rule the verdict the check gives it."""
    from mcp_conform.captures.cli import main as capture_main
    from tests.mavlink.test_live_monitor import same_judgement

    capture, out = tmp_path / "run.mcap", tmp_path / "check.json"
    run = run_gcs_cases(None, seed=6, select=("MAV-CMD-6", "MAV-CMD-17", "MAV-HB-11"),
                        extra=("--capture", str(capture)))
    assert run.rc == 0, run.explain()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
        rc = capture_main(["check", "--protocol", "mavlink", str(capture), "--json", str(out)])
    judged = json.loads(out.read_text())
    assert rc == 0 and judged["verdict"] == "OK", judged
    assert judged["rules"]["MAV-HB-11"] == "passed" and judged["rules"]["MAV-CMD-7"] == "passed", judged["rules"]
    assert sorted(n["id"] for n in judged["nodes"]) == ["1/1", "255/190"], judged["nodes"]
    same_judgement(run.report["monitor"], judged)

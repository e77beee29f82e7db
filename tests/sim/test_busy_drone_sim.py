"""A busy drone judged as the correct node it is (issue 38; the C++ drone's report, s33-cppdrone):
its worker carries out commands one after another and waits out a take-off before the next
(``sim.busy``), so the Mav_Passthrough frames sent while it climbs reach the autopilot seconds
after their ACK, and End_Mission's RTL follows the climb. D-6 allows a busy node; MCP-BLK-7:
"On End_Mission the drone finishes pending actions, then commands RTL".

The runner's waits follow the vehicle (``VehicleModel.pending_action``: a take-off short of its
altitude): a delivery's window (``CaseContext.await_past_pending``) and MCP-BLK-7's run from the
end of the node's pending action, bounded by the case's limit. A node that never forwards, or
never commands RTL, keeps its verdict, and its skip or warning says how long the runner waited
and for what. On the old runner every test here failed: the first four on their verdicts (the
six passthrough cases skipped, "the node forwarded no Mav_Passthrough frame to its autopilot",
and MCP-BLK-7 warned, "no RTL within 3 s of End_Mission"), the last three on their reasons (the
same verdicts, saying neither how long the runner waited nor for what).
"""

from __future__ import annotations

import re

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mav

from mcp_conform.sim.busy import busy_drone_factory
from mcp_conform.sim.runner import run_cases
from tests.sim.test_runner_vehicle_sim import VEHICLE_CASES
from tests.vehicle.test_model import ACCEPTED, ack_of, armed_in_guided

#: (--rto, --ack-window, take-off altitude): the C++ drone's short timings with a 150 m climb
#: (7.5 s at the vehicle's 20 m/s; 1.6 s of busy time already lost the probes), and the
#: description's 5 s timings with an 800 m one (40 s: its startup phase outlasts a shorter climb)
SHORT = (0.3, 0.3, 150.0)
DESCRIPTION = (5.0, 2.0, 800.0)
PASSTHROUGH_CASES = [c for c in VEHICLE_CASES if c.startswith(("DUP/", "PAY/", "SEQ/"))]
BLK7 = "BLK/test_end_mission_then_rtl"


def _run(timing, *, serial=True, select=(), **model):
    rto, window, alt = timing
    return run_cases(busy_drone_factory(alt, rto=rto, seed=1, **model), seed=1, rto=rto, ack_window=window,
                     mavlink=True, serial=serial, select=select)


def _case(run, case_id):
    return next(c for c in run.report["cases"] if c["id"] == case_id)


@pytest.mark.parametrize(("timing", "serial"), [(SHORT, True), (SHORT, False), (DESCRIPTION, True)],
                         ids=["short-serial", "short-scheduled", "description-5s"])
def test_a_busy_drone_is_judged_as_a_correct_one(timing, serial):
    run = _run(timing, serial=serial)
    assert run.rc == 0, run.explain()
    assert not run.rules_with("failed", "warned"), run.explain()
    assert run.report["monitor"]["violations"] == [], run.report["monitor"]  # one judge
    cases = run.cases()
    assert {c: cases.get(c) for c in VEHICLE_CASES} == VEHICLE_CASES, run.explain()


def test_rtl_is_awaited_past_the_pending_take_off():
    """End_Mission right after Start_Mission (MCP-BLK-7 alone): the RTL comes some 7 s after
    it, once the climb is over; the note names the pending take-off."""
    run = _run(SHORT, select=(BLK7,))
    case = _case(run, BLK7)
    assert case["outcome"] == "passed", run.explain()
    note = " ".join(case["notes"])
    after = float(note.split(" s after End_Mission")[0])
    assert after > 3.0, note  # past the fixed window the old runner allowed
    assert "a take-off to 150 m" in note, note


def test_a_node_that_never_forwards_is_skipped_saying_how_long_it_waited():
    """Not busy (a 2 m climb, over before the first probe): the six cases skipped as before,
    after the window alone (2 x 0.3 s, at least 1 s), and the reason says so."""
    run = _run((0.3, 0.3, 2.0), forwards=False)
    assert run.rc == 0 and not run.rules_with("failed", "warned"), run.explain()
    for case_id in PASSTHROUGH_CASES:
        case = _case(run, case_id)
        assert case["outcome"] == "skipped", run.explain()
        m = re.search(r"forwarded no Mav_Passthrough frame to its autopilot within ([0-9.]+) s of the "
                      r"capability probe's ACK", case["reason"])
        assert m is not None, case["reason"]
        assert 1.0 <= float(m.group(1)) < 1.2, case["reason"]
        assert "busy" not in case["reason"], case["reason"]


def test_a_busy_node_that_never_forwards_is_skipped_naming_the_take_off():
    """Busy (the 150 m climb) and forwarding nothing: skipped, the wait bounded by the climb
    and the window after it (7.5 s + 1 s), the reason naming the take-off and that the node
    may have been busy."""
    run = _run(SHORT, forwards=False)
    assert run.rc == 0 and not run.rules_with("failed", "warned"), run.explain()
    reasons = {_case(run, c)["outcome"]: _case(run, c)["reason"] for c in PASSTHROUGH_CASES}
    assert list(reasons) == ["skipped"], reasons
    reason = reasons["skipped"]
    m = re.search(r"within ([0-9.]+) s of the capability probe's ACK", reason)
    assert m is not None and 1.0 < float(m.group(1)) <= 7.5 + 1.2, reason
    assert "a take-off to 150 m" in reason and "the node may have been busy" in reason, reason


def test_a_busy_node_that_never_commands_rtl_is_still_warned():
    """No RTL at all (the sample node's ``no-rtl``) behind the same climb: MCP-BLK-7 warned once
    the climb is over and the window after it has passed, saying so."""
    run = _run(SHORT, select=(BLK7,), rtl=False)
    case = _case(run, BLK7)
    assert case["outcome"] == "warned", run.explain()
    assert "of the end of the node's pending actions (a take-off to 150 m" in case["expected"], case
    waited = float(re.search(r"none in ([0-9.]+) s", case["actual"]).group(1))
    assert 3.0 + 5.0 < waited < 3.0 + 8.0, case["actual"]  # the climb's rest, then the 3 s window


def _monitor_blk7(run):
    mon = run.report["monitor"]
    return mon["rules"]["1"]["MCP-BLK-7"], [v for v in mon["violations"] if v["rule"] == "MCP-BLK-7"]


def test_the_monitor_waits_out_the_pending_take_off_as_the_case_does():
    """One judge (the JS drone's report, s34-jsdrone): the run's monitor, like the case, runs
    MCP-BLK-7's window from the end of the take-off the vehicle showed in progress when
    End_Mission was ACKed (its ``busy``/``idle`` events, recorded to the capture too). The old
    monitor warned "no RTL within 3.850 s of End_Mission's ACK" beside the case's pass."""
    run = _run(SHORT, select=(BLK7,))
    assert _case(run, BLK7)["outcome"] == "passed", run.explain()
    assert _monitor_blk7(run) == ("passed", []), run.report["monitor"]


def test_the_monitor_still_warns_a_busy_node_that_never_commands_rtl():
    """No RTL behind the same climb: the monitor warns once the climb is over and the window
    after it has passed (the climb's rest, some 5-7.5 s, seen at the vehicle's next tick, then 3 s), as the case
    does."""
    run = _run(SHORT, select=(BLK7,), rtl=False)
    outcome, violations = _monitor_blk7(run)
    assert outcome == "warned" and len(violations) == 1, run.report["monitor"]
    waited = float(re.search(r"no RTL within ([0-9.]+) s", violations[0]["actual"]).group(1))
    assert 3.0 + 5.0 < waited < 3.0 + 9.0, violations[0]


def test_the_vehicle_records_when_a_pending_action_starts_and_ends():
    """The ``busy``/``idle`` events the monitor judges by: one pair per take-off, from its
    acceptance to its altitude (``idle`` names the last state shown)."""
    model, gcs = armed_in_guided()
    assert ack_of(gcs.command(mav.MAV_CMD_NAV_TAKEOFF, *[0] * 6, 30.0, now=1.0), 22) == ACCEPTED
    model.tick(2.0)
    model.tick(2.5)
    model.tick(3.0)
    got = [(e.t, e.kind, e.detail["action"]) for e in model.events() if e.kind in ("busy", "idle")]
    assert got == [(1.0, "busy", "a take-off to 30 m, at 0.0 m"), (2.5, "idle", "a take-off to 30 m, at 20.0 m")]


def test_the_vehicle_shows_a_take_off_pending_until_its_altitude():
    """``VehicleModel.pending_action``, what the runner's waits follow: a take-off from its
    acceptance to its altitude (20 m/s: 30 m in 1.5 s), nothing on the ground or once there; a
    take-off cut short by RTL is no longer pending."""
    model, gcs = armed_in_guided()
    assert model.pending_action() is None
    assert ack_of(gcs.command(mav.MAV_CMD_NAV_TAKEOFF, *[0] * 6, 30.0, now=1.0), 22) == ACCEPTED
    assert model.pending_action() == "a take-off to 30 m, at 0.0 m"
    model.tick(2.0)
    assert model.pending_action() == "a take-off to 30 m, at 20.0 m"
    model.tick(2.5)
    assert model.pending_action() is None and model.altitude == 30.0
    model, gcs = armed_in_guided()
    assert ack_of(gcs.command(mav.MAV_CMD_NAV_TAKEOFF, *[0] * 6, 30.0, now=1.0), 22) == ACCEPTED
    model.tick(1.5)
    assert ack_of(gcs.command(mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, now=1.5), 20) == ACCEPTED
    assert model.pending_action() is None

"""The gcs role's MAV-CMD-10 against a resend that crossed the runner's MAV_RESULT_IN_PROGRESS
(the reference ground station, a lossy TCP link, the runner late by up to 1 s): its command
timer fired before the IN_PROGRESS reached it, and the one resend that came 0.3-0.4 s after the
IN_PROGRESS went out was warned as a resend while in progress (seeds 105 and 134 of a 150-seed
sweep). A ground station that ignores IN_PROGRESS resends all through the runner's 5 s hold
(sim.gcs_faults' ``ignores-in-progress``: the matrix of test_mavlink_gcs_sim.py)."""

from __future__ import annotations

import pytest

from mcp_conform.sim.gcs_role import run_gcs_cases


@pytest.mark.parametrize("seed", [105, 134])
def test_a_resend_that_crossed_in_progress_is_no_violation(seed):
    from tests.sim.test_mavlink_gcs_sim import LOSSY as lossy

    run = run_gcs_cases(None, seed=seed, link=lossy, stalls=(0.1, 1.0), select=["CMD"])
    case = next(c for c in run.report["cases"] if c["id"] == "CMD/test_no_resend_while_in_progress")
    assert case["outcome"] == "passed", run.explain()


def test_a_ground_station_ignoring_in_progress_is_still_warned():
    run = run_gcs_cases("ignores-in-progress", seed=105, select=["CMD"])
    case = next(c for c in run.report["cases"] if c["id"] == "CMD/test_no_resend_while_in_progress")
    assert case["outcome"] == "warned", run.explain()

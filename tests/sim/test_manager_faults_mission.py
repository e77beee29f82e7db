"""Session 34's missed manager faults, in the simulator: each fault model (``sim.manager_faults``)
against the manager role's cases and its trace monitor, which must judge the same traffic alike
(one judge), each fault under its one rule and no other. Each test failed on the judge before
session 34 (the monitor, or case and monitor alike, let the fault pass or named another rule).

- ``skips-a-waypoint`` / ``broadcast-skips-a-waypoint`` (MCP-FLOW-5 "WP_On messages carry the
  mission's waypoints"): the third waypoint's WP_On carries the second again. The case judged
  every waypoint; the monitor (live, and ``mcp-capture check``) did not: now both ask
  ``judge.waypoints``.
- ``broadcast-after-end`` (MCP-BLK-6 "no command to a drone after that drone's End_Mission"): a
  WP_Off broadcast once every End_Mission is ACKed goes to every drone (D-11); it passed both.
- ``broadcast-early`` (MCP-BLK-3): tests/sim/test_manager_broadcast_sim.py.
"""

from __future__ import annotations

import pytest

from mcp_conform.sim.manager_runner import run_manager_cases

SHORT = {"rto": 0.2, "ack_window": 0.25}


def _failed_cases(run) -> dict[str, dict]:
    return {c["id"]: c for c in run.report["cases"] if c["outcome"] in ("failed", "warned", "error")}


def _monitor_bad(run) -> set[str]:
    return {r for r, o in run.report["monitor"]["rules"].get("0", {}).items() if o in ("failed", "warned")}


@pytest.mark.parametrize("fault", ["skips-a-waypoint", "broadcast-skips-a-waypoint"])
def test_a_waypoint_skipped_mid_mission_fails_flow5_in_the_case_and_the_monitor(fault):
    run = run_manager_cases(fault, seed=5, challenge=2, **SHORT)
    bad = _failed_cases(run)
    assert list(bad) == ["FLOW/test_challenge_2_wp_off_follows_wp_on"], run.explain()
    case = bad["FLOW/test_challenge_2_wp_off_follows_wp_on"]
    assert case["expected"].startswith("every waypoint of the file in a WP_On to drone"), case
    assert case["actual"] == "1 of 5 never sent", case
    assert _monitor_bad(run) == {"MCP-FLOW-5"}, run.report["monitor"]
    got = [v for v in run.report["monitor"]["violations"] if v["rule"] == "MCP-FLOW-5"]
    assert got and all("1 of 5 waypoints in no WP_On to it (first: item 2)" in v["actual"] for v in got), got
    assert {v["actual"].split(" with ")[0] for v in got} == {f"End_Mission to drone {d}" for d in (1, 2, 3)}, got
    assert set(run.rules_with("failed", "warned")) == {"MCP-FLOW-5"}, run.explain()


def test_a_broadcast_after_every_end_mission_fails_blk6_in_the_case_and_the_monitor():
    run = run_manager_cases("broadcast-after-end", seed=5, challenge=2, **SHORT)
    bad = _failed_cases(run)
    assert list(bad) == ["BLK/test_nothing_after_end_mission"], run.explain()
    assert "a broadcast: D-11" in bad["BLK/test_nothing_after_end_mission"]["actual"], bad
    assert _monitor_bad(run) == {"MCP-BLK-6"}, run.report["monitor"]
    got = [v for v in run.report["monitor"]["violations"] if v["rule"] == "MCP-BLK-6"]
    # each drone's, once per mission the monitors watched (the main one and the silent drone's)
    assert {v["expected"] for v in got} == {f"no command to drone {d} after its End_Mission" for d in (1, 2, 3)}, got
    assert set(run.rules_with("failed", "warned")) == {"MCP-BLK-6"}, run.explain()

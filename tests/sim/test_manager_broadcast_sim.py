"""D-11 in the manager role's suite, in the simulator: a manager that broadcasts the challenge's
messages to every drone (delivery "any": the C manager's ``VARIANT=BROADCAST``, the C++ one's
``--broadcast-lists``) against the runner's cases and its trace monitor.

Correct (``broadcasts-mission``): Start_Mission to each drone, then one WP_List / each
waypoint's WP_On and WP_Off / one Obstacles_List broadcast once, after every Start_Mission was
ACKed, then End_Mission to each: no failed or warned verdict, at every challenge, serial and side
by side alike. The suite before D-11 failed it: "one WP_LIST to drone 1: 0" (MCP-FLOW-4/6) and
"every waypoint of the file in a WP_On to drone 1: 4 of 4 never sent" (MCP-FLOW-5).

Faulty (``broadcast-early``): the same broadcasts sent as the last drone's Start_Mission goes out,
before its ACK: a broadcast goes to every drone, so a further command to that drone before the
ACK, MCP-BLK-3, and no other rule (challenge 1 also in tests/sim/test_manager_sim.py's list of
faults), in the case and the monitor alike (session 34; before, that drone's mission got none and
the challenge's rule failed, in the case alone at challenge 2: the monitor did not judge whether
every waypoint went out in a WP_On, ``judge.waypoints`` now serves both).
"""

from __future__ import annotations

import pytest

from mcp_conform.sim.manager_runner import run_manager_cases

SHORT = {"rto": 0.2, "ack_window": 0.25}
FLOW = {1: "MCP-FLOW-4", 2: "MCP-FLOW-5", 3: "MCP-FLOW-6"}


def _bad(run) -> dict[str, str]:
    return {c["id"]: c["outcome"] for c in run.report["cases"] if c["outcome"] in ("failed", "warned", "error")}


def _monitor(run) -> dict[str, str]:
    return dict(run.report["monitor"]["rules"].get("0", {}))


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_a_manager_broadcasting_the_challenge_gets_no_verdict(challenge):
    runs = [run_manager_cases("broadcasts-mission", seed=10 + challenge, challenge=challenge, serial=serial, **SHORT)
            for serial in (False, True)]
    for run in runs:
        assert run.rc == 0, run.explain()
        assert not _bad(run), run.explain()
        assert not run.rules_with("failed", "warned"), run.explain()
        assert not {r: o for r, o in _monitor(run).items() if o in ("failed", "warned")}, run.report["monitor"]
        assert run.rules[FLOW[challenge]] == "passed", run.explain()
        assert _monitor(run)[FLOW[challenge]] == "passed", run.report["monitor"]
        assert run.rules["MCP-RTX-4"] == "passed", run.explain()  # each broadcast sent once
        sent = [a for m in run.managers for a, d in m.sent if d == 0xFFFF]
        assert sent, "the model broadcast nothing: not the run this test is for"
    assert (runs[0].cases(), _monitor(runs[0])) == (runs[1].cases(), _monitor(runs[1]))


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_a_broadcast_before_the_last_start_is_acked_fails_blk3(challenge):
    """A further command to the last drone before its Start_Mission's ACK (a broadcast goes to every
    drone), MCP-BLK-3 in the case and the monitor alike; it is that drone's command, so its
    mission's list or waypoints are there: the challenge's rule passes (one fault, one rule). The
    judge before session 34 said the challenge's rule (the case: "one WP_LIST to drone 3: 0")."""
    run = run_manager_cases("broadcast-early", seed=20 + challenge, challenge=challenge, **SHORT)
    assert run.rules.get("MCP-BLK-3") == "failed", run.explain()
    assert set(run.rules_with("failed", "warned")) == {"MCP-BLK-3"}, run.explain()
    assert run.rules.get(FLOW[challenge]) == "passed", run.explain()
    assert "error" not in run.cases().values(), run.explain()
    case = next(c for c in run.report["cases"] if "MCP-BLK-3" in c["rules"])
    assert "to drone 3" in case["expected"] and "a broadcast: D-11" in case["actual"], case
    monitor = {r for r, o in _monitor(run).items() if o in ("failed", "warned")}
    assert monitor == {"MCP-BLK-3"}, run.report["monitor"]

"""A drone that gives up its Mission_Ready and exits before Start_Mission: the setup error says so,
truly (issue 38).

The C++ drone with ``--retries 2`` (examples/mcp_cpp/drone), which exits 1 when it gives up,
got "the node exited with code 1 after Start_Mission" -- it had exited 0.5 s before Start_Mission
was sent -- and "to the runner: 3 datagram(s), none a Mission_Ready: MISSION_READY x3", which
contradicts itself. (The runner now restarts a retry limit of 2 to tell it from MCP-RTX-2's fault,
tests/sim/test_rtx2_second_look.py; a limit below it still ends the node before Start_Mission.)
Now the session checks the node is there before it sends Start_Mission, and the explanation
lists what the node sent without claiming it sent no Mission_Ready.

(Session 33: a node that gives up so, at its timer's time, now gets MCP-RTX-1's verdict on a restart
instead, tests/sim/test_give_up_short.py; the setup error stays for one that ends as it sends its
second copy -- a crash, here with code 1 -- which is what this test now runs.)
"""

from __future__ import annotations

import pytest

from mcp_conform.harness.driver import TargetDriver
from mcp_conform.sim.runner import SimSession, run_cases
from mcp_conform.spec.codec import Action
from tests.sim.test_give_up_short import exiting


@pytest.fixture
def sessions(monkeypatch: pytest.MonkeyPatch) -> list[tuple[SimSession, TargetDriver]]:
    """The run's simulated session and its driver (closed, still readable), kept for the test."""
    kept: list[tuple[SimSession, TargetDriver]] = []
    real = SimSession._spawn

    def spawn(self: SimSession) -> None:
        assert self.driver is not None
        if (self, self.driver) not in kept:
            kept.append((self, self.driver))
        real(self)

    monkeypatch.setattr(SimSession, "_spawn", spawn)
    return kept


@pytest.mark.parametrize("mavlink", [False, True], ids=["no-vehicle", "vehicle"])
def test_a_node_gone_before_start_mission_is_not_said_to_exit_after_it(
        sessions: list[tuple[SimSession, TargetDriver]], mavlink: bool) -> None:
    """Two copies, then exit 1 as the second leaves, while the startup still withholds the ACK."""
    run = run_cases(exiting(1, 0.01), seed=5, select=["RTX"], mavlink=mavlink)
    error, detail = run.report.get("error") or "", run.report.get("error_detail") or []
    assert run.rc == 2, run.explain()
    ((session, drv),) = sessions
    (model,) = session.models
    ready = [d for d in drv.received() if d.action == int(Action.MISSION_READY)]
    # what happened: two copies, the node gone, no Start_Mission ever sent
    assert len(ready) == 2 and model.closed_at is not None and model.closed_at >= ready[-1].t, run.explain()
    assert not [s for s in drv.sent() if s.action == int(Action.START_MISSION)]
    # what the error says of it
    assert error.startswith("the node exited with code 1 before Start_Mission was sent; the last of its "
                            "2 datagram(s) to the runner, MISSION_READY, came "), error
    assert "after Start_Mission" not in error, error
    assert "to the runner: 2 datagram(s): MISSION_READY ×2" in detail, detail
    assert not [line for line in detail if "none a Mission_Ready" in line or "never announced" in line], detail

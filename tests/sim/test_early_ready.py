"""A Mission_Ready that reaches the runner before its startup phase looks still counts (issue 38).

Found by the C++ drone (examples/mcp_cpp/drone, ``make FAULT=no_retransmit``): it sends
Mission_Ready once, about 1 ms after it starts, and never again. It should fail MCP-RTX-1
(exit 1); in 10 of 22 runs the run was an exit-2 setup error instead, "the node sent no
Mission_Ready within the --startup-timeout" and "to the runner: no datagram", though ``-v``
printed that very copy. The startup's wait counted from a mark of the driver taken after the
spawn returned -- and a first spawn also starts the reaper (``harness.procs``), some tens of ms
while the node already runs -- so a copy the driver recorded meanwhile was before the mark.
Now the mark is taken just before the node starts (``DatagramSessionBase.spawn_mark``).

Deterministic here: the spawn (``SimSession._spawn``) returns only once the node model's one
Mission_Ready has reached the runner's driver -- the window the race needed, held open until
the event itself, on virtual time.
"""

from __future__ import annotations

import pytest

from mcp_conform.sim.runner import SimSession, drone_factory, run_cases
from mcp_conform.spec.codec import Action

READY = int(Action.MISSION_READY)


@pytest.fixture
def ready_before_the_startup(monkeypatch: pytest.MonkeyPatch) -> list[int]:
    """Each spawn returns once the node's first Mission_Ready has reached the driver; the
    number of copies the driver held then, one entry a spawn."""
    real = SimSession._spawn
    held: list[int] = []

    def spawn_and_hear_it(self: SimSession) -> None:
        drv = self.driver
        assert drv is not None
        since = drv.mark()
        real(self)
        got = drv.wait_for(lambda d: d.action == READY, 5.0, since)
        assert got is not None, "the model sent no Mission_Ready within 5 virtual s of its start"
        held.append(sum(d.action == READY for d in drv.received(since)))

    monkeypatch.setattr(SimSession, "_spawn", spawn_and_hear_it)
    return held


def test_a_mission_ready_sent_once_as_the_node_starts_fails_rtx1_not_the_setup(
        ready_before_the_startup: list[int]) -> None:
    """The copy sent at once is the startup's first; the node never sends another: MCP-RTX-1
    fails (exit 1), no setup error, and no other MUST rule fails for it (the monitor's
    included). Before the fix: "the node sent no Mission_Ready within ..." (exit 2)."""
    run = run_cases(drone_factory("rtx-none", rto=0.2, seed=3, ready_after=0.001), seed=3)
    assert ready_before_the_startup[:1] == [1]  # the window was open: the copy came before the startup looked
    assert run.report.get("error") is None, run.explain()
    assert run.rc == 1, run.explain()
    assert run.rules["MCP-RTX-1"] == "failed", run.explain()
    assert set(run.rules_with("failed")) == {"MCP-RTX-1"}, run.explain()

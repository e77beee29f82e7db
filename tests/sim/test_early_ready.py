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

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import Datagram, Sent
from mcp_conform.sim.runner import STEP_S, SimSession, drone_factory, run_cases
from mcp_conform.sim.transport import SimTransport
from mcp_conform.spec.codec import Action

READY = int(Action.MISSION_READY)


@pytest.fixture
def ready_before_the_startup(monkeypatch: pytest.MonkeyPatch) -> list[Datagram]:
    """Each spawn returns once the node's first Mission_Ready has reached the driver: that
    copy, one a spawn (the driver held no other then)."""
    real = SimSession._spawn
    held: list[Datagram] = []

    def spawn_and_hear_it(self: SimSession) -> None:
        drv = self.driver
        assert drv is not None
        since = drv.mark()
        real(self)
        got = drv.wait_for(lambda d: d.action == READY, 5.0, since)
        assert got is not None, "the model sent no Mission_Ready within 5 virtual s of its start"
        assert sum(d.action == READY for d in drv.received(since)) == 1
        held.append(got)

    monkeypatch.setattr(SimSession, "_spawn", spawn_and_hear_it)
    return held


def test_a_mission_ready_sent_once_as_the_node_starts_fails_rtx1_not_the_setup(
        ready_before_the_startup: list[Datagram]) -> None:
    """The copy sent at once is the startup's first; the node never sends another: MCP-RTX-1
    fails (exit 1), no setup error, and no other MUST rule fails for it (the monitor's
    included). Before the fix: "the node sent no Mission_Ready within ..." (exit 2)."""
    run = run_cases(drone_factory("rtx-none", rto=0.2, seed=3, ready_after=0.001), seed=3)
    assert ready_before_the_startup  # the window was open: the copy came before the startup looked
    assert run.report.get("error") is None, run.explain()
    assert run.rc == 1, run.explain()
    assert run.rules["MCP-RTX-1"] == "failed", run.explain()
    assert set(run.rules_with("failed")) == {"MCP-RTX-1"}, run.explain()


def _acks_then_start(sent: list[Sent], seq: int) -> tuple[list[int], list[int]]:
    """Where in ``sent`` (the runner's sends in order) its ACKs naming ``seq`` are, and its
    Start_Mission copies."""
    acks = [i for i, s in enumerate(sent) if s.action == int(Action.ACK) and int.from_bytes(s.data[17:19], "big") == seq]
    return acks, [i for i, s in enumerate(sent) if s.action == int(Action.START_MISSION)]


@pytest.mark.parametrize("model", ["rtx-none", None], ids=["sent-once", "reference"])
def test_the_quick_startup_acks_a_mission_ready_sent_as_the_node_starts(
        ready_before_the_startup: list[Datagram], model: str | None) -> None:
    """The quick startup (nothing observed: a ``--parallel`` shard without the startup's cases,
    a restart) ACKs the Mission_Ready it counts before it sends Start_Mission, though that copy
    came before the driver would ACK it: once each start, both for a node that sends it once
    and for one that goes on retransmitting it. Before the fix the first start was a setup error
    for the node that sends it once; counted but left unACKed, the Start_Mission went first."""
    clock = VirtualClock(step=STEP_S)
    session = SimSession(RunConfig(spawn="sim:x", rto=0.2, ack_window=0.25), clock=clock,
                         transport=SimTransport(clock, None, None, link_seed=0),
                         make_model=drone_factory(model, rto=0.2, ready_after=0.001), name="x")
    def main() -> None:
        try:
            for start in (lambda: session.start(observe_startup=False, diagnose=True), session.restart):
                before = len(session.driver.sent()) if session.driver is not None else 0
                start()
                assert session.driver is not None
                first = ready_before_the_startup[-1].header
                assert first is not None
                acks, starts = _acks_then_start(session.driver.sent()[before:], first[2])
                assert len(starts) >= 1 and acks and acks[0] < starts[0], (acks, starts)
                assert len([i for i in acks if i < starts[0]]) == 1, acks  # ACKed once, not twice
        finally:
            session.close()

    clock.run(main)
    assert len(ready_before_the_startup) == 2

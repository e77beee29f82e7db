"""A restart's observation counts from the new instance's start, not from before the old one
was stopped (issue 38; ``DatagramSessionBase.spawn_mark``).

MCP-RTX-2's second look (``harness.drone_rtx2.observe_again``) and the fuzzer's withheld start
(``fuzz.drone_target.FuzzTarget.restart_withholding``, MCP-RTX-1/2, MCP-SEQ-2) took the driver's
mark before ``respawn``: a copy of the old instance's Mission_Ready recorded while the runner
stopped it was then taken for the new instance's first (the second look's wrong ACKs went out
after the wrong copy; the fuzzer's oracles judged copies of two nodes as one). Now the mark is
the one ``spawn_node`` takes once the old instance is stopped, just before the new one starts
(as the first spawn's, added for the same race).

Deterministic here: the first respawn runs only once the old node model has sent one more copy
of its Mission_Ready (a copy its timer fired as the runner decided) and the driver recorded it.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from mcp_conform.fuzz.drone_target import FuzzTarget
from mcp_conform.fuzz.target_base import TargetBase
from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import Datagram
from mcp_conform.sim.runner import STEP_S, SimSession, drone_factory
from mcp_conform.sim.transport import SimTransport
from mcp_conform.spec.codec import Action

READY = int(Action.MISSION_READY)


@pytest.fixture
def late_copy_of_the_old_node(monkeypatch: pytest.MonkeyPatch) -> list[Datagram]:
    """The first respawn of a session starts once the old model's last Mission_Ready, sent
    again, has been recorded by the driver; that copy."""
    real = SimSession.respawn
    late: list[Datagram] = []

    def respawn(self: SimSession, grace: float = 2.0) -> None:
        drv = self.driver
        if not late and drv is not None and self.models:
            last = [d for d in drv.received() if d.action == READY][-1]
            since = drv.mark()
            self.sim_transport._up(self.models[-1], last.data, None)
            got = drv.wait_for(lambda d: d.data == last.data, 1.0, since)
            assert got is not None, "the old model's copy never reached the driver"
            late.append(got)
        real(self, grace)

    monkeypatch.setattr(SimSession, "respawn", respawn)
    return late


def test_the_second_look_at_rtx2_counts_the_new_instance_only(late_copy_of_the_old_node) -> None:
    """A drone with a retry limit of 2 (correct: the startup's one look cannot tell it from
    stopping on any ACK) is restarted for a second look; every copy that look counts came after
    the old instance's late copy, and the look still passes its copy 3. Before the fix the late
    copy was the second look's first."""
    clock = VirtualClock(step=STEP_S)
    session = SimSession(RunConfig(spawn="sim:limit-2", rto=0.2, ack_window=0.25), clock=clock,
                         transport=SimTransport(clock, None, None, link_seed=0),
                         make_model=drone_factory(rto=0.2, seed=11, retries=2, exits_on_give_up=False),
                         name="limit-2")
    got: dict[str, Any] = {}

    def main() -> None:
        try:
            session.start()
            got["startup"] = session.startup
        finally:
            session.close()

    clock.run(main)
    (late,) = late_copy_of_the_old_node
    again = got["startup"].again
    assert again is not None and again.copies, "no second look"
    assert min(d.index for d in again.copies) > late.index, [d.index for d in again.copies]
    assert len(session.models) == 2


def test_the_fuzzers_withheld_start_counts_the_new_instance_only(late_copy_of_the_old_node) -> None:
    """The fuzzer's drone target on the simulated session (the reference drone): a fresh node's
    Mission_Ready withheld for 3 copies; each of them came after the old instance's late copy.
    Before the fix the late copy was the first of the 3."""
    clock = VirtualClock(step=STEP_S)
    cfg = RunConfig(spawn="sim:reference-drone", rto=0.2, ack_window=0.25)
    session = SimSession(cfg, clock=clock, transport=SimTransport(clock, None, None, link_seed=0),
                         make_model=drone_factory(rto=0.2, seed=12), name="reference-drone")
    target = FuzzTarget.__new__(FuzzTarget)  # (its own __init__ makes a real session)
    TargetBase.__init__(target, SimpleNamespace(), cfg, session)
    got: dict[str, Any] = {}

    def main() -> None:
        try:
            session.start(observe_startup=False, watch=False)  # as FuzzTarget.start, unmeasured
            got["withheld"] = target.restart_withholding(3)
        finally:
            session.close()

    clock.run(main)
    (late,) = late_copy_of_the_old_node
    copies = got["withheld"].copies
    assert len(copies) >= 3, copies
    assert min(d.index for d in copies) > late.index, [d.index for d in copies]

"""Attach mode: a datagram the driver received before the run's observers were added is in the
capture and before the run's monitor all the same ("nothing is lost"; issue 38).

``driver.open()`` starts the driver's receiver thread; ``observe_run`` adds the capture and the
run's trace monitor a moment later. An attached node runs already and speaks when it likes: a
datagram of it that came in between was in the driver's list (the cases saw it) but missing
from the capture and from the monitor's judgement. Now the driver keeps what it notified before
its first observers were added and hands it to them first (``TargetDriver.add_observers``).

Deterministic here: the node model (attach mode: it runs before the runner's socket opens) is
attached before ``observe_run`` and the window held open until its first datagram has reached
the driver -- the event itself, on virtual time.
"""

from __future__ import annotations

from typing import Any

import pytest

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import Datagram
from mcp_conform.sim.runner import DRONE_ADDR, STEP_S, SimSession, drone_factory
from mcp_conform.sim.transport import SimTransport
from mcp_conform.traceio.reader import open_capture
from mcp_conform.traceio.recorder import McapRecorder


@pytest.fixture
def heard_before_observed(monkeypatch: pytest.MonkeyPatch) -> list[Datagram]:
    """``observe_run`` of an attached session runs only once the node model, started first,
    has had a datagram recorded by the driver; that datagram."""
    real = SimSession.observe_run
    early: list[Datagram] = []

    def started_first(self: SimSession, target: tuple[str, int], node_id: int | None, **kw: Any) -> Any:
        assert self.driver is not None and not self.spawned
        model = self.make_model(self.clock.monotonic())
        model.addr = target
        self.models.append(model)  # (the real one then starts no other)
        self.sim_transport.attach(model)
        got = self.driver.wait_for(lambda d: True, 5.0, 0)
        assert got is not None, "the model sent nothing within 5 virtual s"
        early.append(got)
        return real(self, target, node_id, **kw)

    monkeypatch.setattr(SimSession, "observe_run", started_first)
    return early


def test_a_datagram_before_observe_run_is_captured_and_judged(tmp_path, heard_before_observed) -> None:
    """Every datagram the driver received and sent through the startup is in the capture, in
    order, and was fed to the run's monitor: the early one included. Before the fix the capture
    and the monitor lacked it (one datagram fewer than the driver's list)."""
    clock = VirtualClock(step=STEP_S)
    path = tmp_path / "run.mcap"
    recorder = McapRecorder(path)
    session = SimSession(RunConfig(target=DRONE_ADDR, rto=0.2, ack_window=0.25), recorder, clock=clock,
                         transport=SimTransport(clock, None, None, link_seed=0),
                         make_model=drone_factory(None, rto=0.2, ready_after=0.001), name="reference-drone")
    ran: dict[str, Any] = {}

    def main() -> None:
        try:
            session.start()
            ran["driver"], ran["monitor"] = session.driver, session.monitor
        finally:
            session.close()  # (the driver stopped, the monitor finished: everything fed judged)
            recorder.close()

    clock.run(main)
    rx = [d.data for d in ran["driver"].received()]
    tx = [s.data for s in ran["driver"].sent()]
    (early,) = heard_before_observed
    assert rx[0] == early.data  # the window was open: the node's first datagram came in it
    captured = list(open_capture(path).datagrams())
    assert [d.data for d in captured if d.direction == "rx"] == rx
    assert [d.data for d in captured if d.direction == "tx"] == tx
    assert ran["monitor"].monitor.count == len(rx) + len(tx)

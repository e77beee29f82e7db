"""Attach mode's startup: the node runs (and speaks) before the runner does."""

from __future__ import annotations

import sys
import time

from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import TargetDriver
from mcp_conform.harness.drone_session import Session
from mcp_conform.spec.codec import Action
from tests.conformance.runner_helpers import ROOT, free_port
from tests.spawned import attached_node


def test_a_mission_ready_heard_before_the_startup_phase_is_not_acked(monkeypatch):
    """A Mission_Ready that lands between the driver's bind and the startup phase is not
    ACKed: ACKed there (the driver's auto-ACK), the node stopped sending it, the startup saw
    none within 2.5 x --rto + 1 s and probed ID 1 (the node's ID still unknown), which a node
    with ID 3 rightly ignores (MCP-ACK-5): "target never answered" on a quiet host
    (test_runner's attach-mode test, once). Here the window is held open until the node's
    next copy has arrived."""
    listen = free_port()
    real_open = TargetDriver.open

    def open_and_hear_a_copy(self: TargetDriver):
        addr = real_open(self)
        assert self.wait_for(lambda d: d.action == Action.MISSION_READY, 10.0) is not None
        time.sleep(0.05)  # whatever the driver does with it is done
        return addr

    with attached_node(lambda p: [sys.executable, "-m", "mcp_conform.reference_impl", "drone", "--id", "3", "--bind",
                                  f"127.0.0.1:{p}", "--send-to", f"127.0.0.1:{listen}", "--rto", "0.2"],
                       listen, cwd=ROOT) as (_, port):  # it has spoken
        session = Session(RunConfig(target=("127.0.0.1", port), listen=("127.0.0.1", listen), rto=0.2,
                                    ack_window=0.25))
        try:
            monkeypatch.setattr(TargetDriver, "open", open_and_hear_a_copy)
            session.start()
            assert session.target_id == 3
            assert session.startup is not None and session.startup.observed, session.startup.reason
        finally:
            session.close()

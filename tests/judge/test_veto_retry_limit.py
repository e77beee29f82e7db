"""The veto's retry limit (``judge.veto._limit_reached``): a sender's copies stopped right after a
wrong ACK, ``min_copies`` (3) of them before it, no right ACK until later. A retry limit of 2 --
MCP-RTX-1's configurable limit, "no violation" (spec/mcp.yaml's ``min_copies``) -- ends them
there as taking the wrong ACK does: the monitor's MCP-RTX-2 failure is dropped, naming the
limit (the C drone's ``--retries 2`` failed the run on it). With fewer copies before the wrong
ACK (the runner's second look, ``harness.drone_rtx2``) no limit the rule allows explains the
stop, and the failure stands; so does one where the sender moved on at once."""

from __future__ import annotations

import pytest

from mcp_conform.judge.monitor import TESTER
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action
from tests.judge.monitor_scripts import Script

MIN_COPIES = int(SPEC.params["min_copies"])


def _stops_after_wrong_ack(copies: int, *, moves_on: bool = False) -> Script:
    """Drone 1's Mission_Ready, ``copies`` copies, the runner's wrong-seq ACK, then nothing from
    the drone for 1 s (or, ``moves_on``, a new message at once), then the right ACK."""
    s = Script((1,), vehicle=False)
    seq, data = s.send(1, 0, Action.MISSION_READY)
    for _ in range(copies - 1):
        s.tick(s.rto)
        s.raw(1, data)
    s.tick(0.001)
    s.ack(0, 1, (seq + 0x8000) & 0xFFFF, origin=TESTER)
    if moves_on:
        s.tick(0.002)
        s.send(1, 0, Action.MISSION_READY)
    s.tick(1.0)
    s.ack(0, 1, seq, origin=TESTER)
    return s


@pytest.mark.parametrize("copies", [MIN_COPIES, MIN_COPIES + 2])
def test_a_stop_after_min_copies_is_a_retry_limits(copies: int) -> None:
    s = _stops_after_wrong_ack(copies)
    s.judge()
    mon = s.last_monitor
    assert not [v for v in mon.violations if v.rule == "MCP-RTX-2"], mon.violations
    assert mon.verdicts()[1]["MCP-RTX-2"] != "failed"
    (x,) = [x for x in mon.vetoed if x.violation.rule == "MCP-RTX-2"]
    assert f"{copies} copies before the wrong ACK, then none: a retry limit of {copies - 1}" in x.explanation


def test_a_stop_after_fewer_copies_stands() -> None:
    s = _stops_after_wrong_ack(MIN_COPIES - 1)
    s.judge()
    mon = s.last_monitor
    assert mon.verdicts()[1]["MCP-RTX-2"] == "failed"
    assert not [x for x in mon.vetoed if x.violation.rule == "MCP-RTX-2"]


def test_a_move_on_at_once_after_min_copies_is_not_a_retry_limits() -> None:
    """A give-up comes at the sender's timer, not 2 ms after the wrong ACK."""
    s = _stops_after_wrong_ack(MIN_COPIES, moves_on=True)
    s.judge()
    mon = s.last_monitor
    assert not [x for x in mon.vetoed if "retry limit" in x.explanation], mon.vetoed
    assert mon.verdicts()[1]["MCP-RTX-2"] == "failed"

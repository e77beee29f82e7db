"""The silent drone's manager instance is judged up to its stop, not to the run's last case mark
(session 34; the Go manager's ``-broadcast-lists``: tests/examples/test_go_manager.py's
``SILENT_SESSION_END``), in the simulator: the runner's own cases and monitor against a manager
model, live and in ``mcp-capture check`` of the run's capture (one judge).

The correct model (:class:`EndsSilentLast`) is the D-11 broadcaster (``broadcasts-mission``) with
its End_Missions in another order: the silent drone's last. Its other drones' End_Missions are
ACKed at once, so the silent drone's scenario ends a tail after them (``MissionScript._await_end``)
and its instance is stopped while that drone's End_Mission is still retransmitted: 2 copies at
``--rto 0.2``. Side by side (the default), the scenario's session is told when its case asks,
after the main mission; its monitor ended at the run's last case mark, 2.5 s after the stop, and
failed MCP-RTX-1 ("2 copies of End_Mission ... to ID 1, no ACK, none for 2.500 s"), live and in
``check`` alike, exit 1. Now the session ends at the instance's stop: its run delay read as it
is stopped, held with the scenario's traffic and written to its session
(``SideScenario._hold_stop``, ``judge.run_monitor.session_end``).

The faulty model (``broadcasts-mission``'s plan, the silent drone's End_Mission first, sent once
and never again: ``manager-rtx-none``'s endpoint) shows the session still judges what happened
before the stop: that End_Mission's one copy and the 12.5 s of silence after it while the instance
ran (at ``--rto 0.5`` the scenario's cap, 12.5 s, is past a lone copy's due time, judged at the
description's 5 s timeout) fail MCP-RTX-1 in the silent session, live and in ``check``.
"""

from __future__ import annotations

import random
from pathlib import Path
from typing import Any

import pytest

from mcp_conform.judge.judging import Params, judge
from mcp_conform.sim.faults import FAULTS, fault_endpoint
from mcp_conform.sim.manager_faults import BroadcastsMission
from mcp_conform.sim.manager_runner import SIDE_MANAGER_ADDR, run_manager_cases
from mcp_conform.spec.codec import Action
from mcp_conform.traceio.reader import Metadata, open_capture
from mcp_conform.traceio.recorder import RUN_DELAY_METADATA, recorded_run_delay

SHORT = {"rto": 0.2, "ack_window": 0.25, "challenge": 1}
RETRIES = 12  # the embedded manager's (harness.manager_session.EMBEDDED_RETRIES)


class EndsSilentLast(BroadcastsMission):
    """Correct: ``broadcasts-mission`` with the first drone's End_Mission last (the order of the
    drones' End_Missions is not specified). The first drone is the silent scenario's silent one."""

    def plan(self) -> list[tuple[int, int, Any]]:
        out = super().plan()
        n = len(self.drones)
        return [*out[:-n], *out[-n + 1:], out[-n]]


def _factory(cls: type, fault: str | None = None, rto: float = 0.2) -> Any:
    endpoint = fault_endpoint(FAULTS[fault], RETRIES) if fault is not None else None
    spawns = random.Random(0)

    def make(drones: tuple[int, ...], challenge: int, items: tuple[Any, ...], now: float) -> Any:
        return cls(drones, challenge, items, rto, RETRIES, random.Random(spawns.getrandbits(64)), endpoint=endpoint)

    make.__name__ = cls.__name__ if fault is None else f"{cls.__name__}-{fault}"
    return make


def _to_silent_drone(rtx1: list[tuple[str, str]]) -> list[str]:
    """MCP-RTX-1's violations about the silent drone's End_Mission (the main mission ACKs every
    End_Mission at once: these are the silent session's)."""
    return [actual for rule, actual in rtx1 if rule == "MCP-RTX-1" and "End_Mission" in actual and "to ID 1," in actual]


def _run(tmp_path: Path, make: Any, serial: bool, **kw: Any) -> tuple[Any, list[tuple[str, str]], list[tuple[str, str]], Path]:
    cap = tmp_path / f"run-{'serial' if serial else 'side'}.mcap"
    run = run_manager_cases(make, seed=5, serial=serial, extra=["--capture", str(cap)], **{**SHORT, **kw})
    live = [(v["rule"], v["actual"]) for v in run.report["monitor"]["violations"]]
    check = [(v.rule, v.actual) for v in judge(cap, Params()).violations]
    return run, live, check, cap


def _stops(cap: Path, segment: str) -> list[int]:
    """The times of the run delays read as ``segment``'s manager instance was stopped."""
    out = []
    for r in open_capture(cap):
        if isinstance(r, Metadata) and r.name == RUN_DELAY_METADATA and r.data.get("segment") == segment:
            got = recorded_run_delay(r.data)
            assert got is not None
            out.append(got[0])
    return out


@pytest.mark.parametrize("serial", [False, True])
def test_the_silent_instance_stopped_mid_retransmission_draws_no_rtx1(tmp_path: Path, serial: bool) -> None:
    run, live, check, cap = _run(tmp_path, _factory(EndsSilentLast), serial)
    silent = run.managers[-1] if serial else next(m for m in run.managers if m.addr == SIDE_MANAGER_ADDR)
    # the run this test is for: the silent instance's last message, the silent drone's
    # End_Mission, was never delivered (the stop came while it was retransmitted), and the
    # other drones' End_Missions were
    assert (Action.END_MISSION, 1) not in silent.sent and not silent.failed, silent.sent
    assert {(Action.END_MISSION, 2), (Action.END_MISSION, 3)} <= set(silent.sent), silent.sent
    assert _to_silent_drone(live) == [] and _to_silent_drone(check) == [], (live, check)
    assert live == [] and sorted(check) == sorted(live), (live, check)
    assert run.rc == 0 and not run.rules_with("failed", "warned"), run.explain()
    assert run.report["monitor"]["rules"]["0"].get("MCP-RTX-1") != "failed", run.report["monitor"]
    # the stop is in the silent session's record, as the main instance's is in its own
    assert len(_stops(cap, "silent")) == 1 and len(_stops(cap, "main")) >= 1


def test_the_silent_session_still_judges_what_came_before_the_stop(tmp_path: Path) -> None:
    run, live, check, cap = _run(tmp_path, _factory(BroadcastsMission, "manager-rtx-none", rto=0.5), serial=False,
                                 rto=0.5, ack_window=0.6)
    assert run.rc == 1 and run.rules.get("MCP-RTX-1") == "failed", run.explain()
    assert run.missions["silent"].ended_by == "cap", run.missions["silent"].ended_by
    found = _to_silent_drone(live)
    assert len(found) == 1 and found == _to_silent_drone(check), (live, check)
    # judged at the instance's stop, the scenario's cap after the copy (before: at the case's
    # end mark, a second later: "none for 13.500 s")
    assert found[0].startswith("1 copy of End_Mission") and found[0].endswith("none for 12.500 s"), found
    assert len(_stops(cap, "silent")) == 1
    assert sorted(check) == sorted(live), (live, check)

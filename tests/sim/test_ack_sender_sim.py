"""MCP-ACK-3 ("An ACK's dst is the src of the acknowledged message") judged from a src other than
the manager's 0, and D-10 (a drone may ignore a command from a src other than 0), on virtual time.

From ID 0 alone a drone whose ACKs always go to ID 0 looks right: the case probed from 0 only
and passed it (the sample node's ``ack-to-manager``; without the vehicle nothing else sends from
another src, so the whole run passed). A drone that answers nothing from another src shows
nothing of where its ACKs go: the case is skipped with D-10's reason, never passed, and
MCP-ACK-1 is not failed for it (D-10)."""

from __future__ import annotations

import random
from typing import Any

import pytest

from mcp_conform.sim.models import DroneModel
from mcp_conform.sim.mutants import mutant_factory
from mcp_conform.sim.runner import run_cases
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import MANAGER_ID, Action, peek_header

CASE = "ACK/test_ack_is_addressed_back_to_the_sender"
SHORT = {"rto": 0.2, "ack_window": 0.25}


class ManagerOnlyDrone(DroneModel):
    """The reference drone model that reads nothing but ACKs from a src other than the
    manager's 0: a command from another src is neither ACKed nor delivered (D-10: correct)."""

    def receive(self, data: bytes, addr: Any, now: float) -> None:
        head = peek_header(data)
        if head is not None and head[1] != MANAGER_ID and head[3] != int(Action.ACK):
            self.now = now
            return
        super().receive(data, addr, now)


def manager_only(seed: int):
    retries = int(SPEC.params["retries"])
    spawns = random.Random(seed)

    def make(now: float) -> DroneModel:
        return ManagerOnlyDrone(1, SHORT["rto"], retries, random.Random(spawns.getrandbits(64)),
                                ready_at=now + 0.05)

    make.__name__ = "manager-only"
    return make


def _case(run) -> dict:
    (case,) = [c for c in run.report["cases"] if c["id"] == CASE]
    return case


@pytest.mark.parametrize("mavlink", [False, True], ids=["no-vehicle", "vehicle"])
def test_acks_always_to_id_0_fail_mcp_ack_3_in_its_case(mavlink):
    """The case itself fails the drone (with the vehicle the trace monitor saw it too, in
    MCP-DUP-3's messages from another src: the case said passed beside it); nothing else fails."""
    run = run_cases(mutant_factory("ack-to-manager", rto=SHORT["rto"], seed=5), seed=5, mavlink=mavlink, **SHORT)
    case = _case(run)
    assert case["outcome"] == "failed", run.explain()
    assert case["actual"].startswith("dst=0, src=1") and "dst=2 (the acknowledged message's src)" in case["expected"], case
    assert run.rules_with("failed", "warned") == {"MCP-ACK-3": "failed"}, run.explain()
    assert run.rc == 1


def test_a_drone_that_ignores_other_sources_leaves_mcp_ack_3_skipped_not_passed():
    """D-10: no failure for ignoring them (MCP-ACK-1 passed on the manager's messages), and no
    pass of what could not be seen."""
    run = run_cases(manager_only(6), seed=6, mavlink=True, **SHORT)
    case = _case(run)
    assert case["outcome"] == "skipped", run.explain()
    assert "answers no message from src 2 (D-10" in case["reason"], case
    assert run.rules["MCP-ACK-3"] == "skipped" and run.rules["MCP-DUP-3"] == "skipped", run.explain()
    (dup3,) = [c for c in run.report["cases"] if "MCP-DUP-3" in c["rules"]]
    assert "D-10" in dup3["reason"], dup3
    assert run.rules["MCP-ACK-1"] == "passed", run.explain()
    assert not run.rules_with("failed", "warned"), run.explain()
    assert run.report["monitor"]["violations"] == [], run.report["monitor"]["violations"]


@pytest.mark.parametrize("mavlink", [False, True], ids=["no-vehicle", "vehicle"])
def test_the_reference_drone_passes_it_from_both_sources(mavlink):
    run = run_cases(None, seed=7, mavlink=mavlink, **SHORT)
    assert _case(run)["outcome"] == "passed", run.explain()
    assert not run.rules_with("failed", "warned"), run.explain()


def test_a_drone_deaf_to_other_source_ports_gets_mcp_ack_1_as_mcp_trn_2s_consequence():
    """The sample node's source-port-filter (a drone on a connect()ed socket): MCP-TRN-2 fails,
    and the monitor's MCP-ACK-1 violation on the datagrams it dropped is TRN-2's consequence in
    the failures and in the rules table alike (it was "passed" there), no failure of its own."""
    run = run_cases(mutant_factory("source-port-filter", rto=SHORT["rto"], seed=3), seed=3, **SHORT)
    assert run.rules_with("failed", "warned") == {"MCP-TRN-2": "failed"}, run.explain()
    mon = [f for f in run.report["failures"] if f.get("source") == "monitor"]
    assert [(f["rule"], f["consequence_of"]) for f in mon] == [("MCP-ACK-1", ["MCP-TRN-2"])], run.report["failures"]
    assert run.rules["MCP-ACK-1"] == "consequence", run.explain()


@pytest.mark.parametrize("seed", [13, 17])
def test_acks_always_to_id_0_through_the_impairment_fail_mcp_ack_3_alone(seed):
    """Through ``--impair`` the drone's ACK of the runner's seq 516 from src 2, sent to ID 0,
    met the manager's 1026 (516 byte-swapped) within the horizon: the monitor called it a byte
    swap (MCP-ACK-2) beside the true MCP-ACK-3, in 7 of seeds 1-20 (these two among them). As
    the ACK of the message it names it breaks MCP-ACK-3 only; neither explanation is proven
    (``judge._monitor_receiver``; tests/judge/test_monitor.py's unit of it)."""
    run = run_cases(mutant_factory("ack-to-manager", rto=SHORT["rto"], seed=seed), seed=seed, select=["ACK", "DUP"],
                    extra=("--impair", f"loss=0.1,dup=0.05,reorder=0.1,seed={seed}"), **SHORT)
    assert run.rules_with("failed", "warned") == {"MCP-ACK-3": "failed"}, run.explain()

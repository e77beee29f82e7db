"""The fuzzer's withheld start (``fuzz.drone_target.FuzzTarget.restart_withholding``, judged by
``fuzz.oracles.judge_withheld``: the path of ``fuzz.replay`` and ``fuzz.engine_stateful``) on the
simulated session, against the drone models the drone suite is judged on in
tests/sim/test_reannounce.py: the fuzzer's finding and the suite's verdict agree (one judge,
``judge.copies_by_number``).

A drone at retry limit 1 that announces again when it gives up (seq N twice, then seq N+1; the
Node.js drone's ``--retries 1 --reannounce``) had 2 copies while the ACK was withheld: the
fuzzer found MCP-SEQ-2 there, taking N+1 for N's third copy, where the suite fails MCP-RTX-1.
At retry limit 2 (the rule's least) announcing again breaks nothing; a drone whose every copy
takes a new number (``rtx-new-seq``) keeps its MCP-SEQ-2 finding.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from mcp_conform.fuzz.drone_target import FuzzTarget
from mcp_conform.fuzz.oracles import judge_withheld
from mcp_conform.fuzz.target_base import TargetBase
from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.config import RunConfig
from mcp_conform.sim.mutants import mutant_factory
from mcp_conform.sim.runner import STEP_S, SimSession
from mcp_conform.sim.transport import SimTransport
from tests.sim.test_reannounce import RTO, reannouncing


def _withheld(name: str, make_model: Any, copies: int = 3) -> tuple[Any, Any]:
    """A fresh simulated node's Mission_Ready withheld for ``copies`` copies, as the fuzzer's
    withhold move asks; (what was seen, the oracle's flaw)."""
    clock = VirtualClock(step=STEP_S)
    cfg = RunConfig(spawn=f"sim:{name}", rto=RTO, ack_window=0.25)
    session = SimSession(cfg, clock=clock, transport=SimTransport(clock, None, None, link_seed=0),
                         make_model=make_model, name=name)
    target = FuzzTarget.__new__(FuzzTarget)  # (its own __init__ makes a real session)
    TargetBase.__init__(target, SimpleNamespace(), cfg, session)
    got: dict[str, Any] = {}

    def main() -> None:
        try:
            session.start(observe_startup=False, watch=False)  # as FuzzTarget.start, unmeasured
            w = target.restart_withholding(copies)
            got["w"], got["flaw"] = w, judge_withheld(w.copies, w.after_wrong_ack, copies, target.alive())
        finally:
            session.close()

    clock.run(main)
    return got["w"], got["flaw"]


def test_a_drone_that_gives_up_short_and_announces_again_is_found_by_rtx1_not_seq2() -> None:
    w, flaw = _withheld("reannounce-1", reannouncing(1))
    seqs = [d.header[2] for d in w.copies]
    assert len(set(seqs)) == 2 and seqs.count(seqs[0]) == 2, seqs  # N, N, then N+1
    assert flaw is not None and flaw.rule == "MCP-RTX-1", flaw
    assert flaw.actual.startswith("2 copies seen, then a new Mission_Ready"), flaw.actual


@pytest.mark.parametrize("copies", [2, 3])
def test_at_the_least_retry_limit_announcing_again_is_no_finding(copies: int) -> None:
    _, flaw = _withheld("reannounce-2", reannouncing(2), copies)
    assert flaw is None, flaw


def test_a_drone_whose_retransmissions_take_new_numbers_keeps_seq2() -> None:
    w, flaw = _withheld("rtx-new-seq", mutant_factory("rtx-new-seq", rto=RTO, seed=5))
    assert len({d.header[2] for d in w.copies}) == len(w.copies) >= 3, w.copies
    assert flaw is not None and flaw.rule == "MCP-SEQ-2", flaw

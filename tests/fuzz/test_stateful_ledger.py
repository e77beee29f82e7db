"""After a flaw, the stateful engine goes on on a node its delivery ledger knows (issue 38: a
false verdict is as bad as a missed fault).

Triage replays a flaw on fresh nodes, so the node left after it is the last replay's, and
the flaw's own node had just broken a rule: neither is what the ledger (``DeliveryLedger``,
MCP-DUP-1's premise: what the node was sent) knows. A seq-no-wrap node left by the
confirmation replays of its wrap (seq 65535 then 0 from our src) takes every later message
of ours for a duplicate: on the old engine the next program's passthrough frame was
under-delivered, an MCP-DUP-2 flaw of a node the ledger did not know, triaged in vain
(unconfirmed) or kept as a finding of another rule.
"""

from __future__ import annotations

from pathlib import Path

import pytest

from mcp_conform.fuzz.campaign import run_campaign
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import FindingStore
from tests.fuzz.test_stateful_finds import DURATION_S, RTO, spawn_command


@pytest.mark.slow
@pytest.mark.timeout(DURATION_S + 120)
def test_after_a_finding_the_flaws_are_the_nodes_own_rule(tmp_path: Path) -> None:
    """seq-no-wrap, the stateful engine, seed 1: the wrap (MCP-SEQ-3) is found about 100 cases
    in; in the 2,400 cases after it every flaw seen is that rule again (a node of the ledger's
    knowledge breaks only the rule its fault breaks: a new seq above the last is delivered,
    MCP-DUP-2, by it too). On the old engine, the programs after the finding ran on the last
    replay's node: an MCP-DUP-2 flaw came next, unconfirmed or kept as a second finding."""
    cfg = FuzzConfig(spawn=spawn_command("seq-no-wrap", True), mavlink=True, engine="stateful", seed=1,
                     max_cases=2500, duration=DURATION_S, rto=RTO, out=str(tmp_path))
    store = FindingStore(tmp_path, cfg.replay_args())
    summary = run_campaign(cfg, store)
    eng = summary["workers"][0]["engines"]["stateful"]
    assert "MCP-SEQ-3" in store.by_rule(), (store.by_rule(), eng)
    others = {r for r in [*store.by_rule(), *eng["unconfirmed_by_rule"]] if r != "MCP-SEQ-3"}
    assert not others, (store.by_rule(), eng["unconfirmed_by_rule"], summary["restarts_by_reason"])
    assert eng["flaws_seen"] >= 1 and eng["cases"] == 2500, eng


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_fresh_nodes_ledger_knows_its_startups_start_mission(tmp_path: Path) -> None:
    """A fresh node's history starts with its startup: the Start_Mission our src sent, whose
    seq the node's duplicate check goes by. Here it is 65,000; the next program's passthrough
    frame, SEQ_GAP later, has wrapped (seq ~465), and the seq-no-wrap node drops it: the
    ledger names the wrap, MCP-SEQ-3, and the node's state before it. On the old engine the
    ledger started empty after a restart ("nothing delivered from src 0 yet") and called the
    same drop an MCP-DUP-2 (a new seq not delivered), the node's own fault under a rule it did
    not break."""
    from mcp_conform.fuzz.engine_stateful import SEQ_GAP, StatefulEngine
    from mcp_conform.fuzz.programs import Move
    from mcp_conform.fuzz.targets import start_target
    from mcp_conform.fuzz.triage import Triage
    from mcp_conform.spec.codec import Action

    cfg = FuzzConfig(spawn=spawn_command("seq-no-wrap", True), mavlink=True, engine="stateful", seed=1,
                     rto=RTO, out=str(tmp_path))
    t = start_target(cfg)
    try:
        eng = StatefulEngine(t, Triage(t, FindingStore(tmp_path), "stateful", cfg.seed), cfg)  # type: ignore[arg-type]
        eng._over = lambda: False
        drv = t.driver
        drv.set_seq(65_000)
        t.session.ended = True  # the mission ended: the next program gets a fresh node
        got = eng._play([Move("command", action=int(Action.MAV_PASSTHROUGH))]) or eng._settle_and_judge()
        assert t.restarts == 1, t.restart_reasons
        assert (drv.peek_seq() - 1) < 65_000 - SEQ_GAP  # the program's seq wrapped
        assert got is not None, "the seq-no-wrap node delivered the frame after the wrap"
        flaw = got[0]
        assert flaw.rule == "MCP-SEQ-3", (flaw.rule, flaw.evidence)
        assert any("last delivered from src" in e for e in flaw.evidence), flaw.evidence
    finally:
        t.close()

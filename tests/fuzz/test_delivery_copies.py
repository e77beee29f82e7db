"""A frame over-delivered after its copy: MCP-DUP-1 only when the copy added a delivery.

MCP-DUP-1: "A message with the same (src, seq) as the one last delivered from that src is a
duplicate: ACKed again (MCP-ACK-1) but not delivered to the application again." MCP-PAY-8
(SHOULD): "A drone linked to an autopilot forwards each delivered Mav_Passthrough frame to it
exactly once." A node that writes each delivered frame twice to its autopilot and discards
copies (the sample node's ``--fault passthrough-twice``) breaks the second, not the first:
its frame reaches the vehicle twice with or without a copy behind it. ``mcp-conform --spawn``
says so (DUP/test_same_seq_twice_is_delivered_once passed, PAY-8's case warned); the fuzzer
confirmed an MCP-DUP-1 finding on it (the ledger blamed the copy that came last, the count
over the allowance whoever caused it). One judge: the replay lets the original's forwards
settle before its copy, as the conformance case takes its baseline (``fuzz.delivery``).
"""

from __future__ import annotations

import shlex
import sys
from pathlib import Path

import pytest

from mcp_conform.fuzz.campaign import run_campaign
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import FindingStore
from mcp_conform.fuzz.replay import run_sequence
from mcp_conform.fuzz.targets import start_target
from mcp_conform.spec.codec import MANAGER_ID, Action, build_datagram
from mcp_conform.vehicle import make_probe

SAMPLE = Path(__file__).resolve().parents[1] / "conformance" / "nodes" / "sample_node.py"
RTO = 0.2


def _spawn(*faults: str) -> str:
    return (f"{shlex.quote(sys.executable)} {shlex.quote(str(SAMPLE))} --id {{id}} "
            "--bind {target_host}:{target_port} --send-to {listen_host}:{listen_port} "
            f"--rto {RTO} --mavlink {{mavlink}}" + "".join(f" --fault {f}" for f in faults))


@pytest.mark.slow
@pytest.mark.timeout(120)
@pytest.mark.parametrize("faults, rule", [
    ((), None),
    (("passthrough-twice",), "MCP-PAY-8"),
    (("no-dup-discard",), "MCP-DUP-1"),
    (("passthrough-twice", "no-dup-discard"), "MCP-DUP-1"),
], ids=["correct", "twice", "no-dup-discard", "both"])
def test_a_replayed_copy_is_blamed_only_when_it_adds_a_delivery(tmp_path: Path, faults, rule) -> None:
    """A passthrough frame and its copy (same bytes: same src, seq), replayed as triage and
    ``mcp-fuzz --replay`` replay them: the over-delivery is the copy's (MCP-DUP-1) only when
    the frame's count grew after it, else the original's (MCP-PAY-8). Before the fix the
    twice node's replay named MCP-DUP-1 (the node breaks no duplicate rule)."""
    cfg = FuzzConfig(spawn=_spawn(*faults), mavlink=True, engine="stateful", seed=1, rto=RTO,
                     ack_window=0.25, out=str(tmp_path))
    t = start_target(cfg)
    try:
        seq = (t.driver.peek_seq() + 100) & 0xFFFF
        frame = build_datagram(t.node_id, MANAGER_ID, seq, Action.MAV_PASSTHROUGH, make_probe("dupcopy1"))
        out = run_sequence(t, [frame, frame])
    finally:
        t.close()
    vehicle = [f for f in out.flaws if f.source == "vehicle"]
    assert out.probe_acked, out.flaws
    assert [f.rule for f in vehicle] == ([rule] if rule else []), [(f.rule, f.actual, f.evidence) for f in vehicle]
    if rule is not None:
        assert any("before its copy" in e for e in vehicle[0].evidence), vehicle[0].evidence


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_node_that_forwards_twice_has_no_duplicate_finding(tmp_path: Path) -> None:
    """The stateful campaign (seed 6, as tests/fuzz/test_faulty_nodes.py runs no-dup-discard)
    against the twice node, until its MCP-PAY-8 finding: no MCP-DUP-1 finding, confirmed or
    not, on the way. Before the fix the campaign's first finding was MCP-DUP-1 (3 runs of 3,
    confirmed 3 of 3: the copy replayed right behind its original, the count 2 over 1)."""
    cfg = FuzzConfig(spawn=_spawn("passthrough-twice"), mavlink=True, engine="stateful", seed=6,
                     max_cases=20_000, duration=60.0, out=str(tmp_path), rto=RTO, ack_window=0.25,
                     extra={"stop_on_rule": "MCP-PAY-8"})
    store = FindingStore(tmp_path, cfg.replay_args())
    summary = run_campaign(cfg, store)
    eng = summary["workers"][0]["engines"]["stateful"]
    assert "MCP-PAY-8" in store.by_rule(), (store.by_rule(), eng)
    assert "MCP-DUP-1" not in store.by_rule() and "MCP-DUP-1" not in eng["unconfirmed_by_rule"], (
        store.by_rule(), eng)


@pytest.mark.slow
@pytest.mark.timeout(180)
def test_a_node_that_forwards_twice_and_delivers_copies_has_its_duplicate_finding(tmp_path: Path) -> None:
    """Both faults (passthrough-twice and no-dup-discard): the copy adds deliveries (2 before
    it, 4 after), so MCP-DUP-1 is found, not taken for the forwarding's MCP-PAY-8 (a search
    that took PAY-8 for the flaw shrank the frame and its copy to the frame alone, whose count
    2 over 1 is PAY-8's, and counted every later DUP-1 flaw there)."""
    cfg = FuzzConfig(spawn=_spawn("passthrough-twice", "no-dup-discard"), mavlink=True, engine="stateful", seed=6,
                     max_cases=20_000, duration=60.0, out=str(tmp_path), rto=RTO, ack_window=0.25,
                     extra={"stop_on_rule": "MCP-DUP-1"})
    store = FindingStore(tmp_path, cfg.replay_args())
    summary = run_campaign(cfg, store)
    assert "MCP-DUP-1" in store.by_rule(), (store.by_rule(), summary["workers"][0]["engines"])

"""Every oracle observes as its rule's text says (issue 36, deliverable 1).

MCP-ACK-1 is observed "the runner retransmitting it every --rto as a manager would, up to 5
copies (a node may be deaf while busy, D-6)". The node here is tests/fuzz/nodes/plain_node.py:
a plain, correct, single-threaded UDP drone whose receive buffer is made small (``--rcvbuf``),
so a burst overflows it and the kernel drops datagrams the node never sees — the false MUST
finding of issue 36 ("MCP-ACK-1: no ACK of WP_OFF ... though the probe sent after it was
ACKed"). Each test shows first that the situation arose (the one-copy view does see missing
ACKs; the kernel did drop datagrams), then that the oracle, observing as the rule says, makes
no finding of it — and that a node that really does not ACK is still found.
"""

from __future__ import annotations

import os
import shlex
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import pytest

from mcp_conform.fuzz.campaign import run_campaign
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import FindingStore
from mcp_conform.fuzz.oracles import Input, judge_exchange, judge_replies
from mcp_conform.fuzz.target_base import TargetBase
from mcp_conform.fuzz.targets import start_target
from mcp_conform.spec.codec import ITEM, Action, build_datagram

PLAIN = Path(__file__).resolve().parent / "nodes" / "plain_node.py"
RTO = 0.3
SMALL_RCVBUF = 4096  # the kernel doubles it: one big datagram fills it
#: The Done-when's 60 s campaign; MCP_FUZZ_CAMPAIGN_S shortens it while iterating (it still
#: means something at 10 s: the drops file shows the kernel dropped datagrams)
CAMPAIGN_S = float(os.environ.get("MCP_FUZZ_CAMPAIGN_S", "60"))

pytestmark = pytest.mark.skipif(not Path("/proc/net/udp").exists(),
                                reason="the kernel's drop count of a socket is read from Linux /proc/net/udp")


def plain_command(*extra: str) -> str:
    return (f"{shlex.quote(sys.executable)} {shlex.quote(str(PLAIN))} --id {{id}} "
            "--bind {target_host}:{target_port} --send-to {listen_host}:{listen_port} "
            f"--rto {RTO} " + " ".join(shlex.quote(e) for e in extra))


@contextmanager
def plain_target(*extra: str) -> Iterator[TargetBase]:
    t = start_target(FuzzConfig(spawn=plain_command(*extra), rto=RTO, ack_window=RTO, seed=7))
    try:
        yield t
    finally:
        t.close()


def burst(t: TargetBase, commands: list[Action]) -> list[Input]:
    """One 65,507-byte datagram (the codec rejects it: no ACK due), then ``commands``, each a
    unicast to the node, back to back as the stateless engine sends a batch."""
    drv = t.driver
    big = build_datagram(t.node_id, drv.our_id, drv.next_seq(), int(Action.WP_LIST), b"\xff" * (65507 - 17))
    payload = {Action.WP_ON: bytes(ITEM.size)}  # one all-zero mission item; WP_Off has none
    datagrams = [big] + [build_datagram(t.node_id, drv.our_id, drv.next_seq(), int(a), payload.get(a, b""))
                         for a in commands]
    for d in datagrams:
        drv.send_raw(d)
    return [Input.of(d) for d in datagrams]


def one_copy_view(t: TargetBase, inputs: list[Input], mark: int, probe) -> list[str]:  # noqa: ANN001
    drv = t.driver
    return [f.rule for f in judge_replies(inputs, drv.received(mark), t.node_id, t.broadcast_id, probe.acked,
                                          ignore_seqs=[(drv.our_id, probe.sent.seq)], probe_copies=probe.copies)]


def test_a_node_deaf_for_one_burst_is_not_a_finding() -> None:
    with plain_target("--rcvbuf", str(SMALL_RCVBUF), "--deaf-after-big", "0.6") as t:
        mark = t.driver.mark()
        inputs = burst(t, [Action.WP_OFF] * 20)
        probe = t.probe()
        assert probe.acked, "the node answers its liveness probe once it reads again"
        # what one copy shows: the kernel dropped commands while the node was deaf
        assert "MCP-ACK-1" in one_copy_view(t, inputs, mark, probe)
        flaws = judge_exchange(inputs, t, mark, probe)
        assert flaws == [], flaws
        # each command reached the node on a retransmission (every --rto, as a manager would)
        assert all(i.received for i in inputs[1:])
        assert sum(i.observed.get("resent", 0) for i in inputs) > 0


def test_a_node_that_does_not_ack_a_command_is_still_found_after_a_burst() -> None:
    with plain_target("--rcvbuf", str(SMALL_RCVBUF), "--deaf-after-big", "0.6", "--fault", "no-ack-wp-on") as t:
        mark = t.driver.mark()
        inputs = burst(t, [Action.WP_OFF] * 10 + [Action.WP_ON] + [Action.WP_OFF] * 5)
        probe = t.probe()
        assert probe.acked
        flaws = judge_exchange(inputs, t, mark, probe)
        ack1 = [f for f in flaws if f.rule == "MCP-ACK-1"]
        assert [inputs[f.culprit].msg.action for f in ack1] == [Action.WP_ON], flaws  # type: ignore[union-attr,index]
        assert "5 copies every 0.3 s" in ack1[0].evidence[-1] and "none ACKed" in ack1[0].evidence[-1]
        assert len(flaws) == 1, flaws


def _drops(path: Path) -> list[int]:
    return [int(x) for x in path.read_text().split()] if path.exists() else []


@pytest.mark.slow
def test_a_correct_node_with_a_small_receive_buffer_has_no_finding_in_a_campaign(tmp_path: Path) -> None:
    """The Done-when: a correct node with a small receive buffer under a 60 s campaign (the
    user's settings: --rto 0.3 --seed 7, the default engine): 0 findings. The kernel did drop
    datagrams from its buffer meanwhile (the node's drops file), so the oracles met the case."""
    drops = tmp_path / "drops.txt"
    cfg = FuzzConfig(spawn=plain_command("--rcvbuf", str(SMALL_RCVBUF), "--drops-file", str(drops)),
                     seed=7, duration=CAMPAIGN_S, out=str(tmp_path / "out"), rto=RTO)
    store = FindingStore(tmp_path / "out", cfg.replay_args())
    summary = run_campaign(cfg, store)
    assert summary["error"] is None, summary["error"]
    assert summary["cases"] > 0
    assert sum(d for d in _drops(drops) if d > 0) > 0, f"the kernel dropped nothing: {_drops(drops)}"
    assert store.by_rule() == {}, [(f.rule, f.actual, f.evidence) for f in store.order]
    assert summary["findings"] == 0


@pytest.mark.slow
def test_the_same_campaign_finds_a_node_that_does_not_ack_a_command(tmp_path: Path) -> None:
    """The oracle is not blinded: the same small-buffer node, faulty (WP_On never ACKed, no
    copy), is found under MCP-ACK-1 and the finding is confirmed by replay."""
    cfg = FuzzConfig(spawn=plain_command("--rcvbuf", str(SMALL_RCVBUF), "--fault", "no-ack-wp-on"),
                     seed=7, duration=max(CAMPAIGN_S, 30.0), out=str(tmp_path), rto=RTO,
                     extra={"stop_on_rule": "MCP-ACK-1"})
    store = FindingStore(tmp_path, cfg.replay_args())
    run_campaign(cfg, store)
    found = [f for f in store.order if f.rule == "MCP-ACK-1"]
    assert found, store.by_rule()
    assert any("none ACKed" in e for e in found[0].evidence), found[0].evidence

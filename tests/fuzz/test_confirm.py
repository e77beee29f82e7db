"""Issue 18 item 9: findings that stand up. A finding counts only when every confirming replay
shows it (N of N), and a missing ACK is the node's only when retransmitted copies go unACKed
too (UDP may lose a datagram even on loopback, under a burst)."""

from __future__ import annotations

import socket
import threading
from types import SimpleNamespace

import pytest

import mcp_conform.fuzz.triage  # noqa: F401  (the attribute the next line's name reaches)
from mcp_conform import fuzz
from mcp_conform.fuzz.findings import NO_INPUT, FindingStore
from mcp_conform.fuzz.oracles import Flaw, Input, judge_exchange
from mcp_conform.fuzz.replay import Outcome
from mcp_conform.fuzz.triage import CONFIRM_N, Triage
from mcp_conform.harness.driver import TargetDriver
from mcp_conform.spec.codec import Action, Message, decode, encode


class _Target:
    """What triage reads of a target: its config, liveness; replays are faked."""

    spawned = True
    cfg = SimpleNamespace(mode="spawn", mavlink=False, role="drone")
    run_cfg = SimpleNamespace(spawn="node")

    def check_live(self, why: str) -> None:
        return None


@pytest.mark.parametrize("shows, kept", [([True] * (1 + CONFIRM_N), True),
                                         ([True] * CONFIRM_N + [False], False),
                                         ([True, True, False, True], False)])
def test_a_finding_needs_every_confirming_replay(monkeypatch: pytest.MonkeyPatch, shows, kept) -> None:
    """Before: the minimal sequence was confirmed once in two tries, and findings confirmed
    so replayed 0 of 3 afterwards."""
    flaw = Flaw("MCP-ACK-1", "an ACK naming seq 7", "no ACK of WP_OFF seq 7", culprit=0)
    replies = iter(shows)

    def replay(target, seq, pace, scenario=None):  # noqa: ANN001, ANN202
        return Outcome([flaw] if next(replies) else [])

    monkeypatch.setattr(fuzz.triage, "run_sequence", replay)
    store = FindingStore(None)
    triage = Triage(_Target(), store, "stateless", seed=1)  # type: ignore[arg-type]
    triage.baseline_rules = set()  # the node's baseline is clean (test_the_baseline_... below)
    data = encode(Message(1, 0, 7, Action.WP_OFF))
    found = triage.consider(flaw, [Input.of(data)], "batch")
    assert (found is not None) is kept and (len(store) == 1) is kept
    assert triage.unconfirmed == (0 if kept else 1)


@pytest.mark.parametrize("baseline_shows", [True, False])
def test_the_baseline_decides_whether_the_input_is_blamed(monkeypatch: pytest.MonkeyPatch, baseline_shows) -> None:
    """Issue 36 item 2: a rule that a valid WP_Off in the input's place breaks too, every
    time, is the node's behaviour (one finding, shape NO_INPUT; later flaws counted there);
    a clean baseline leaves the input to be confirmed as before."""
    flaw = Flaw("MCP-ACK-3", "an ACK to the sender", "ACK sent to 4095", culprit=0)
    sent: list[list[bytes]] = []

    def replay(target, seq, pace, scenario=None):  # noqa: ANN001, ANN202
        sent.append(list(seq))
        baseline = seq and seq[0][11:13] == (0x0B5E).to_bytes(2, "big")
        return Outcome([flaw] if baseline_shows or not baseline else [])

    monkeypatch.setattr(fuzz.triage, "run_sequence", replay)
    store = FindingStore(None)
    target = _Target()
    target.node_id = 1  # type: ignore[attr-defined]
    triage = Triage(target, store, "stateless", seed=1)  # type: ignore[arg-type]
    data = encode(Message(1, 0, 7, Action.OBSTACLES_LIST, ()))
    triage.consider(flaw, [Input.of(data)], "batch")
    triage.consider(flaw, [Input.of(data)], "batch")
    assert [f.shape == NO_INPUT for f in store.order] == [baseline_shows], [f.shape for f in store.order]
    # (its occurrences: the baseline's own, then each flaw counted there)
    if baseline_shows:
        assert store.order[0].occurrences == 3 and all(data not in s for s in sent)
        assert len(sent) == CONFIRM_N  # the baseline, once for the worker: not per flaw
    else:
        assert any(s == [data] for s in sent)


class _Node:
    """A UDP node that ACKs every unicast, except the first copy of the seqs in ``lose``
    (as if the kernel had dropped it) and every copy of those in ``never``."""

    def __init__(self, lose: set[int], never: set[int]) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.settimeout(0.05)
        self.lose, self.never, self.seen = lose, never, set()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def _run(self) -> None:
        own = 100
        while not self.stop.is_set():
            try:
                data, addr = self.sock.recvfrom(2048)
            except TimeoutError:
                continue
            m = decode(data)
            if m.seq in self.never or (m.seq in self.lose and m.seq not in self.seen):
                self.seen.add(m.seq)
                continue
            own += 1
            self.sock.sendto(encode(Message(m.src, 1, own, Action.ACK, m.seq)), addr)

    def close(self) -> None:
        self.stop.set()
        self.thread.join()
        self.sock.close()


@pytest.mark.parametrize("lose, never, flagged", [({500}, set(), False), (set(), {500}, True)])
def test_a_missing_ack_counts_only_if_the_retransmissions_go_unacked_too(lose, never, flagged) -> None:
    node = _Node(lose, never)
    drv = TargetDriver(node.sock.getsockname(), ("127.0.0.1", 0))
    drv.open()
    try:
        target = SimpleNamespace(driver=drv, node_id=1, broadcast_id=0xFFFF, rto=0.2, ack_window=0.2,
                                 fate=lambda: {"alive": True}, impairment_spoiled=lambda: [], observations={})
        mark = drv.mark()
        data = encode(Message(1, 0, 500, Action.WP_OFF))
        drv.send_raw(data)
        probe = drv.send(Action.WP_OFF, None, 1)
        assert drv.wait_for(drv.ack_for(probe), 2.0, mark) is not None
        flaws = judge_exchange([Input.of(data)], target, mark, SimpleNamespace(acked=True, sent=probe, copies=1))
        assert ("MCP-ACK-1" in {f.rule for f in flaws}) is flagged, flaws
    finally:
        drv.close()
        node.close()

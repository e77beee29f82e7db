"""The fuzzer's withheld-ACK oracle (``fuzz.oracles.judge_withheld``, behind ``fuzz.replay`` and
``fuzz.engine_stateful``) counts a fresh node's Mission_Ready copies by number, as the drone
suite's cases (``conformance.cases.ready_copies``) and the trace monitor (``judge._monitor_rtx``)
do: one judge (``judge.copies_by_number``), one verdict.

"Retransmissions of the same message are identified by repeating sequence number": a node that
sends seq N twice, gives it up (retry limit 1) and announces again under seq N+1 (the Node.js
drone's ``--retries 1 --reannounce``) had 2 copies while the ACK was withheld -- MCP-RTX-1's
finding, as the suite fails it -- and every copy of N repeats its number and bytes: not
MCP-SEQ-2, which the oracle found taking N+1 for N's third copy. A node whose every copy takes a
new number (the ``rtx-new-seq`` fault) keeps its MCP-SEQ-2 finding.
"""

from __future__ import annotations

import time
from types import SimpleNamespace

from mcp_conform.conformance.cases import ready_copies
from mcp_conform.fuzz.oracles import judge_withheld
from mcp_conform.harness.driver import Datagram, read_header
from mcp_conform.spec.codec import Action, Message, decode, encode

NODE = 1


def _ready(seq: int) -> Datagram:
    data = encode(Message(0, NODE, seq, Action.MISSION_READY, None))
    return Datagram(0, time.monotonic(), time.time_ns(), data, ("127.0.0.1", 1), decode(data), None,
                    read_header(data))


def test_a_reannounce_after_two_copies_is_rtx1_not_seq2() -> None:
    """[N, N, N+1], then a copy of N+1 after the wrong ACK (it goes on with its new message)."""
    copies = [_ready(40), _ready(40), _ready(41)]
    flaw = judge_withheld(copies, _ready(41), 3, True)
    assert flaw is not None and flaw.rule == "MCP-RTX-1", flaw
    assert flaw.actual.startswith("2 copies seen"), flaw.actual
    assert "seq 41" in flaw.actual, flaw.actual  # the new message named, as the suite names it
    # the suite's view of the same datagrams: seq 40's two copies, seq 41 a new message
    st = SimpleNamespace(copies=copies)
    assert len(ready_copies.by_number(st)) == 2 and not ready_copies.renumbered(st)


def test_a_new_message_after_enough_copies_breaks_nothing() -> None:
    """Three copies of N (the rule's least: a retry limit of 2), then N+1: a correct node that
    announces again after its give-up (withholding asked for 3, N+1 read with them)."""
    copies = [_ready(7), _ready(7), _ready(7), _ready(8)]
    assert judge_withheld(copies, _ready(8), 3, True) is None


def test_renumbered_copies_keep_seq2() -> None:
    """The ``rtx-new-seq`` shape: seq N once, then the same message under N+1, N+2."""
    flaw = judge_withheld([_ready(7), _ready(8), _ready(9)], _ready(10), 3, True)
    assert flaw is not None and flaw.rule == "MCP-SEQ-2", flaw
    assert "seq 8" in flaw.actual and "seq 9" in flaw.actual, flaw.actual


def test_copies_that_repeat_the_number_are_judged_as_before() -> None:
    same = [_ready(7), _ready(7), _ready(7)]
    assert judge_withheld(same, _ready(7), 3, True) is None
    assert judge_withheld(same[:2], _ready(7), 3, True).rule == "MCP-RTX-1"
    assert judge_withheld(same, None, 3, True).rule == "MCP-RTX-2"

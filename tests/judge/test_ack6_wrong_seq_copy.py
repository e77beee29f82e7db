"""MCP-ACK-6 ("A node never ACKs an ACK") against an ACK that may as well answer a message copy
with a wrong number (MCP-ACK-2), in the trace monitor.

The C++ manager of examples/mcp_cpp/manager built ``FAULT=ACK_WRONG_SEQ`` ACKs every copy
naming its seq + 1. Drone 1's Mission_Ready is 1307, so every ACK names 1308 -- a number no
datagram carried until drone 1's own ACK of Start_Mission took it (the runner's drones number
ACKs and messages from one counter, D-5). The next copy of Mission_Ready drew, 0.2 ms later,
one more ACK naming 1308: the monitor failed it as "ACK of the ACK with seq 1308". Two
explanations fit the trace: an ACK of that ACK (MCP-ACK-6), or the copy's answer with a wrong
number (MCP-ACK-2); each breaks another rule, so the ACK proves neither (D-9's principle). The
copy's deadline decides: when it drew an ACK naming its number too, the ACK named what it
ACKed; else neither is proven (the node's ACKs naming a number nothing carried prove its
MCP-ACK-2 anyway). An ACK of an ACK with no such copy before it (within the wait of a late
ACK) is MCP-ACK-6 as before."""

from __future__ import annotations

import pytest

from mcp_conform.judge.monitor import late_ack_wait_s
from mcp_conform.spec.codec import Action
from tests.judge.monitor_faults import FAULTY
from tests.judge.monitor_scripts import Script


def _rules(s: Script) -> set[str]:
    return {v.rule for v in s.judge()}


def wrong_seq_manager(*, right_ack_too: bool = False, copy_before_s: float | None = 0.0002) -> Script:
    """The manager's view of drone 1 (ready = 1307): each Mission_Ready copy ACKed 0.2 ms later
    naming 1308; a Start_Mission the drone ACKs with its next number, 1308; then one more copy
    of Mission_Ready, ``copy_before_s`` before the manager's ACK naming 1308 (None: no copy,
    the ACK alone, past the wait of a late ACK after the last one), the copy ACKed with its own
    number as well when ``right_ack_too``."""
    s = Script((1,), seqs={1: 1307, 0: 31618})
    ready, data = s.send(1, 0, Action.MISSION_READY)
    for _ in range(5):
        s.tick(0.0002)
        s.ack(0, 1, ready + 1)  # names a number nothing carried: MCP-ACK-2
        s.tick(s.rto - 0.0002)
        s.raw(1, data)
    s.tick(0.0002)
    s.ack(0, 1, ready + 1)
    s.tick(0.1)
    start, _ = s.send(0, 1, Action.START_MISSION)
    s.tick(0.0005)
    s.ack(1, 0, start)  # drone 1's ACK takes seq 1308
    assert s.seq[1] == ready + 2
    if copy_before_s is not None:
        s.tick(0.3)
        s.raw(1, data)  # a copy of Mission_Ready
        s.tick(copy_before_s)
    else:
        s.tick(late_ack_wait_s(s.rto, s.ack_window) + 0.1)
    s.ack(0, 1, ready + 1)  # names the drone's ACK's number: ACK-6, or the copy's wrong ACK
    if right_ack_too:
        s.tick(0.0003)
        s.ack(0, 1, ready)
    s.tick(0.5)
    return s


def test_an_ack_right_after_an_unanswered_copy_is_no_proven_ack_of_an_ack():
    """The C++ manager's trace: fails on the monitor before this fix (MCP-ACK-6)."""
    rules = _rules(wrong_seq_manager())
    assert "MCP-ACK-6" not in rules, rules
    assert "MCP-ACK-2" in rules, rules


def test_the_copy_answered_with_its_number_leaves_an_ack_of_the_ack():
    """The copy drew its own ACK (after the one naming 1308): that one answered the copy, so
    the ACK naming 1308 answered the drone's ACK (the monitor's reading of a copy answered)."""
    assert "MCP-ACK-6" in _rules(wrong_seq_manager(right_ack_too=True))


@pytest.mark.parametrize("copy_before_s", [None, "past-the-wait"], ids=["no-copy", "copy-too-early"])
def test_without_a_waiting_copy_an_ack_of_an_ack_is_mcp_ack_6(copy_before_s):
    """No copy before the ACK, or one past the wait of a late ACK: nothing else it answers."""
    s = Script((1,))
    wait = late_ack_wait_s(s.rto, s.ack_window)
    before = None if copy_before_s is None else wait + 0.1
    assert "MCP-ACK-6" in _rules(wrong_seq_manager(copy_before_s=before))


def test_the_monitors_ack_of_an_ack_fault_still_fails_ack_6():
    assert "MCP-ACK-6" in {v.rule for v in FAULTY["ack6-acks-ack"].build().judge()}

"""A drone that writes each delivered Mav_Passthrough frame twice (MCP-PAY-8's fault, the sample
node's ``--fault passthrough-twice``) is not taken for one that delivers a duplicate again
(MCP-DUP-1) when a copy of the message was sent between its two writes (issue 38).

The monitor counted the copies sent before each write of the frame, and a second write with a
copy more before it was a second delivery, the copy's: MCP-DUP-1 (the reference-shaped trace
below, a write 0.5 ms before the manager's retransmission and one 0.5 ms after it, was
MCP-DUP-1 on a complete trace). A copy is taken for a write's cause only once the earlier
delivery's count on the link has stood still (the case's ``quiet_count``: half the ACK window,
at least 0.1 s), as the case sends its copy (``conformance.drone_case``'s ``redeliver``). A copy
that left while the writes were still coming leaves two explanations, the earlier delivery
written twice (MCP-PAY-8) or the copy delivered again (MCP-DUP-1), neither rule broken in both:
neither is reported from that write (as D-9 for ACKs). One judge: the live monitor and
``mcp-capture check`` both run ``judge.monitor``.
"""

from __future__ import annotations

import pytest

from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.spec.mavframe import heartbeat_frame
from tests.judge.monitor_scripts import Script


def _rules(s: Script, complete: bool) -> list[tuple[str, int]]:
    return sorted((v.rule, v.node) for v in s.judge(complete=complete))


def forwarded_twice(first_write_ms: float, second_write_ms: float) -> Script:
    """Drone 1 writes a Mav_Passthrough's frame twice, ``first_write_ms`` and ``second_write_ms``
    after it came, and ACKs it once both are done (the ACK after the work: a reading the
    documents leave open); the manager's retransmission, a timeout after the first copy, comes
    around them, and is ACKed and discarded."""
    s = Script((1,), challenge=2)
    s.ready(1)
    s.start(1)
    s.passthrough(1, heartbeat_frame(seq=1))  # a first frame, written once
    frame = heartbeat_frame(seq=2)
    seq, _ = s.send(0, 1, Action.MAV_PASSTHROUGH, frame)
    at = 0.0
    for ms, what in sorted([(first_write_ms, "write"), (s.rto * 1000, "copy"), (second_write_ms, "write")]):
        s.tick((ms - at) / 1000)
        at = ms
        if what == "copy":
            s.raw(0, encode(Message(1, 0, seq, Action.MAV_PASSTHROUGH, frame)), to=1)
        else:
            s.vehicle(1, "frame", frame=frame)
    s.tick(0.001)
    s.ack(1, 0, seq)
    s.tick(0.001)
    s.ack(1, 0, seq)  # the copy ACKed again (MCP-ACK-1), not delivered
    s.tick(0.1)
    s.challenge_steps()
    s.end(1)
    return s


@pytest.mark.parametrize("complete", [False, True], ids=["lossy", "complete"])
@pytest.mark.parametrize(("first_write_ms", "second_write_ms"), [(199.5, 200.5), (198.0, 203.0)])
def test_a_copy_between_the_two_writes_of_one_delivery_is_no_dup1(complete: bool, first_write_ms: float,
                                                                  second_write_ms: float) -> None:
    s = forwarded_twice(first_write_ms, second_write_ms)
    assert _rules(s, complete) == []


@pytest.mark.parametrize("complete", [False, True], ids=["lossy", "complete"])
def test_the_writes_before_the_copy_are_pay8_as_before(complete: bool) -> None:
    s = forwarded_twice(190.0, 191.0)
    assert _rules(s, complete) == ([("MCP-PAY-8", 1)] if complete else [])


@pytest.mark.parametrize("complete", [False, True], ids=["lossy", "complete"])
def test_a_copy_after_the_count_stood_still_delivered_again_is_dup1(complete: bool) -> None:
    """The same shape, the first write 20 ms after the message came and 180 ms before the copy
    (more than the 125 ms the count must stand still at a 0.25 s ACK window): the write after
    the copy is its delivery, MCP-DUP-1, as before."""
    s = forwarded_twice(20.0, 201.0)
    assert _rules(s, complete) == ([("MCP-DUP-1", 1)] if complete else [])

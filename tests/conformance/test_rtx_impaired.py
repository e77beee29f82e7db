"""MCP-RTX-2 through ``--impair`` (issue 38): a copy after the wrong ACKs proves the node
went on retransmitting only if the node had both wrong ACKs when it sent it and the link did
not make it (``conformance.link_copies``)."""

from __future__ import annotations

import pytest

from mcp_conform.conformance.link_copies import credited_copy
from mcp_conform.harness.driver import Datagram, Sent
from mcp_conform.harness.impair import Decision, Delivery
from mcp_conform.harness.impair_link import ImpairEvent
from mcp_conform.spec.codec import Action, Message, encode

from .runner_helpers import FAST, run_conform, sample_node_command

READY = encode(Message(0, 1, 500, Action.MISSION_READY, None))
T0 = 100.0


def _ack(t: float, named: int, src: int = 0) -> Sent:
    data = encode(Message(1, src, 7, Action.ACK, named))
    return Sent(t, int(t * 1e9), data, ("127.0.0.1", 9), 1, src, 7, int(Action.ACK))


def _copy(t: float, index: int) -> Datagram:
    return Datagram(index, t, int(t * 1e9), READY, ("127.0.0.1", 9), None, None, (0, 1, 500, 0))


class _Link:
    """The record an ``ImpairedLink`` keeps (``events``), with real decisions in it."""

    def __init__(self, *events: ImpairEvent) -> None:
        self.events = list(events)


def _event(t: float, direction: str, data: bytes, *deliveries: Delivery, dropped: str | None = None) -> ImpairEvent:
    d = Decision(direction, 0, len(data), tuple(deliveries), dropped)
    return ImpairEvent(t, int(t * 1e9), d, "a datagram", True)


WRONG = [_ack(T0, 0x8000 + 500), _ack(T0 + 0.0001, 500, src=0x101)]


def test_on_a_clean_link_the_first_copy_after_the_wrong_acks_is_credited():
    copies = [_copy(T0 + 0.2, 5), _copy(T0 + 0.4, 6)]
    assert credited_copy(None, WRONG, copies) == (copies[0], [])
    assert credited_copy(_Link(), WRONG, copies) == (copies[0], [])


def test_a_wrong_ack_the_link_dropped_leaves_no_copy_credited():
    """The seed=11 run: both wrong ACKs dropped, the node (stopping on any ACK) never had
    them and went on: its copies prove nothing about MCP-RTX-2."""
    link = _Link(_event(T0 + 0.0002, "tx", WRONG[0].data, dropped="loss"))
    copies = [_copy(T0 + 0.2, 5), _copy(T0 + 0.4, 6)]
    credited, why = credited_copy(link, WRONG, copies)
    assert credited is None and len(why) == 2 and "never got it" in why[0], why


def test_a_wrong_ack_held_by_the_link_credits_only_the_copies_after_it_landed():
    link = _Link(_event(T0 + 0.0002, "tx", WRONG[1].data, Delivery(0.3, WRONG[1].data, ("reorder",))))
    copies = [_copy(T0 + 0.2, 5), _copy(T0 + 0.4, 6)]
    credited, why = credited_copy(link, WRONG, copies)
    assert credited is copies[1] and len(why) == 1 and "reached the node" in why[0], why


def test_a_wrong_ack_corrupted_on_its_way_is_not_one_the_node_had():
    link = _Link(_event(T0 + 0.0002, "tx", WRONG[0].data, Delivery(0.0, WRONG[0].data[:-1], ("cut",))))
    assert credited_copy(link, WRONG, [_copy(T0 + 0.2, 5)])[0] is None


def test_a_copy_the_link_held_or_duplicated_is_not_the_nodes():
    """A Mission_Ready copy the node sent before the wrong ACKs, held by the link (reorder,
    or the delayed second of a duplicate) into the window, is not credited; the node's own
    copy after it is."""
    held = _event(T0 - 0.05, "rx", READY, Delivery(0.0, READY, ()), Delivery(0.25, READY, ("dup", "reorder")))
    copies = [_copy(T0 + 0.2001, 5), _copy(T0 + 0.4, 6)]
    credited, why = credited_copy(_Link(held), WRONG, copies)
    assert credited is copies[1] and "the link's" in why[0], why
    assert credited_copy(_Link(held), WRONG, copies[:1])[0] is None


# ---------------------------------------------------------------------- end to end
ISSUE_38 = "loss=0.1,dup=0.05,reorder=0.1,seed=11"


@pytest.mark.slow
def test_a_node_stopping_on_any_ack_does_not_pass_rtx2_through_the_impairment():
    """Issue 38's measurement: ``sample_node --fault rtx-stop-on-any-ack`` through
    ``--impair loss=0.1,dup=0.05,reorder=0.1,seed=11`` passed MCP-RTX-2 (the link dropped
    both wrong ACKs; the decisions are seeded by each datagram's identity, so the same ones
    every run); without the impairment it fails. Now: skipped, the reason naming the drops."""
    spawn = ["--spawn", sample_node_command("--fault", "rtx-stop-on-any-ack"), "--mavlink", *FAST,
             "--select", "MCP-RTX-2"]
    clean = run_conform(*spawn)
    bad = run_conform(*spawn, "--impair", ISSUE_38)
    assert clean.rules.get("MCP-RTX-2") == "failed", clean.explain()
    assert bad.rules.get("MCP-RTX-2") == "skipped", bad.explain()
    case = bad.cases_with("skipped")[0]
    assert "spoiled by the impairment" in case["reason"] and "drop" in case["reason"], case

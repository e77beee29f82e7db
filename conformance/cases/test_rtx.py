"""RTX — retransmission by the node, observed on its Mission_Ready while the runner
withholds the ACK (the startup phase).

"This allows a sender to guarantee delivery of a unicast messages by retransmitting the
message until an acknowledgement is received."
"""

from __future__ import annotations

from mcp_conform.conformance.cases.ready_copies import (
    by_number,
    describe_new,
    new_numbers,
    renumbered,
)
from mcp_conform.conformance.link_copies import credited_copy
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.drone_rtx2 import ready_before_wrong_acks
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action

MIN_COPIES = int(SPEC.params["min_copies"])
_READY = int(Action.MISSION_READY)


@rules("MCP-RTX-1", "MCP-FLOW-1", phase="startup")
def test_mission_ready_is_retransmitted_until_acked(node):
    """A node that gave up short of the copies and exited (``harness.drone_giveup``, spawn mode)
    is judged on them, its exit in the evidence; the cases after it ran on it restarted. Copies
    are counted by number (``cases.ready_copies``): a new Mission_Ready after a give-up is a new
    message; copies renumbered are MCP-SEQ-2's, and count for nothing here."""
    st = node.require_startup("MCP-RTX-1")
    if renumbered(st):
        raise Inconclusive(f"MCP-RTX-1: the node's Mission_Ready was sent once under its number, then again "
                           f"under new ones ({describe_new(st)}): not copies of one message (see MCP-SEQ-2)")
    copies = by_number(st)
    n = len(copies)
    gone = [f"then {st.gave_up.partition(', then ')[2]}; the cases after this one ran on it restarted, "
            "its Mission_Ready ACKed at once"] if st.gave_up else []
    if not gone and new_numbers(st):
        gone = [f"then a new Mission_Ready ({describe_new(st)}): a new message, not a copy "
                "(retransmissions repeat the number)"]
    node.expect_true(n >= MIN_COPIES and not st.copies_after_right_ack, "MCP-RTX-1",
                     f"at least {MIN_COPIES} copies while the ACK is withheld, none after the right ACK",
                     f"{n} cop{'y' if n == 1 else 'ies'} while withheld" + (f", {gone[0]}" if gone else "")
                     if n < MIN_COPIES else
                     f"{len(st.copies_after_right_ack)} copies after the right ACK "
                     f"(watched {st.stop_watch:.2f} s)",
                     [d.describe() for d in (st.copies_after_right_ack or copies)[:3]] + gone)


def _stopped_before_wrong_acks(node, st):
    """Why the node's next copy was overdue when the runner's wrong ACKs went out
    (``WithheldCopies.ended_before_wrong_acks``, as the manager role's case asks it), by its
    Mission_Ready copies that reached the runner before them. The runner sends them once it has
    the copies MCP-RTX-1 asks for, or once it waited for them in vain: a C drone's ``--retries 1``
    (two copies, the wrong ACKs 2.06 s after the last at --rto 0.3) failed MCP-RTX-2 before."""
    if not st.wrong_acks or not st.copies:
        return None
    return st.ended_before_wrong_acks(ready_before_wrong_acks(node.driver, st))


def _spoiled(node, st, first):
    """Through --impair: why no copy after ``st``'s wrong ACKs shows the node had them (None:
    one does, or the link is clean): a copy proves it only if the node had both wrong ACKs when
    it sent it and the link did not make it (``conformance.link_copies``)."""
    if first is None or node.driver.link is None:
        return None
    end = st.right_ack.t if st.right_ack is not None else float("inf")
    copies = [d for d in node.driver.received(first.index) if d.action == _READY and d.t <= end]
    credited, why = credited_copy(node.driver.link, st.wrong_acks, copies)
    return None if credited is not None else "; ".join(why[:3])


def _watched(st):
    """How long the runner watched for a copy after the wrong ACKs: until the right ACK (the
    wait ends early when the node exits)."""
    if st.right_ack is None or not st.wrong_acks:
        return st.wrong_ack_wait
    return min(st.wrong_ack_wait, st.right_ack.t - st.wrong_acks[-1].t)


def _judged_again(node, st):
    """The startup's copies stopped right after the wrong ACKs, ``MIN_COPIES`` or more before
    them (``WithheldCopies.limit_or_any_ack``): a retry limit of ``MIN_COPIES - 1``, the rule's
    configurable one (spec/mcp.yaml's ``min_copies``), and a node that stops on any ACK look the
    same (the C drone's ``--retries 2`` failed here). Judged on the second observation
    (``harness.drone_rtx2``): the node restarted, the wrong ACKs after a copy its first run's
    copies show its retry limit goes past; its next copy is owed unless a wrong ACK ended them.
    Attach mode cannot restart it: skipped, naming why."""
    n = len(ready_before_wrong_acks(node.driver, st))
    first_look = (f"first observation: {n} copies, then none within {_watched(st):.2f} s after the "
                  f"wrong ACKs: a retry limit of {n - 1} ends them there too")
    again = st.again
    if again is None:
        raise Inconclusive(f"MCP-RTX-2: {n} copies then none after the wrong ACKs: a retry limit of {n - 1} and "
                           "stopping on any ACK look the same; run with --spawn to tell")
    m = len(ready_before_wrong_acks(node.driver, again))
    if not again.wrong_acks or not 2 <= m < n:
        raise Inconclusive(f"MCP-RTX-2: {first_look}; the restarted node's wrong ACKs came after {m} of its "
                           f"copies, not after 2 to {n - 1}: they tell nothing more")
    stopped = _stopped_before_wrong_acks(node, again)
    if stopped is not None:
        raise Inconclusive(f"MCP-RTX-2: {first_look}; the restarted node had stopped retransmitting before "
                           f"its wrong ACKs were sent ({stopped})")
    later = again.copy_after_wrong_acks
    spoiled = _spoiled(node, again, later)
    if spoiled is not None:
        raise Inconclusive(f"MCP-RTX-2: spoiled by the impairment: {first_look}; on the restarted node no copy "
                           f"after the wrong ACKs shows it had them ({spoiled})")
    end = again.right_ack.t if again.right_ack is not None else None
    touched = node.session.spoiled_by_impairment(again.wrong_acks[0].t, end, lookback=False) if later is None else []
    if touched:  # through --impair: the copy owed may have been lost or held
        raise Inconclusive(f"MCP-RTX-2: spoiled by the impairment: {first_look}; on the restarted node no copy "
                           f"came after the wrong ACKs while the link dropped or held datagrams ({'; '.join(touched[:3])})")
    second_look = (f"second observation (the node restarted): the wrong ACKs after its copy {m}, "
                   + (f"its copy {m + 1} {later.t - again.wrong_acks[-1].t:.2f} s after them" if later is not None
                      else f"then no copy within {_watched(again):.2f} s, though its first run's {n} copies "
                      f"show its retry limit reaches a copy {m + 1}"))
    node.expect_true(later is not None, "MCP-RTX-2",
                     "retransmission goes on after an ACK with the wrong seq and one from the wrong src",
                     second_look, [first_look, second_look]
                     + [f"wrong ACK: {s.data.hex(' ')}" for s in (*st.wrong_acks, *again.wrong_acks)])
    node.info(f"MCP-RTX-2: {first_look}; {second_look}")


@rules("MCP-RTX-2", phase="startup")
def test_only_the_right_ack_ends_retransmission(node):
    st = node.require_startup("MCP-RTX-2")
    if st.gave_up is not None:  # no wrong ACK was sent to a node gone (harness.drone_giveup)
        raise Inconclusive(f"MCP-RTX-2: {st.gave_up}, before the wrong ACKs were due: what it does with "
                           "a wrong ACK is not seen (see MCP-RTX-1)")
    if len(st.copies) < 2:
        raise Inconclusive("MCP-RTX-2: the node did not retransmit at all (see MCP-RTX-1)")
    stopped = _stopped_before_wrong_acks(node, st)
    if stopped is not None:
        raise Inconclusive(f"MCP-RTX-2: the node had stopped retransmitting before the wrong ACKs were "
                           f"sent ({stopped}): they show nothing of what it does with a wrong ACK "
                           "(see MCP-RTX-1)")
    if st.limit_or_any_ack(ready_before_wrong_acks(node.driver, st)):
        _judged_again(node, st)
        return
    first = st.copy_after_wrong_acks
    spoiled = _spoiled(node, st, first)
    if spoiled is not None:
        raise Inconclusive(f"MCP-RTX-2: spoiled by the impairment: no copy after the wrong ACKs shows the "
                           f"node had them ({spoiled})")
    node.expect_true(first is not None, "MCP-RTX-2",
                     "retransmission goes on after an ACK with the wrong seq and one from the wrong src",
                     f"no copy within {st.wrong_ack_wait:.2f} s after them",
                     [f"wrong ACK: {s.data.hex(' ')}" for s in st.wrong_acks])


@rules("MCP-RTX-3", phase="startup")
def test_copies_are_evenly_spaced(node):
    """The gaps between copies that repeat the first's number (``cases.ready_copies``)."""
    st = node.require_startup("MCP-RTX-3")
    if renumbered(st):
        raise Inconclusive(f"MCP-RTX-3: the node's Mission_Ready was sent once under its number, then again "
                           f"under new ones ({describe_new(st)}): not copies of one message (see MCP-SEQ-2)")
    copies = by_number(st)
    ts = [d.t for d in copies]
    node.expect_even_spacing([b - a for a, b in zip(ts, ts[1:], strict=False)],
                             run_delays=[d.run_delay for d in copies])


@rules("MCP-RTX-4")
def test_broadcasts_are_not_retransmitted(node):
    node.require_observable("MCP-RTX-4")

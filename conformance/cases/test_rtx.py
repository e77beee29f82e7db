"""RTX — retransmission by the node, observed on its Mission_Ready while the runner
withholds the ACK (the startup phase).

"This allows a sender to guarantee delivery of a unicast messages by retransmitting the
message until an acknowledgement is received."
"""

from __future__ import annotations

from mcp_conform.conformance.link_copies import credited_copy
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action

MIN_COPIES = int(SPEC.params["min_copies"])
_READY = int(Action.MISSION_READY)


@rules("MCP-RTX-1", "MCP-FLOW-1", phase="startup")
def test_mission_ready_is_retransmitted_until_acked(node):
    st = node.require_startup("MCP-RTX-1")
    n = len(st.copies)
    node.expect_true(n >= MIN_COPIES and not st.copies_after_right_ack, "MCP-RTX-1",
                     f"at least {MIN_COPIES} copies while the ACK is withheld, none after the right ACK",
                     f"{n} cop{'y' if n == 1 else 'ies'} while withheld" if n < MIN_COPIES else
                     f"{len(st.copies_after_right_ack)} copies after the right ACK "
                     f"(watched {st.stop_watch:.2f} s)",
                     [d.describe() for d in (st.copies_after_right_ack or st.copies)[:3]])


def _stopped_before_wrong_acks(node, st):
    """Why the node's next copy was overdue when the runner's wrong ACKs went out
    (``WithheldCopies.ended_before_wrong_acks``, as the manager role's case asks it), by its
    Mission_Ready copies that reached the runner before them. The runner sends them once it has
    the copies MCP-RTX-1 asks for, or once it waited for them in vain: a C drone's ``--retries 1``
    (two copies, the wrong ACKs 2.06 s after the last at --rto 0.3) failed MCP-RTX-2 before."""
    if not st.wrong_acks or not st.copies:
        return None
    t_wrong = st.wrong_acks[0].t
    return st.ended_before_wrong_acks([d.t for d in node.driver.received(st.copies[0].index)
                                       if d.action == _READY and d.t <= t_wrong])


@rules("MCP-RTX-2", phase="startup")
def test_only_the_right_ack_ends_retransmission(node):
    st = node.require_startup("MCP-RTX-2")
    if len(st.copies) < 2:
        raise Inconclusive("MCP-RTX-2: the node did not retransmit at all (see MCP-RTX-1)")
    stopped = _stopped_before_wrong_acks(node, st)
    if stopped is not None:
        raise Inconclusive(f"MCP-RTX-2: the node had stopped retransmitting before the wrong ACKs were "
                           f"sent ({stopped}): they show nothing of what it does with a wrong ACK "
                           "(see MCP-RTX-1)")
    first = st.copy_after_wrong_acks
    if first is not None and node.driver.link is not None:
        # through --impair: a copy proves it only if the node had both wrong ACKs when it sent
        # it and the link did not make it (``conformance.link_copies``)
        end = st.right_ack.t if st.right_ack is not None else float("inf")
        copies = [d for d in node.driver.received(first.index) if d.action == _READY and d.t <= end]
        credited, why = credited_copy(node.driver.link, st.wrong_acks, copies)
        if credited is None:
            raise Inconclusive("MCP-RTX-2: spoiled by the impairment: no copy after the wrong ACKs "
                               "shows the node had them (" + "; ".join(why[:3]) + ")")
    node.expect_true(first is not None, "MCP-RTX-2",
                     "retransmission goes on after an ACK with the wrong seq and one from the wrong src",
                     f"no copy within {st.wrong_ack_wait:.2f} s after them",
                     [f"wrong ACK: {s.data.hex(' ')}" for s in st.wrong_acks])


@rules("MCP-RTX-3", phase="startup")
def test_copies_are_evenly_spaced(node):
    st = node.require_startup("MCP-RTX-3")
    node.expect_even_spacing(st.gaps(), run_delays=st.run_delays())


@rules("MCP-RTX-4")
def test_broadcasts_are_not_retransmitted(node):
    node.require_observable("MCP-RTX-4")

"""The batch's verdicts do not depend on how the cases' messages interleave (issue 35): a
correct node that remembers only the seq it last delivered from each src (MCP-DUP-1's own
words; an older copy is MCP-DUP-4's open question) is the independent node
(tests/conformance/nodes/independent_node.py, one thread, one ``select`` loop) at its
default. Beside the batch's other cases, a message of theirs that reached the node between
MCP-DUP-1's message and its copy made the copy a late copy of an older message, delivered
again: ``DUP/test_same_seq_twice_is_delivered_once ended CaseFailure`` in every run, the
batch thrown away and every case run again alone.

Here the interleaving is forced, not hoped for: a neighbour case of the batch sends a
WP_Off (a message the node delivers) as soon as MCP-DUP-1's first probe has reached the
vehicle, well before its copy (half an ACK window later). The real runner's batch
(``conformance._batch.run_batch``), the real session, vehicle and node.
"""

from __future__ import annotations

import shlex
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import pytest

from mcp_conform.conformance._batch import BatchRun, run_batch
from mcp_conform.conformance.cases.test_dup import test_same_seq_twice_is_delivered_once as dup_1
from mcp_conform.conformance.drone_case import CaseContext
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.drone_session import Session
from mcp_conform.spec.codec import Action

from .runner_helpers import FAST, run_conform

INDEPENDENT = Path(__file__).resolve().parent / "nodes" / "independent_node.py"
DUP_1 = "DUP/test_same_seq_twice_is_delivered_once"


def independent_node_command(*extra: str, rto: float = 0.2) -> str:
    words = [sys.executable, str(INDEPENDENT), "--id", "{id}", "--bind", "{target_host}:{target_port}",
             "--send-to", "{listen_host}:{listen_port}", "--mavlink", "{mavlink}", "--rto", str(rto), *extra]
    return " ".join(shlex.quote(w) if "{" not in w else w for w in words)


class _Item:
    """What the batch takes of a pytest item: its function, its id, the leader's context."""

    def __init__(self, fn, nodeid: str, case_id: str, rules: tuple[str, ...]) -> None:
        self.obj, self.nodeid, self.funcargs = fn, nodeid, {}
        self.rec = SimpleNamespace(id=case_id, rules=rules)


def test_a_message_of_another_case_between_the_copies_does_not_fail_mcp_dup_1():
    session = Session(RunConfig(spawn=independent_node_command(rto=0.3), mavlink=True, rto=0.3, ack_window=1.0))
    session.make_context = CaseContext
    try:
        session.start(observe_startup=False)
        v = session.vehicle
        learn = session.begin_case("learn", ("MCP-PAY-8",))
        learn.learn_passthrough("MCP-PAY-8")  # as the batch would, alone, first
        session.end_case(learn, "passed")
        assert session.passthrough_forwarded, session.node_evidence()
        seen = len(v.probe_tokens())
        wp_off: list = []

        def neighbour(node):
            assert v.wait_for(lambda: len(v.probe_tokens()) > seen, 5.0)  # MCP-DUP-1's first arrived
            ex = node.command(Action.WP_OFF)  # a message the node delivers, from the manager
            wp_off.append(ex)
            assert ex.acked

        items = [_Item(dup_1, "dup-1", DUP_1, ("MCP-DUP-1",)),
                 _Item(neighbour, "neighbour", "neighbour", ("MCP-ACK-1",))]
        state = SimpleNamespace(session=session, record=lambda item: item.rec)
        leader = items[0]
        leader.funcargs["node"] = session.begin_case(DUP_1, ("MCP-DUP-1",))
        batch = BatchRun()
        t0 = time.monotonic()
        run_batch(state, leader, items, batch)
        outcome = {m.ctx.case_id: m.exc for m in batch.members.values()}
        assert outcome == {DUP_1: None, "neighbour": None}, (outcome, batch.why)
        assert batch.kept, batch.why
        # the neighbour's WP_Off was held back until MCP-DUP-1's copy had gone: the node saw
        # the message and its copy in a row, as alone
        sent = session.driver.sent()
        copy = max(n for n, s in enumerate(sent) if s.action == int(Action.MAV_PASSTHROUGH) and s.t >= t0)
        assert wp_off and sent.index(wp_off[0].first) > copy
    finally:
        session.close()


@pytest.mark.slow
def test_the_independent_node_keeps_the_batch_and_passes():
    """The node the issue describes, end to end: the batch kept, every verdict a pass (or
    the skips and INFO a drone node has), as serial."""
    res = run_conform("--spawn", independent_node_command(), "--mavlink", *FAST)
    plan = res.report.get("schedule", {})
    assert plan.get("batch_outcome") == "kept", (plan.get("batch_outcome"), res.explain())
    assert res.rc == 0 and not res.cases_with("failed", "warned", "error"), res.explain()

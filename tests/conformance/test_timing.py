"""Issue 18 item 10: the node's retransmission period, seen at startup, against --rto. When
they disagree the tools say so and judge by what the node does: a correct node retransmitting
every 1.5 s is not failed under --rto 0.2 (before: MCP-RTX-1 by the run's monitor after its
first copy), and the fuzzer paces itself at the node's period."""

from __future__ import annotations

import pytest

from mcp_conform.harness.session_base import disagrees, timing_note
from mcp_conform.judge.monitor import Monitor
from mcp_conform.spec.codec import Action, Message, encode

from .runner_helpers import run_conform, sample_node_command

MS = 1_000_000


@pytest.mark.parametrize("period, rto, says", [(0.3, 5.0, True), (1.5, 0.2, True), (0.25, 0.2, False),
                                               (5.0, 5.0, False), (None, 0.2, False)])
def test_a_period_far_from_rto_is_said(period, rto, says):
    assert disagrees(period, rto) is says
    note = timing_note(period, rto, 3, "judged by the node's copies")
    assert (note is not None) is says
    if says:
        assert f"every {period:.2f} s" in note and f"every {rto:g} s" in note


def test_a_lone_copy_is_not_overdue_before_the_descriptions_timeout():
    """Under --rto 0.2 a node whose second copy comes 1.5 s after its first is not failed in
    between: one copy says nothing of the node's period, the description's 5 s bounds it."""
    ready = encode(Message(0, 1, 9, Action.MISSION_READY))
    m = Monitor(rto=0.2, ack_window=0.25, complete=True)
    out = m.datagram(0, ("127.0.0.1", 2), ("127.0.0.1", 1), ready)
    other = encode(Message(5, 0, 1, Action.WP_OFF))  # traffic that shows time passing
    out += m.datagram(1400 * MS, ("127.0.0.1", 1), ("127.0.0.1", 3), other)
    for k in range(1, 4):
        out += m.datagram(k * 1500 * MS, ("127.0.0.1", 2), ("127.0.0.1", 1), ready)
    assert "MCP-RTX-1" not in {v.rule for v in out}
    # a lone copy then silence well past the description's timeout is still MCP-RTX-1
    m = Monitor(rto=0.2, ack_window=0.25, complete=True)
    out = m.datagram(0, ("127.0.0.1", 2), ("127.0.0.1", 1), ready)
    out += m.datagram(9000 * MS, ("127.0.0.1", 1), ("127.0.0.1", 3), other)
    assert "MCP-RTX-1" in {v.rule for v in out + m.finish()}


@pytest.mark.slow
def test_a_node_slower_than_rto_is_judged_by_what_it_does():
    res = run_conform("--spawn", sample_node_command(rto=1.5), "--mavlink", "--rto", "0.2",
                      "--ack-window", "0.25")
    assert res.rc == 0, res.explain()
    assert not res.rules_with("failed"), res.explain()
    assert res.report["monitor"]["violations"] == [], res.report["monitor"]["violations"]
    assert res.rules["MCP-RTX-1"] == "passed", res.explain()
    assert "timing: the node retransmits every 1.5" in res.output, res.output[-3000:]
    assert "retransmits every 1.5" in res.report["parameters"]["timing"]

"""MCP-ACK-3's case says truly why it cannot judge a manager whose ACKs all name a wrong seq.

The C++ manager built ``FAULT=ACK_WRONG_SEQ`` (every ACK names the copy's seq + 1) sent 148
ACKs, none attributed to a Mission_Ready or a probe; ``ACK/test_ack_is_addressed_to_the_drone_from_the_manager``
was skipped "the manager ACKed nothing" -- false. Now the skip names the ACKs and why they
cannot be judged here (which drone's message each answers is unknown: MCP-ACK-2's fault); a
manager that sent no ACK at all is still "ACKed nothing". The fault as the simulator's manager
model (tests/sim/test_manager_wrong_seq_ack_sim.py), and on recorded missions.
"""

from __future__ import annotations

import re

import pytest

from mcp_conform.conformance.cases_manager import test_ack
from mcp_conform.harness.errors import Inconclusive
from tests.sim.test_manager_wrong_seq_ack_sim import _case, _recorded, _run

ACK3_CASE = "ACK/test_ack_is_addressed_to_the_drone_from_the_manager"


def test_the_wrong_seq_managers_ack_3_skip_counts_its_acks():
    """Simulated run (seed 1, serial): skipped, naming how many ACKs the manager sent."""
    run = _run(1, True)
    case = _case(run, ACK3_CASE)
    assert case["outcome"] == "skipped", case
    assert "ACKed nothing" not in case["reason"], case
    found = re.search(r"none of the manager's (\d+) ACK\(s\) was attributed", case["reason"])
    assert found is not None and int(found.group(1)) > 0, case
    assert "(see MCP-ACK-2)" in case["reason"], case


def _reason(node) -> str:
    with pytest.raises(Inconclusive) as exc:
        test_ack.test_ack_is_addressed_to_the_drone_from_the_manager(node)
    return str(exc.value)


def test_on_a_recorded_mission_the_reason_counts_the_acks_or_says_there_were_none():
    """Two ACKs naming 1308 (none attributed: the mission's exchanges hold no reply) -> "none of
    the manager's 2 ACK(s)"; the same mission with the manager's datagrams gone -> "ACKed nothing"."""
    node = _recorded()
    assert len(node.mission().rx) == 2
    assert _reason(node).startswith("MCP-ACK-3: none of the manager's 2 ACK(s) was attributed to a drone's "
                                    "Mission_Ready or a probe")
    node.mission().rx = []
    assert _reason(node) == "MCP-ACK-3: the manager ACKed nothing"

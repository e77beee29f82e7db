"""A list retransmitted under a new number is one list (MCP-SEQ-2's fault), not a second one
(MCP-FLOW-4): the monitor took the renumbered copy for both -- the simulator's rtx-new-seq
manager (``sim.manager_faults``) failed MCP-FLOW-4 besides MCP-SEQ-2
(``tests/sim/test_manager_sim.py``). A list sent again after the first was ACKed, or after a
sender that retries could have given it up, is still a second one."""

from __future__ import annotations

from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action
from tests.judge.monitor_faults import _finish, _started
from tests.judge.monitor_scripts import Script

MIN_COPIES = int(SPEC.params["min_copies"])


def _verdicts(s: Script) -> dict[str, str]:
    m = s.monitor()
    s.judge(m)
    return m.verdicts()[0]


def _list_again(copies: int) -> Script:
    """The WP_List to drone 1 sent ``copies`` times unACKed, then under a new number (ACKed)."""
    s = _started()
    _seq, data = s.send(0, 1, Action.WP_LIST, tuple(s.items))
    for _ in range(copies - 1):
        s.tick(s.rto)
        s.raw(0, data, to=1)
    s.tick(s.rto)
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items))  # the same list, a new number
    s.tick(0.01)
    s.exchange(0, 2, Action.WP_LIST, tuple(s.items))
    return _finish(s, steps=False)


def test_a_list_renumbered_while_unacked_is_seq2_not_a_second_list() -> None:
    verdicts = _verdicts(_list_again(1))
    assert verdicts["MCP-SEQ-2"] == "failed"
    assert verdicts["MCP-FLOW-4"] == "passed"


def test_a_list_sent_again_after_it_could_be_given_up_is_a_second_one() -> None:
    verdicts = _verdicts(_list_again(MIN_COPIES))
    assert verdicts["MCP-FLOW-4"] == "failed"


def test_a_list_sent_again_after_its_ack_is_a_second_one() -> None:
    s = _started()
    s.challenge_steps()
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items))
    assert _verdicts(_finish(s, steps=False))["MCP-FLOW-4"] == "failed"

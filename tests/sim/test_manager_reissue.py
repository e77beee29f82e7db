"""A manager that gives up a Start_Mission short of MCP-RTX-1's copies and sends it again under a
new number is judged by its copies counted by number, by its cases as by the trace monitor (issue
38: one judge, ``judge.copies_by_number``; the drone role's re-announce, tests/sim/test_reannounce.py).

"Retransmissions of the same message are identified by repeating sequence number": two copies of
Start_Mission seq N, then (its retry limit of 1 reached, a timeout later) seq N+1, are two
messages. Seq N had 2 copies while its ACK was withheld -- MCP-RTX-1's fault; the monitor said so
("2 copies ..., then Start_Mission seq N+1 ...: it gave up") -- and every copy of N repeats its
number and bytes (MCP-SEQ-2 kept). The manager's cases took the runner's withheld copies (every
Start_Mission to that drone) as one message's: MCP-RTX-1 passed on 3 "copies" and MCP-SEQ-2
failed ("1 of 2 copies differ (seq N+1)"); grouping N+1 with N as one message
(``conformance.manager_case.messages``) counts by number too: once split, N+1 is not a command
to the drone before N's "answer" (MCP-BLK-3: N was given up), and the drone, its Start_Mission
sent again and ACKed, is not one the manager gave up on (the flow rules still judge it). A manager whose every copy takes a new number
(``rtx-new-seq``: one copy of each) keeps MCP-SEQ-2, and MCP-RTX-1 and MCP-RTX-3 (copies of one
message) no longer pass on its renumbered copies.
"""

from __future__ import annotations

import pytest

from mcp_conform.sim.manager_runner import run_manager_cases
from mcp_conform.spec import RULES

SHORT = {"rto": 0.2, "ack_window": 0.25}


def _must_failed(run) -> set[str]:
    return {r for r, o in run.rules.items() if o == "failed" and RULES[r].level == "MUST"}


def _case(run, rule: str, prefix: str = "RTX/") -> dict:
    return next(c for c in run.report["cases"] if rule in c["rules"] and c["id"].startswith(prefix))


@pytest.mark.parametrize("serial", [False, True], ids=["side-by-side", "serial"])
def test_a_manager_that_gives_up_short_and_sends_again_fails_rtx1_not_seq2(serial: bool) -> None:
    run = run_manager_cases("reissues-after-two", seed=2, serial=serial, **SHORT)
    assert any(m.reissued for m in run.managers), "the model never sent a given-up Start_Mission again"
    assert run.report.get("error") is None and run.rc == 1, run.explain()
    assert _must_failed(run) == {"MCP-RTX-1"}, run.explain()
    assert run.rules["MCP-SEQ-2"] == "passed" and run.rules["MCP-BLK-3"] == "passed", run.explain()
    rtx1 = _case(run, "MCP-RTX-1")
    assert rtx1["outcome"] == "failed" and rtx1["actual"].startswith("2 copies while withheld, then a new "
                                                                     "Start_Mission"), rtx1
    assert _case(run, "MCP-SEQ-2", "SEQ/")["outcome"] == "passed", run.explain()
    # it gave up a message, not the drone: drone 1 is not excused from the flow rules (its
    # Start_Mission sent again was ACKed, its mission went on)
    flow3 = _case(run, "MCP-FLOW-3", "FLOW/")
    assert flow3["outcome"] == "passed" and not any("gave up on drone" in n for n in flow3["notes"]), flow3
    # the monitor counts by number too: seq N's two copies, then a new message (one judge)
    mon = run.report["monitor"]
    assert {v["rule"] for v in mon["violations"]} == {"MCP-RTX-1"}, mon["violations"]


def test_a_manager_whose_retransmissions_take_new_numbers_keeps_seq2() -> None:
    """``rtx-new-seq``: MCP-SEQ-2 failed on all its copies; MCP-RTX-1 and MCP-RTX-3 do not pass on
    copies renumbered (they passed on 3 "copies" of 3 numbers)."""
    run = run_manager_cases("rtx-new-seq", seed=2, **SHORT)
    assert run.rules_with("failed", "warned") == {"MCP-SEQ-2": "failed"}, run.explain()
    assert _case(run, "MCP-SEQ-2", "SEQ/")["outcome"] == "failed", run.explain()
    for rule in ("MCP-RTX-1", "MCP-RTX-3"):
        case = _case(run, rule)
        assert case["outcome"] != "passed" and "under new ones" in (case.get("reason") or ""), case

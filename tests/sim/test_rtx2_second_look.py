"""MCP-RTX-2 where the startup's one observation cannot tell (issue 38; harness.drone_rtx2).

The startup withholds Mission_Ready's ACK for ``min_copies`` (3) copies, then sends the wrong
ACKs and awaits a 4th. A drone whose retry limit is 2 sends no 4th -- correct by the spec
(spec/mcp.yaml's ``min_copies``: "a retry limit of 2 is the rule's 'configurable' limit, no
violation") -- and neither does one that stops on any ACK (MCP-RTX-2's fault). Before, both
failed MCP-RTX-2 (the case and the monitor): the C drone's ``--retries 2`` did. Now, in spawn
mode, the runner restarts the node and sends the wrong ACKs after its 2nd copy: the 3rd is owed
by a node that keeps the rule (the first run showed its limit reaches it). In attach mode the
case is skipped, naming why. A node that retransmits on past the wrong ACKs is not restarted.
"""

from __future__ import annotations

import pytest

from mcp_conform.sim.runner import drone_factory, run_cases

RTX2 = "RTX/test_only_the_right_ack_ends_retransmission"
SHORT = {"rto": 0.2, "ack_window": 0.25}
DESCRIPTION = {"rto": 5.0, "ack_window": 2.0}


def _case(run):
    (case,) = [c for c in run.report["cases"] if c["id"] == RTX2]
    return case


def _limit_2(timing, seed, exits):
    """The reference drone with a retry limit of 2 (3 copies), correct otherwise; its
    Mission_Ready given up, it exits (as drone.py) or goes on (as the C drone)."""
    return drone_factory(rto=timing["rto"], seed=seed, retries=2, exits_on_give_up=exits)


@pytest.mark.parametrize("timing,mavlink,exits", [(SHORT, False, False), (SHORT, True, False),
                                                  (DESCRIPTION, False, False), (SHORT, False, True)],
                         ids=["short", "short-mavlink", "description-5s", "exits-on-give-up"])
def test_a_retry_limit_of_2_passes_rtx2_on_a_second_look(timing, mavlink, exits):
    run = run_cases(_limit_2(timing, 11, exits), seed=11, mavlink=mavlink, **timing)
    assert not run.rules_with("failed", "warned", "error"), run.explain()  # the monitor's included
    assert run.rc == 0, run.explain()
    case = _case(run)
    assert case["outcome"] == "passed", run.explain()
    (note,) = [n for n in case["notes"] if n.startswith("MCP-RTX-2:")]
    assert "first observation: 3 copies, then none" in note and "a retry limit of 2" in note, note
    assert "second observation (the node restarted): the wrong ACKs after its copy 2, its copy 3" in note, note
    assert run.models == 2  # restarted once, for the second look
    if not exits:  # the monitor's failure of the first look is vetoed, saying why (judge.veto)
        # (one that exits is ACKed right when it ends, before the monitor's deadline: no failure)
        vetoed = [v for v in run.report["monitor"].get("vetoed", []) if v["rule"] == "MCP-RTX-2"]
        assert vetoed and "a retry limit of 2" in vetoed[0]["explanation"], run.report["monitor"]


@pytest.mark.parametrize("timing", [SHORT, DESCRIPTION], ids=["short", "description-5s"])
def test_stopping_on_any_ack_still_fails_rtx2_and_no_other_must(timing):
    run = run_cases("rtx-stop-on-any-ack", seed=12, **timing)
    assert run.rules_with("failed", "warned", "error") == {"MCP-RTX-2": "failed"}, run.explain()
    case = _case(run)
    assert case["outcome"] == "failed", run.explain()
    assert case["actual"].startswith("second observation (the node restarted): the wrong ACKs after its copy 2, "
                                     "then no copy"), case
    assert any(e.startswith("first observation: 3 copies") for e in case["evidence"]), case
    assert run.models == 2


def test_attach_mode_skips_rtx2_naming_why():
    """No restart in attach mode: a retry limit of 2 and stopping on any ACK stay alike, and
    neither the case nor the monitor fails the node for it."""
    run = run_cases("rtx-stop-on-any-ack", seed=13, attach=True, **SHORT)
    case = _case(run)
    assert case["outcome"] == "skipped", run.explain()
    assert case["reason"] == ("MCP-RTX-2: 3 copies then none after the wrong ACKs: a retry limit of 2 and "
                              "stopping on any ACK look the same; run with --spawn to tell"), case
    assert not run.rules_with("failed", "warned", "error"), run.explain()
    assert run.models == 1


def test_a_node_that_retransmits_on_gets_no_second_look():
    """The common correct node (1000 retries) keeps retransmitting past the wrong ACKs: judged
    on the first observation, never restarted, no note."""
    run = run_cases(None, seed=14, **SHORT)
    case = _case(run)
    assert case["outcome"] == "passed" and not case["notes"], case
    assert run.models == 1

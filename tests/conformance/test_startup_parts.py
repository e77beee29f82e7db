"""The observed startup phase in parts (issue 38 item 5; ``harness.drone_session.STARTUP_PARTS``,
``conformance.schedule.shard_plan``): under ``mcp-conform --parallel`` the fix withheld
(MCP-BLK-5), Mission_Ready's copies with the watch after the right ACK (MCP-RTX-1's two
halves, MCP-BLK-4's time to arm) and the wrong ACKs (MCP-RTX-2) may be observed on different
node instances. Each part alone is observed as in the whole startup, with the waits of the
others left out: against the real session, vehicle and sample node (a correct one, and one
that stops retransmitting on any ACK, whose fault only the wrong ACKs' part shows).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import pytest

from mcp_conform.conformance.schedule import (
    PART_OF,
    PARTS,
    STARTUP_BOUND,
    part_of,
    startup_estimate,
)
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.drone_session import STARTUP_PARTS, Session
from mcp_conform.spec import SPEC

from .runner_helpers import run_conform, sample_node_command

MIN_COPIES = int(SPEC.params["min_copies"])
RTO = 0.2


def _started(parts: frozenset[str], *node_args: str) -> Session:
    session = Session(RunConfig(spawn=sample_node_command(*node_args, rto=RTO), mavlink=True, rto=RTO,
                                ack_window=0.25))
    session.start(parts=parts, diagnose=True)
    return session


def test_the_parts_are_the_sessions_and_each_startup_bound_case_has_one():
    assert set(PARTS) == STARTUP_PARTS
    assert set(PART_OF.values()) <= STARTUP_PARTS and part_of(next(iter(STARTUP_BOUND))) == "copies"


@pytest.mark.parametrize("rto,window", [(5.0, 2.0), (0.3, 2.0), (0.2, 0.25)])
def test_the_whole_startups_estimate_is_its_parts_waits(rto, window):
    whole = max(2 * window, 0.5) + 1.0 + MIN_COPIES * rto + max(window, 1.5 * rto)
    assert startup_estimate(PARTS, rto, window) == pytest.approx(whole)
    quick = startup_estimate((), rto, window)
    # the wrong ACKs alone wait for a second copy (the node's period) before them
    assert startup_estimate(("wrong",), rto, window) - quick == pytest.approx(2 * rto)


def test_the_copies_part_withholds_the_ack_for_the_copies_and_watches_after_the_right_one():
    session = _started(frozenset({"copies"}))
    try:
        st = session.startup
        assert st.observed and len(st.copies) >= MIN_COPIES, st.reason
        assert st.right_ack is not None and st.stop_watch > 0 and not st.copies_after_right_ack
        assert not st.wrong_acks and st.copy_after_wrong_acks is None  # not this part's
        assert st.fix_given_at is None and session.start_mission is not None and session.start_mission.acked
    finally:
        session.close()


@pytest.mark.parametrize("node_args,goes_on", [((), True), (("--fault", "rtx-stop-on-any-ack"), False)],
                         ids=["sample", "rtx-stop-on-any-ack"])
def test_the_wrong_acks_part_withholds_for_two_copies_then_watches_for_one_after_them(node_args, goes_on):
    """The wrong ACKs' part alone: the ACK withheld for two copies (the node's period), the two
    wrong ACKs (MCP-RTX-2), then a copy after them from a node that goes on retransmitting, and
    none from one that stops on any ACK (its fault only this part shows); the right ACK either
    way, the watch after it the copies' part's."""
    session = _started(frozenset({"wrong"}), *node_args)
    try:
        st = session.startup
        assert st.observed and len(st.copies) == 2, (st.reason, st.copies)
        assert len(st.wrong_acks) == 2 and (st.copy_after_wrong_acks is not None) == goes_on, st.copy_after_wrong_acks
        assert st.right_ack is not None and st.stop_watch == 0
        assert session.start_mission is not None and session.start_mission.acked
    finally:
        session.close()


def test_the_fix_part_holds_the_fix_then_acks_the_first_mission_ready():
    session = _started(frozenset({"fix"}))
    try:
        st = session.startup
        assert st.observed and st.node_connected_to_vehicle and st.fix_given_at is not None
        assert not st.ready_before_fix and not st.copies and not st.wrong_acks and st.right_ack is None
        assert session.start_mission is not None and session.start_mission.acked
    finally:
        session.close()


# ---------------------------------------------------------------------- end to end (slow)
#: the cases judged on the observed startup, and one judged on the whole run's traffic
STARTUP_CASES = ("BLK/test_nothing_new_while_mission_ready_awaits_its_ack", "BLK/test_no_mission_ready_without_a_gps_fix",
                 "FLOW/test_mission_ready_is_unicast_to_the_manager", "PAY/test_mission_ready_payload",
                 "RTX/test_mission_ready_is_retransmitted_until_acked",
                 "RTX/test_only_the_right_ack_ends_retransmission", "RTX/test_copies_are_evenly_spaced",
                 "SEQ/test_retransmission_repeats_seq_and_bytes", "SEQ/test_initial_sequence_number_is_recorded",
                 "BLK/test_no_arming_before_start_mission", "HDR/test_src_is_the_node_id")
#: timings at which the plan puts each part on an instance of its own (the copies' part, 3.5
#: timeouts, longer than another instance's start): the tests' short ones keep them together
SPLIT = ("--rto", "2.5", "--ack-window", "1")


@pytest.mark.slow
@pytest.mark.parametrize("label,node_args", [
    ("sample", ()),
    ("rtx-stop-on-any-ack", ("--fault", "rtx-stop-on-any-ack")),  # MCP-RTX-2: the wrong ACKs' part
    ("ready-without-fix", ("--fault", "ready-without-fix")),  # MCP-BLK-5: the fix's part
    ("arm-early", ("--fault", "arm-early")),  # MCP-BLK-4: armed during the copies' part's watch
], ids=["sample", "rtx-stop-on-any-ack", "ready-without-fix", "arm-early"])
def test_the_parts_on_three_instances_give_the_whole_startups_verdicts(label, node_args):
    spawn = sample_node_command(*node_args, rto=2.5)
    args = ("--spawn", spawn, "--mavlink", *SPLIT, *(f"--select={c}" for c in STARTUP_CASES))
    with ThreadPoolExecutor(max_workers=2) as pool:
        one, three = pool.map(lambda n: run_conform(*args, "--parallel", n, timeout=300), ["1", "3"])
    plan = three.report.get("schedule") or {}
    observers = {s["shard"] for s in plan.get("steps", []) if s["case"] in STARTUP_CASES[:-1]}
    assert len(observers) == 3, (plan, three.explain())  # each part on an instance of its own
    want = {c["id"]: c["outcome"] for c in one.report.get("cases", [])}
    got = {c["id"]: c["outcome"] for c in three.report.get("cases", [])}
    assert want and want == got, f"{label}: one instance {want}\nthree {got}\n{three.explain()}"
    assert three.rc == one.rc, three.explain()

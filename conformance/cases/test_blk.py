"""BLK — blocking and ordering semantics.

"The drone application must not ARM the autopilot before receiving this message."
"The drone application must verify GPS lock and other similar ready-to-fly capabilities
before sending this message." "The drone application should complete carrying out all
currently pending actions (from previously received commands), then execute an RTL."
"""

from __future__ import annotations

from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive, SilenceUnproven
from mcp_conform.spec.codec import Action
from mcp_conform.vehicle.records import describe_request, is_rtl_request


@rules("MCP-BLK-1", phase="startup")
def test_nothing_new_while_mission_ready_awaits_its_ack(node):
    """Stop-and-wait: while Mission_Ready is unACKed, only its copies and ACKs go out."""
    st = node.require_startup("MCP-BLK-1")
    node.expect_true(not st.others_while_waiting, "MCP-BLK-1",
                     "no new unicast message other than an ACK while Mission_Ready awaits its ACK",
                     f"{len(st.others_while_waiting)} other message(s)",
                     [d.describe() for d in st.others_while_waiting[:3]])


@rules("MCP-BLK-4", phase="late")
def test_no_arming_before_start_mission(node):
    """Judged on the attempt: every arm request the node made of its autopilot, accepted or
    refused (a vehicle without a fix refuses; on a real one with a fix it would arm)."""
    node.require_observable("MCP-BLK-4")
    sm = node.session.start_mission
    if sm is None:
        raise Inconclusive("MCP-BLK-4: Start_Mission was never sent")
    arms = [e for e in node.vehicle.events("request") if e.detail.get("request") == "arm"]
    early = [e for e in arms if e.t < sm.first.t]
    actual = ""
    if early:
        answers = sorted({e.detail.get("result", "?") for e in early})
        actual = (f"{len(early)} arm request(s) before Start_Mission, the first "
                  f"{sm.first.t - early[0].t:.3f} s before it ({' and '.join(answers)} by the vehicle)")
    node.expect_true(not early, "MCP-BLK-4", "no arm request to the autopilot before Start_Mission",
                     actual, [f"{sm.first.t - e.t:.3f} s before Start_Mission: {describe_request(e)}"
                              for e in early[:3]])


@rules("MCP-BLK-5", phase="startup")
def test_no_mission_ready_without_a_gps_fix(node):
    node.require_observable("MCP-BLK-5")
    st = node.require_startup("MCP-BLK-5")
    if st.fix_given_at is None or not st.node_connected_to_vehicle:
        raise Inconclusive("MCP-BLK-5: the node never connected to the vehicle while the fix was withheld")
    early = st.ready_before_fix
    node.expect_true(not early, "MCP-BLK-5", "no Mission_Ready while the autopilot reports no GPS fix",
                     f"Mission_Ready sent {st.fix_given_at - early[0].t:.3f} s before the fix" if early else "",
                     [d.describe() for d in early[:2]])


@rules("MCP-BLK-7", "MCP-ACK-1", phase="end")
def test_end_mission_then_rtl(node):
    """End_Mission is the last command of the run; then the drone commands RTL."""
    ex = node.command(Action.END_MISSION)
    node.session.end_mission = ex
    node.session.ended = True
    watch = node.session.liveness
    if not ex.acked and watch is not None and watch.ended_normally():
        # a node may end after End_Mission (harness.liveness): its ACKs were lost before it did
        raise SilenceUnproven("the node ended its mission (its process exited with code 0 after "
                              "End_Mission) before any ACK of End_Mission reached the runner",
                              [f"End_Mission seq {ex.seq}: {len(ex.copies)} copies {node.rto:g} s apart, "
                               "none answered before the node exited", *node.session.node_evidence()])
    node.expect_acked([("End_Mission", ex)])
    node.require_observable("MCP-BLK-7")
    v = node.vehicle
    wait = max(3.0, 3 * node.ack_window, 2 * node.rto)
    since = ex.first.t

    def rtl_requests():
        return [e for e in v.events("request") if e.t >= since and is_rtl_request(e)]
    # judged on the request, whether or not the vehicle could comply; "finishes pending actions,
    # then commands RTL": the window runs from the end of what the vehicle shows still in
    # progress of the node's earlier commands (a take-off climbing), bounded by the case's limit
    waited, pending = node.await_past_pending(lambda: bool(rtl_requests()), wait,
                                              pause=lambda s: v.wait_for(lambda: bool(rtl_requests()), s))
    got = rtl_requests()
    if got:
        node.info(f"{got[0].t - since:.3f} s after End_Mission: {describe_request(got[0])}"
                  + (f" (after the node's pending action: {pending} when End_Mission was ACKed)" if pending else ""))
    asked = [e for e in v.events("request") if e.t >= since]
    still = v.pending_action()
    within = (f"within {wait:g} s of End_Mission" if pending is None else
              f"within {wait:g} s of the end of the node's pending actions ({pending} after End_Mission)")
    node.expect_true(bool(got), "MCP-BLK-7",
                     f"an RTL request to the autopilot (mode RTL or NAV_RETURN_TO_LAUNCH) {within}",
                     f"none in {waited:.1f} s (mode {v.mode}"
                     + (f"; {still} still in progress at the case's bound)" if still else ")"),
                     [f"{e.t - since:.3f} s after End_Mission: {describe_request(e)}" for e in asked[:5]])

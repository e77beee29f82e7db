"""BLK — blocking and ordering semantics.

"The drone application must not ARM the autopilot before receiving this message."
"The drone application must verify GPS lock and other similar ready-to-fly capabilities
before sending this message." "The drone application should complete carrying out all
currently pending actions (from previously received commands), then execute an RTL."
"""

from __future__ import annotations

from conformance.errors import Inconclusive
from conformance.marks import rules
from spec.codec import Action


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
    node.require_observable("MCP-BLK-4")
    sm = node.session.start_mission
    if sm is None:
        raise Inconclusive("MCP-BLK-4: Start_Mission was never sent")
    armed = node.vehicle.events("arm")
    early = [e for e in armed if e.t < sm.first.t]
    node.expect_true(not early, "MCP-BLK-4", "no ARM on the autopilot before Start_Mission",
                     f"armed {sm.first.t - early[0].t:.3f} s before Start_Mission was sent" if early else "",
                     [f"arm event at t={e.t:.3f}" for e in early[:3]])


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
    node.expect_acked([("End_Mission", ex)])
    node.require_observable("MCP-BLK-7")
    v = node.vehicle
    wait = max(3.0, 3 * node.ack_window, 2 * node.rto)
    rtl = v.wait_for(lambda: v.rtl_commanded, wait)
    node.expect_true(rtl, "MCP-BLK-7", f"an RTL on the autopilot within {wait:g} s of End_Mission",
                     f"none (mode {v.mode})")

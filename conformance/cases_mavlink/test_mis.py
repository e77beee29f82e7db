"""MIS — the mission (plan) protocol (https://mavlink.io/en/services/mission.html), as a
ground station drives it: upload, an item withheld once, download and the round trip, set
current, clear, an upload of nothing. Each case uploads its own plan of the mission type
(around the vehicle's position, degE7): the vehicle's mission is replaced, and the last case
leaves it empty."""

from __future__ import annotations

from mcp_conform.conformance.marks import rules
from mcp_conform.spec import MAVLINK

MAV = MAVLINK.dialect
#: ArduPilot's item 0 is home, not what was uploaded (E-3)
ARDUPILOT = MAV.MAV_AUTOPILOT_ARDUPILOTMEGA


def home_items(node) -> int:
    """Items a cleared plan may still count: ArduPilot's home, item 0 (E-3), else none."""
    hb = node.from_vehicle(0.0, "HEARTBEAT")
    return 1 if hb and hb[-1].msg.autopilot == ARDUPILOT else 0


@rules("MAV-MIS-1", "MAV-MIS-2")
def test_upload(node):
    """MAV-MIS-1: MISSION_COUNT answered by a request for each seq, then MISSION_ACK
    ACCEPTED with the mission_type; MAV-MIS-2: in order, none past the end."""
    items = node.plan(4)
    node.expect_upload(node.upload(items), len(items))


@rules("MAV-MIS-3")
def test_item_withheld_is_requested_again(node):
    """MAV-MIS-3: the request for seq 1 left unanswered once is sent again within
    mission_rerequest_max_s, and the upload completes."""
    items = node.plan(3)
    node.expect_upload(node.upload(items, withhold=1), len(items), rule="MAV-MIS-3", order_rule="MAV-MIS-3",
                       rerequested=1)


@rules("MAV-MIS-8", "MAV-MIS-9")
def test_download_is_the_upload(node):
    """MAV-MIS-8: MISSION_REQUEST_LIST answered with MISSION_COUNT, each MISSION_REQUEST_INT
    with its item; MAV-MIS-9: the plan downloaded is the plan uploaded (from seq 1 on an
    ArduPilot, whose item 0 is home: E-3)."""
    items = node.plan(4)
    node.expect_upload(node.upload(items), len(items))
    count, got = node.download()
    node.expect_true(count == len(items) and len(got) == count, "MAV-MIS-8",
                     f"MISSION_COUNT {len(items)}, then {len(items)} items", f"MISSION_COUNT {count}, {len(got)} items")
    first = home_items(node)
    keys = ("command", "frame", "x", "y", "param1", "param2", "param3", "param4")

    def differs(want, have):
        return [k for k in keys if abs(float(getattr(have, k)) - float(want[k])) > 1e-3] + \
               (["z"] if abs(have.z - want["z"]) > 1e-3 else [])
    bad = [(w["seq"], differs(w, h)) for w, h in zip(items[first:], got[first:], strict=False) if differs(w, h)]
    node.expect_true(not bad, "MAV-MIS-9", f"items {first}..{len(items) - 1} as uploaded",
                     "; ".join(f"seq {seq}: {', '.join(k)} differ" for seq, k in bad),
                     [f"uploaded {items[seq]}" for seq, _ in bad[:2]])


@rules("MAV-MIS-15")
def test_set_current(node):
    """MAV-MIS-15: MISSION_SET_CURRENT with a seq of the plan answered by MISSION_CURRENT
    with that seq."""
    items = node.plan(4)
    node.expect_upload(node.upload(items), len(items))
    since = node.send("MISSION_SET_CURRENT", target_system=node.sysid, target_component=node.compid, seq=2)
    ok = node.link.wait_for(lambda: any(r.msg.seq == 2 for r in node.from_vehicle(since, "MISSION_CURRENT")),
                            float(node.params["mission_reply_max_s"]))
    seen = sorted({r.msg.seq for r in node.from_vehicle(since, "MISSION_CURRENT")})
    node.expect_true(ok, "MAV-MIS-15", "after MISSION_SET_CURRENT seq 2, MISSION_CURRENT seq 2",
                     f"MISSION_CURRENT seq {seen}" if seen else "no MISSION_CURRENT")


@rules("MAV-MIS-13", phase="late")
def test_clear_all(node):
    """MAV-MIS-13: MISSION_CLEAR_ALL answered with MISSION_ACK ACCEPTED and a download then
    counting nothing (an error code and the plan kept pass too)."""
    items = node.plan(3)
    node.expect_upload(node.upload(items), len(items))
    since = node.send("MISSION_CLEAR_ALL", target_system=node.sysid, target_component=node.compid,
                      mission_type=MAV.MAV_MISSION_TYPE_MISSION)
    node.link.wait_for(lambda: bool(node.from_vehicle(since, "MISSION_ACK")), float(node.params["mission_reply_max_s"]))
    acks = node.from_vehicle(since, "MISSION_ACK")
    node.expect_true(bool(acks), "MAV-MIS-13", "after MISSION_CLEAR_ALL, a MISSION_ACK", "no MISSION_ACK")
    count, _ = node.download()
    accepted = acks[0].msg.type == MAV.MAV_MISSION_ACCEPTED
    empty = count is not None and count <= home_items(node)  # ArduPilot may count its home (E-3)
    node.expect_true(empty if accepted else count == len(items), "MAV-MIS-13",
                     "MAV_MISSION_ACCEPTED and an empty plan, or an error and the plan kept",
                     f"MISSION_ACK type {acks[0].msg.type}, then MISSION_COUNT {count}")


@rules("MAV-MIS-14", phase="late")
def test_upload_of_nothing_clears(node):
    """MAV-MIS-14: MISSION_COUNT 0 answered at once with MISSION_ACK, and the plan empty."""
    items = node.plan(3)
    node.expect_upload(node.upload(items), len(items))
    replies = node.upload([])
    node.expect_true([r.name for r in replies][:1] == ["MISSION_ACK"] and replies[0].msg.type == MAV.MAV_MISSION_ACCEPTED,
                     "MAV-MIS-14", "after MISSION_COUNT 0, MISSION_ACK MAV_MISSION_ACCEPTED",
                     ", ".join(r.name for r in replies) or "nothing")
    count, _ = node.download()
    node.expect_true(count is not None and count <= home_items(node), "MAV-MIS-14", "an empty plan after it (ArduPilot: home only)",
                     f"MISSION_COUNT {count}")

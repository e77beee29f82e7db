"""HB — heartbeat, identity and framing of the vehicle (mavlink.io's heartbeat, serialization
and routing pages): what every frame the vehicle sends on the runner's link shows, and how it
takes frames that are not quite right."""

from __future__ import annotations

import inspect

from mcp_conform.conformance.marks import rules
from mcp_conform.spec import MAVLINK

#: the HEARTBEAT.mavlink_version pymavlink's encoder fills in (the dialect's, MAV-HB-9)
MAVLINK_VERSION = inspect.signature(MAVLINK.dialect.MAVLink.heartbeat_encode).parameters["mavlink_version"].default


@rules("MAV-HB-1", phase="startup")
def test_heartbeat_is_regular(node):
    """MAV-HB-1: the vehicle's HEARTBEAT from the link's start, never a gap over
    heartbeat_gap_max_s (D-2); the first one's delay is the startup's."""
    gap_max = float(node.params["heartbeat_gap_max_s"])
    first = node.session.first_heartbeat - node.session.link_opened
    node.expect_true(first <= gap_max or node.session.spawned, "MAV-HB-1",
                     f"the first HEARTBEAT within {gap_max:g} s of the link's opening", f"after {first:.2f} s")
    node.expect_heartbeats(gap_max + float(node.params["heartbeat_period_s"]))


@rules("MAV-HB-3")
def test_heartbeat_names_a_vehicle_and_its_flight_stack(node):
    """MAV-HB-3: type a vehicle's (not MAV_TYPE_GCS), autopilot a flight stack (not
    MAV_AUTOPILOT_INVALID), both values of their enums."""
    mav = node.mav
    types, stacks = mav.enums["MAV_TYPE"], mav.enums["MAV_AUTOPILOT"]

    def check(r):
        t, a = r.msg.type, r.msg.autopilot
        if t not in types or t in (mav.MAV_TYPE_GCS, mav.MAV_TYPE_ONBOARD_CONTROLLER):
            return f"type {t} ({types[t].name if t in types else 'no MAV_TYPE'})"
        if a not in stacks or a == mav.MAV_AUTOPILOT_INVALID:
            return f"autopilot {a} ({stacks[a].name if a in stacks else 'no MAV_AUTOPILOT'})"
        return None
    node.watch(float(node.params["heartbeat_period_s"]))
    node.expect_frames(node.from_vehicle(0.0, "HEARTBEAT"), check, "MAV-HB-3",
                       "HEARTBEAT.type a vehicle's MAV_TYPE, HEARTBEAT.autopilot a flight stack")


@rules("MAV-HB-6")
def test_one_source_address_in_range(node):
    """MAV-HB-6: every frame of the vehicle's system carries the IDs of its first HEARTBEAT,
    both 1..255 (0 is the broadcast address)."""
    node.watch(float(node.params["heartbeat_period_s"]))
    sysid, compid = node.sysid, node.compid
    ok = 1 <= sysid <= 255 and 1 <= compid <= 255
    frames = [r for r in node.link.received() if not r.bad and r.msg.get_srcSystem() == sysid]
    node.expect_frames(frames, lambda r: None if ok and r.msg.get_srcComponent() == compid
                       else f"{r.name} from {r.msg.get_srcSystem()}/{r.msg.get_srcComponent()}", "MAV-HB-6",
                       f"every frame from system {sysid} component {compid}, both 1..255")


@rules("MAV-HB-8")
def test_autopilot_uses_its_component_id(node):
    """MAV-HB-8 (SHOULD): an autopilot's component ID is MAV_COMP_ID_AUTOPILOT1."""
    want = node.mav.MAV_COMP_ID_AUTOPILOT1
    node.expect_true(node.compid == want, "MAV-HB-8", f"component ID {want} (MAV_COMP_ID_AUTOPILOT1)",
                     f"component ID {node.compid}")


@rules("MAV-HB-9")
def test_heartbeat_mavlink_version(node):
    """MAV-HB-9: HEARTBEAT.mavlink_version is the dialect's (as pymavlink's encoder fills it)."""
    node.expect_frames(node.from_vehicle(0.0, "HEARTBEAT"),
                       lambda r: None if r.msg.mavlink_version == MAVLINK_VERSION else f"mavlink_version {r.msg.mavlink_version}",
                       "MAV-HB-9", f"HEARTBEAT.mavlink_version {MAVLINK_VERSION}")


@rules("MAV-HB-10", phase="late")
def test_every_frame_is_whole_and_checksummed(node):
    """MAV-HB-10: every byte the vehicle sent on the link so far parsed as a frame of the
    dialect with a right checksum (pymavlink's parser; bad bytes are its BAD_DATA)."""
    frames = node.link.received()
    node.expect_frames(frames, lambda r: r.describe() if r.bad else None, "MAV-HB-10",
                       "every frame a whole MAVLink frame of the dialect with its CRC right")


@rules("MAV-HB-11", phase="late")
def test_sequence_numbers_count_up(node):
    """MAV-HB-11: the sequence number goes up by one with every frame of the vehicle's
    component (the link is loopback: nothing is lost between)."""
    frames = node.from_vehicle()
    pairs = list(zip(frames, frames[1:], strict=False))
    bad = [(a, b) for a, b in pairs if (a.msg.get_seq() + 1) % 256 != b.msg.get_seq()]
    node.expect_true(bool(pairs) and not bad, "MAV-HB-11", "each frame's seq the previous one's + 1 (mod 256)",
                     f"{len(bad)} of {len(pairs)} steps are not" if pairs else "fewer than two frames",
                     [f"{a.name} seq {a.msg.get_seq()} then {b.name} seq {b.msg.get_seq()}" for a, b in bad[:3]])


@rules("MAV-HB-12", phase="late")
def test_mavlink2_payloads_are_truncated(node):
    """MAV-HB-12: no MAVLink 2 frame of the vehicle ends its payload with a zero byte
    (the first byte excepted)."""
    def check(r):
        length = r.raw[1]
        payload = r.raw[10:10 + length]
        return f"{r.name}: payload of {length} B ends in a zero" if length > 1 and payload[-1] == 0 else None
    node.expect_frames([r for r in node.from_vehicle() if r.version == 2], check, "MAV-HB-12",
                       "MAVLink 2 payloads without trailing zeros")


@rules("MAV-HB-15")
def test_answers_mavlink2_in_mavlink2(node):
    """MAV-HB-15 (SHOULD): the runner speaks MAVLink 2, so what the vehicle sends after a
    heartbeat period is MAVLink 2."""
    period = float(node.params["heartbeat_period_s"])
    since = node.link.sent[0][0] + float(node.params["heartbeat_gap_max_s"])
    node.watch(max(period, since + period - node.t0))
    node.expect_frames(node.from_vehicle(since), lambda r: None if r.version == 2 else f"{r.name} in MAVLink 1",
                       "MAV-HB-15", "MAVLink 2 frames on a link the ground station speaks MAVLink 2 on")


@rules("MAV-HB-13")
def test_untruncated_request_is_handled(node):
    """MAV-HB-13: a COMMAND_LONG whose payload keeps its trailing zeros is answered as the
    same command truncated."""
    cmd = node.mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
    msg = node.message("COMMAND_LONG", target_system=node.sysid, target_component=node.compid, command=cmd,
                       confirmation=0, param1=1, param2=0, param3=0, param4=0, param5=0, param6=0, param7=0)
    since = node.send_raw(node.frame_of(msg, pad=True), "COMMAND_LONG")
    node.expect_ack(since, cmd, "MAV-HB-13", once_rule=None, what="a COMMAND_LONG with its payload's trailing zeros")


@rules("MAV-HB-14")
def test_bad_checksum_is_discarded(node):
    """MAV-HB-14: a COMMAND_LONG with a spoiled checksum is not answered; the same command
    whole right after it is."""
    cmd = node.mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
    msg = node.message("COMMAND_LONG", target_system=node.sysid, target_component=node.compid, command=cmd,
                       confirmation=0, param1=1, param2=0, param3=0, param4=0, param5=0, param6=0, param7=0)
    since = node.send_raw(node.frame_of(msg, bad_crc=True), "COMMAND_LONG")
    node.expect_no_ack(since, cmd, "MAV-HB-14", "a COMMAND_LONG with a bad checksum")
    since = node.command_long(cmd, 1)
    node.expect_ack(since, cmd, "MAV-HB-14", once_rule=None, what="the same command whole, after the bad one")

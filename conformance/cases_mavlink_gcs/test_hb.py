"""HB — the ground station's heartbeat, identity and framing (mavlink.io's heartbeat,
serialization and routing pages), judged over its run against a vehicle that answers as
ArduPilot: the frames it sends from connecting until it has done its work."""

from __future__ import annotations

import inspect

from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec import MAVLINK

#: the HEARTBEAT.mavlink_version pymavlink's encoder fills in (the dialect's, MAV-HB-9)
MAVLINK_VERSION = inspect.signature(MAVLINK.dialect.MAVLink.heartbeat_encode).parameters["mavlink_version"].default


def _heartbeats(node):
    """The ground station's HEARTBEATs, one awaited (SKIPPED when none came: MAV-HB-2's)."""
    node.run()
    node.wait(lambda: node.from_gcs("HEARTBEAT"), float(node.params["heartbeat_gap_max_s"]))
    beats = node.from_gcs("HEARTBEAT")
    if not beats:
        raise Inconclusive("the ground station sent no HEARTBEAT (MAV-HB-2 judges that)")
    return beats


@rules("MAV-HB-2")
def test_heartbeat_is_regular(node):
    """MAV-HB-2: the ground station's HEARTBEAT from the link's opening, while it works and
    while it commands nothing, never a gap over heartbeat_gap_max_s (D-2).

    Watched for heartbeat_gap_max_s + heartbeat_period_s from when the ground station is seen
    on the link (``node.on_link``: its TCP connection, or over UDP its first frame; one beat
    owed in any case), and on while the ground station is still at its work, up to twice the gap
    allowance: a station that beats only until it hears the vehicle and then works in silence
    (seed 001's programs) shows its gap whenever it heard the vehicle within that time, not only
    when it heard it in the first second. Ends early once a gap is proven."""
    node.run()
    gap_max = float(node.params["heartbeat_gap_max_s"])
    window = gap_max + float(node.params["heartbeat_period_s"])
    longest = window + gap_max
    start = node.on_link

    def beats_until(end):
        return [r.t for r in node.from_gcs("HEARTBEAT") if r.t <= end]

    def gap_proven():
        got = beats_until(node.now())
        return node.now() - (got[-1] if got else start) > gap_max

    node.wait(lambda: False, start + window - node.now())
    if not node.ended() and not node.quiet():
        node.wait(gap_proven, start + longest - node.now())
    end = min(node.now(), start + longest)
    beats = beats_until(end)
    if end - start < gap_max and not beats:
        raise Inconclusive(f"the ground station was on the link only {end - start:.1f} s, with no HEARTBEAT")
    edges = [start, *beats, end]
    gaps = [b - a for a, b in zip(edges, edges[1:], strict=False)]
    node.expect_true(bool(beats) and max(gaps) <= gap_max, "MAV-HB-2",
                     f"a HEARTBEAT at least every {gap_max:g} s over {end - start:.1f} s",
                     f"{len(beats)} HEARTBEAT(s), longest gap {max(gaps):.2f} s",
                     [f"gaps (s): {', '.join(f'{g:.2f}' for g in gaps)}"])


@rules("MAV-HB-4")
def test_heartbeat_says_ground_station(node):
    """MAV-HB-4: HEARTBEAT.type MAV_TYPE_GCS (or MAV_TYPE_ONBOARD_CONTROLLER, an application
    on the companion computer)."""
    mav = node.mav
    ok = (mav.MAV_TYPE_GCS, mav.MAV_TYPE_ONBOARD_CONTROLLER)
    names = mav.enums["MAV_TYPE"]
    node.expect_frames(_heartbeats(node), lambda r: None if r.msg.type in ok else
                       f"type {r.msg.type} ({names[r.msg.type].name if r.msg.type in names else 'no MAV_TYPE'})",
                       "MAV-HB-4", "HEARTBEAT.type MAV_TYPE_GCS or MAV_TYPE_ONBOARD_CONTROLLER")


@rules("MAV-HB-5")
def test_heartbeat_autopilot_invalid(node):
    """MAV-HB-5 (SHOULD): HEARTBEAT.autopilot MAV_AUTOPILOT_INVALID."""
    want = node.mav.MAV_AUTOPILOT_INVALID
    node.expect_frames(_heartbeats(node), lambda r: None if r.msg.autopilot == want else f"autopilot {r.msg.autopilot}",
                       "MAV-HB-5", f"HEARTBEAT.autopilot MAV_AUTOPILOT_INVALID ({want})")


@rules("MAV-HB-9")
def test_heartbeat_mavlink_version(node):
    """MAV-HB-9: HEARTBEAT.mavlink_version is the dialect's (as pymavlink's encoder fills it)."""
    node.expect_frames(_heartbeats(node), lambda r: None if r.msg.mavlink_version == MAVLINK_VERSION
                       else f"mavlink_version {r.msg.mavlink_version}", "MAV-HB-9",
                       f"HEARTBEAT.mavlink_version {MAVLINK_VERSION}")


@rules("MAV-HB-6", "MAV-HB-7")
def test_one_source_address_not_the_vehicles(node):
    """MAV-HB-6: every frame of the ground station carries one system/component pair, both
    1..255; MAV-HB-7: its system ID is not the vehicle's."""
    node.run()
    node.settle()
    frames = node.need(node.from_gcs(), "frame")
    first = (frames[0].msg.get_srcSystem(), frames[0].msg.get_srcComponent())
    ok = 1 <= first[0] <= 255 and 1 <= first[1] <= 255
    node.expect_frames(frames, lambda r: None if ok and (r.msg.get_srcSystem(), r.msg.get_srcComponent()) == first
                       else f"{r.name} from {r.msg.get_srcSystem()}/{r.msg.get_srcComponent()}", "MAV-HB-6",
                       f"every frame from one system and component (the first: {first[0]}/{first[1]}), both 1..255")
    vehicle = node.vehicle_ids[0]
    node.expect_true(first[0] != vehicle, "MAV-HB-7", f"a system ID other than the vehicle's ({vehicle})",
                     f"system ID {first[0]}")


@rules("MAV-HB-10", "MAV-HB-11", "MAV-HB-12")
def test_frames_whole_counted_and_truncated(node):
    """MAV-HB-10: every byte the ground station sent parsed as a frame of the dialect with its
    CRC right; MAV-HB-12: no MAVLink 2 payload ends in a zero byte (the first byte excepted);
    MAV-HB-11: the sequence number one up with every frame (loopback: nothing is lost)."""
    node.run()
    node.settle()
    every = node.link.received()
    node.expect_frames(every, lambda r: r.describe() if r.bad else None, "MAV-HB-10",
                       "every frame a whole MAVLink frame of the dialect with its CRC right")
    frames = node.from_gcs()

    def truncated(r):
        length = r.raw[1]
        return f"{r.name}: payload of {length} B ends in a zero" if length > 1 and r.raw[9 + length] == 0 else None
    v2 = [r for r in frames if r.version == 2]
    if v2:
        node.expect_frames(v2, truncated, "MAV-HB-12", "MAVLink 2 payloads without trailing zeros")
    pairs = list(zip(frames, frames[1:], strict=False))
    bad = [(a, b) for a, b in pairs if (a.msg.get_seq() + 1) % 256 != b.msg.get_seq()]
    node.expect_true(bool(pairs) and not bad, "MAV-HB-11", "each frame's seq the previous one's + 1 (mod 256)",
                     f"{len(bad)} of {len(pairs)} steps are not" if pairs else "fewer than two frames",
                     [f"{a.name} seq {a.msg.get_seq()} then {b.name} seq {b.msg.get_seq()}" for a, b in bad[:3]])


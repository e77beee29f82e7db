"""MIS — the ground station's side of the mission protocol
(https://mavlink.io/en/services/mission.html): the upload handshake (MISSION_COUNT, each item
when it is requested, until the vehicle's MISSION_ACK), the items' seq, mission_type and degE7
positions, the download handshake, an item re-requested sent again, MISSION_COUNT resent when
unanswered and given up at a bound, an error MISSION_ACK ending the upload. The runner's vehicle
asks for items with MISSION_REQUEST_INT, as ArduPilot does once a ground station has sent
MISSION_ITEM_INT.

The cases that judge the run against ArduPilot's behaviour come first, one after another: they
share that run (the ground station is started afresh for each change of behaviour: two starts
fewer than with a departure's case between them)."""

from __future__ import annotations

import math
from collections import Counter

from mcp_conform.conformance.cases_mavlink_gcs.mavlink_gcs_services import (
    GLOBAL_FRAMES,
    degrees_sent,
)
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec import MAVLINK
from mcp_conform.vehicle.behaviour import Behaviour

mav = MAVLINK.dialect
ITEMS = ("MISSION_ITEM_INT", "MISSION_ITEM")
REQUESTS = ("MISSION_REQUEST_INT", "MISSION_REQUEST")
IGNORE_COUNT = Behaviour("ignore-mission-count", ignore_mission_count=True)
ERROR_ACK = Behaviour("error-ack-on-item-0", error_ack_item=0)
DROP_ITEM = Behaviour("drop-item-1", drop_item=1)
#: the commands of a navigation item with a position (MAV-MIS-26: not in MAV_FRAME_MISSION)
POSITIONED = frozenset({mav.MAV_CMD_NAV_WAYPOINT, mav.MAV_CMD_NAV_LOITER_UNLIM, mav.MAV_CMD_NAV_LOITER_TURNS,
                        mav.MAV_CMD_NAV_LOITER_TIME, mav.MAV_CMD_NAV_LAND, mav.MAV_CMD_NAV_SPLINE_WAYPOINT})


def _upload(node, settle=True):
    """The run's first upload as one timeline: (time, who, message), who 'gcs' or 'vehicle',
    from the first MISSION_COUNT on; SKIPPED when the ground station uploaded nothing."""
    if settle:
        node.settle()
    counts = node.need(node.from_gcs("MISSION_COUNT"), "MISSION_COUNT (no upload)")
    gcs = [(r.t, "gcs", r.msg) for r in node.from_gcs("MISSION_COUNT", *ITEMS) if r.t >= counts[0].t]
    vehicle = [(t, "vehicle", m) for t, m in node.runner_sent(*REQUESTS, "MISSION_ACK") if t >= counts[0].t]
    return sorted(gcs + vehicle, key=lambda e: e[0])


def _owed(timeline, until=float("inf")):
    """The vehicle's requests not answered yet at ``until``, by seq: each request the vehicle
    sent is owed one item of its seq until an item of that seq came. A request and its
    re-request (ArduPilot asks again after 1 s) that both reach the ground station before its
    answer do are both answered: the second item then comes after a later request went out,
    or after the upload ended (a runner late to read, a lossy link) -- an answer to a request,
    not an item unasked."""
    owed = Counter()
    for t, who, m in timeline:
        if t >= until:
            break
        if who == "vehicle" and m.get_type() in REQUESTS:
            owed[m.seq] += 1
        elif who == "gcs" and m.get_type() in ITEMS and owed[m.seq] > 0:
            owed[m.seq] -= 1
    return owed


def _step(who, m):
    name = m.get_type()
    return f"{who} {name}" + (f" {m.seq}" if hasattr(m, "seq") and name != "MISSION_COUNT" else "") + (
        f" {m.count}" if name == "MISSION_COUNT" else "") + (f" {m.type}" if name == "MISSION_ACK" else "")


@rules("MAV-MIS-20")
def test_upload_handshake(node):
    """MAV-MIS-20: MISSION_COUNT first, then each item only as it is requested, with the seq of
    the vehicle's latest request (or of an earlier request not answered yet: ``_owed``), until
    the vehicle's MISSION_ACK."""
    node.run()
    timeline = _upload(node)
    requested, done, bad = None, False, []
    owed = Counter()
    for _, who, m in timeline:
        name = m.get_type()
        if who == "vehicle":
            # an ACK ends the upload, but not an ACCEPTED before any request: another operation's (a clear's)
            done = done or (name == "MISSION_ACK" and (requested is not None or m.type != mav.MAV_MISSION_ACCEPTED))
            if name in REQUESTS:
                requested = m.seq
                owed[m.seq] += 1
        elif name in ITEMS and owed[m.seq] > 0:
            owed[m.seq] -= 1
        elif name in ITEMS and not done and m.seq != requested:
            bad.append(f"item {m.seq} sent" + (f" when {requested} was requested" if requested is not None
                                                else " before any request"))
    last = timeline[-1]
    if not bad and last[1] == "vehicle" and last[2].get_type() in REQUESTS:  # a slow ground station: waited for
        node.wait(lambda: len(_upload(node, settle=False)) > len(timeline), 3 * float(node.params["mission_timeout_s"]))
        last = _upload(node, settle=False)[-1]
    if not bad and last[1] == "vehicle" and last[2].get_type() in REQUESTS:
        bad.append(f"item {last[2].seq} requested, never sent (no MISSION_ACK ended the upload)")
    node.expect_true(not bad, "MAV-MIS-20", "each item sent with the seq the vehicle requested",
                     f"{len(bad)} departure(s): {bad[0]}" if bad else "",
                     [", ".join(_step(w, m) for _, w, m in timeline[:12])])


@rules("MAV-MIS-21")
def test_items_seq_and_mission_type(node):
    """MAV-MIS-21: the upload's items have seq 0..count - 1 and the MISSION_COUNT's mission_type."""
    node.run()
    timeline = _upload(node)
    count = timeline[0][2]
    items = [m for _, who, m in timeline if who == "gcs" and m.get_type() in ITEMS]
    problems = [f"item {m.seq} of {count.count}" for m in items if not 0 <= m.seq < count.count]
    problems += [f"item {m.seq} with mission_type {m.mission_type}, the count's {count.mission_type}"
                 for m in items if m.mission_type != count.mission_type]
    node.need(items, "mission item (MAV-MIS-20 judges an upload that sent none)")
    node.expect_true(not problems, "MAV-MIS-21", f"items seq 0..{count.count - 1} with mission_type "
                     f"{count.mission_type}", problems[0] if problems else "")


def degrees_float(x: float, y: float) -> bool:
    """D-6, the deprecated MISSION_ITEM: x a latitude and y a longitude in degrees, or NaN
    (common.xml: "NaN may be used to indicate an optional/default value")."""
    return (math.isnan(x) or -90 <= x <= 90) and (math.isnan(y) or -180 <= y <= 180)


@rules("MAV-MIS-26")
def test_item_positions_in_degE7(node):
    """MAV-MIS-26 (D-6): MISSION_ITEM_INT x, y in degrees * 1E7 in a global frame; the
    deprecated MISSION_ITEM's x, y in degrees (a latitude within -90..90, a longitude within
    -180..180: a degE7 integer there is no latitude; NaN, "an optional/default value", not
    judged); a navigation item with a position not in MAV_FRAME_MISSION."""
    node.run()
    node.settle()

    def check(r):
        m = r.msg
        if m.frame in GLOBAL_FRAMES and r.name == "MISSION_ITEM_INT" and degrees_sent(m.x, m.y):
            return f"item {m.seq}: x {m.x}, y {m.y}: degrees, not degE7"
        if m.frame in GLOBAL_FRAMES and r.name == "MISSION_ITEM" and not degrees_float(m.x, m.y):
            return f"MISSION_ITEM {m.seq}: x {m.x}, y {m.y}: not degrees (degE7 in a float field?)"
        if m.command in POSITIONED and m.frame == mav.MAV_FRAME_MISSION:
            return f"item {m.seq}: command {m.command} in MAV_FRAME_MISSION"
        return None
    items = [r for r in node.from_gcs() if r.name in ITEMS]
    node.expect_frames(node.need(items, "MISSION_ITEM_INT or MISSION_ITEM"), check, "MAV-MIS-26",
                       "global positions in degrees * 1E7 (MISSION_ITEM: in degrees), positioned items in a "
                       "global frame")


@rules("MAV-MIS-12", "MAV-MIS-17")
def test_no_deprecated_messages_and_mission_types(node):
    """MAV-MIS-12 (SHOULD): no MISSION_REQUEST or MISSION_ITEM of its own accord (the runner
    asks with MISSION_REQUEST_INT); MAV-MIS-17: mission_type a MAV_MISSION_TYPE,
    MAV_MISSION_TYPE_ALL only in MISSION_CLEAR_ALL."""
    node.run()
    node.settle()
    types = {v for v, e in mav.enums["MAV_MISSION_TYPE"].items() if not e.name.endswith("_ENUM_END")}
    frames = node.need([r for r in node.from_gcs() if r.name.startswith("MISSION_")], "mission message")
    node.expect_frames(frames, lambda r: None if r.msg.mission_type in types and (
        r.msg.mission_type != mav.MAV_MISSION_TYPE_ALL or r.name == "MISSION_CLEAR_ALL")
        else f"{r.name} with mission_type {r.msg.mission_type}", "MAV-MIS-17",
        "mission_type a MAV_MISSION_TYPE (ALL only in MISSION_CLEAR_ALL)")
    node.expect_frames(frames, lambda r: f"{r.name}: deprecated" if r.name in ("MISSION_REQUEST", "MISSION_ITEM")
                       else None, "MAV-MIS-12", "MISSION_REQUEST_INT and MISSION_ITEM_INT, not the deprecated")


@rules("MAV-MIS-25")
def test_download_handshake(node):
    """MAV-MIS-25: MISSION_REQUEST_LIST, then MISSION_REQUEST_INT for seq 0..count - 1 in order
    (a seq asked again allowed), then MISSION_ACK MAV_MISSION_ACCEPTED."""
    node.run()
    node.settle()
    lists = node.need(node.from_gcs("MISSION_REQUEST_LIST"), "MISSION_REQUEST_LIST (no download)")
    counts = [m for t, m in node.runner_sent("MISSION_COUNT") if t >= lists[0].t]
    if not counts:
        raise Inconclusive("the runner's vehicle sent no MISSION_COUNT")
    n = counts[0].count
    asked = [r.msg.seq for r in node.from_gcs(*REQUESTS) if r.t >= lists[0].t]
    distinct = [s for i, s in enumerate(asked) if i == 0 or asked[i - 1] != s]
    acks = [r for r in node.from_gcs("MISSION_ACK") if r.t >= lists[0].t]
    ok = distinct == list(range(n)) and bool(acks) and acks[0].msg.type == mav.MAV_MISSION_ACCEPTED
    node.expect_true(ok, "MAV-MIS-25", f"requests for seq 0..{n - 1} in order, then MISSION_ACK MAV_MISSION_ACCEPTED",
                     f"requests for {asked[:12]}, " + (f"MISSION_ACK {acks[0].msg.type}" if acks else "no MISSION_ACK"))


@rules("MAV-MIS-20")
def test_rerequested_item_sent_again(node):
    """MAV-MIS-20: an item the vehicle requests again (the runner drops the first item 1, and
    asks for it again as ArduPilot does after 1 s) is sent again, the same item -- waited for
    up to 3 x mission_timeout_s after the request: the ground station's settling (2 s without
    its work) may come before that request is answered when it went out late (a runner late to
    send it, a lossy link)."""
    node.run(DROP_ITEM)
    node.settle()
    node.need(node.from_gcs("MISSION_COUNT"), "MISSION_COUNT (no upload)")
    first = [r for r in node.from_gcs(*ITEMS) if r.msg.seq == 1]
    if not first:
        raise Inconclusive("the ground station never sent item 1: nothing was dropped to be requested again")
    dropped = first[0].t
    asks = [t for t, m in node.runner_sent(*REQUESTS) if m.seq == 1 and t > dropped]
    ended = [t for t, _ in node.runner_sent("MISSION_ACK") if t > dropped]
    if not asks or (ended and ended[0] < asks[0]):
        raise Inconclusive("the upload ended before the vehicle requested item 1 again")

    def answers():
        return [r for r in node.from_gcs(*ITEMS) if r.msg.seq == 1 and r.t > asks[0]]
    node.wait(answers, asks[0] + 3 * float(node.params["mission_timeout_s"]) - node.now())
    again = answers()
    same = bool(again) and again[0].msg.to_dict() == first[0].msg.to_dict()
    node.expect_true(same, "MAV-MIS-20", "item 1 sent again, the same, when the vehicle requests it again",
                     "not sent again" if not again else "a different item 1")


def _counts(node):
    window = 3 * float(node.params["mission_timeout_s"])
    node.await_work(lambda: node.from_gcs("MISSION_COUNT"))
    node.need(node.from_gcs("MISSION_COUNT"), "MISSION_COUNT (no upload)")
    return window


@rules("MAV-MIS-22")
def test_unanswered_count_resent(node):
    """MAV-MIS-22 (D-7): a MISSION_COUNT the vehicle does not answer is resent within
    3 x mission_timeout_s."""
    node.run(IGNORE_COUNT)
    window = _counts(node)
    node.wait(lambda: len(node.from_gcs("MISSION_COUNT")) > 1, window)
    node.expect_true(len(node.from_gcs("MISSION_COUNT")) > 1, "MAV-MIS-22",
                     f"MISSION_COUNT resent within {window:g} s when unanswered", "not resent")


@rules("MAV-MIS-23")
def test_unanswered_upload_given_up(node):
    """MAV-MIS-23 (D-7): at most mission_resends_max resends of an unanswered MISSION_COUNT."""
    node.run(IGNORE_COUNT)
    window = _counts(node)
    bound = int(node.params["mission_resends_max"])
    sent = node.resends(lambda: node.from_gcs("MISSION_COUNT"), bound, window, (bound + 2) * window)
    node.need(sent[1:], "resent MISSION_COUNT")
    node.expect_true(len(sent) - 1 <= bound, "MAV-MIS-23", f"at most {bound} resends of MISSION_COUNT",
                     f"{len(sent) - 1} resends")


@rules("MAV-MIS-24")
def test_error_ack_ends_the_upload(node):
    """MAV-MIS-24: after the vehicle's MISSION_ACK MAV_MISSION_ERROR (to item 0), no more items
    of that upload (until a new MISSION_COUNT) within 3 x mission_timeout_s; an item that
    answers a request the vehicle sent before its error (owed then: ``_owed``) crossed it."""
    node.run(ERROR_ACK)
    window = _counts(node)

    def error_acks():
        return [t for t, m in node.runner_sent("MISSION_ACK") if m.type == mav.MAV_MISSION_ERROR]
    node.await_work(error_acks)
    errors = error_acks()
    if not errors:
        raise Inconclusive("the upload never reached item 0: no error MISSION_ACK went out")
    node.wait(lambda: False, window)
    restart = [r.t for r in node.from_gcs("MISSION_COUNT") if r.t > errors[0]]
    until = restart[0] if restart else float("inf")
    owed = _owed(_upload(node, settle=False), errors[0])
    after = []
    for r in node.from_gcs(*ITEMS):
        if errors[0] < r.t < until:
            if owed[r.msg.seq] > 0:
                owed[r.msg.seq] -= 1
            else:
                after.append(r)
    node.expect_true(not after, "MAV-MIS-24", "no item after the error MISSION_ACK",
                     f"{len(after)} item(s), the first item {after[0].msg.seq} {after[0].t - errors[0]:.2f} s after"
                     if after else "")

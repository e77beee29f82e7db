"""MIS — the mission (plan) protocol (https://mavlink.io/en/services/mission.html), as a
ground station drives it: upload, an item withheld once, an item out of sequence, an upload
abandoned, failed or cancelled, download and the round trip, the deprecated MISSION_REQUEST
and MISSION_ITEM, plan types kept apart, positions to the unit, set current, clear, an
upload of nothing, and the mission_type of everything the vehicle sent. Each case uploads its
own plan of the mission type (around the vehicle's position, degE7): the vehicle's mission
is replaced, and the last case leaves it empty."""

from __future__ import annotations

from mcp_conform.conformance.cases_mavlink.mavlink_services import (
    UNKNOWN_COMMAND,
    ItemAnswers,
    result_name_mission,
    upload_replies,
)
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec import MAVLINK

MAV = MAVLINK.dialect
MISSION = MAV.MAV_MISSION_TYPE_MISSION
#: the messages that carry one plan item
ITEMS = ("MISSION_ITEM_INT", "MISSION_ITEM")
#: ArduPilot's item 0 is home, not what was uploaded (E-3)
ARDUPILOT = MAV.MAV_AUTOPILOT_ARDUPILOTMEGA


def home_items(node) -> int:
    """Items a cleared plan may still count: ArduPilot's home, item 0 (E-3), else none."""
    hb = node.from_vehicle(0.0, "HEARTBEAT")
    return 1 if hb and hb[-1].msg.autopilot == ARDUPILOT else 0


#: the fields of an item a round trip keeps (MAV-MIS-9), and those that say which item it is
#: (its command and position: MAV-MIS-4, 7, 16 judge which items a plan holds, the round
#: trip's fidelity being MAV-MIS-9's)
FIELDS = ("command", "frame", "param1", "param2", "param3", "param4", "x", "y", "z")
WHICH = ("command", "x", "y", "z")


def expect_plan(node, items, got, rule, *, fields=FIELDS):
    """``got`` (downloaded items) is ``items`` from the first non-home seq on (E-3): per item
    the same ``fields`` (to 1e-3: exact for degE7 integers), and no item missing."""
    first = home_items(node)

    def differs(want, have):
        return [k for k in fields if abs(float(getattr(have, k)) - float(want[k])) > 1e-3]
    bad = [(w["seq"], differs(w, h)) for w, h in zip(items[first:], got[first:], strict=False) if differs(w, h)]
    node.expect_true(not bad and len(got) >= len(items), rule, f"items {first}..{len(items) - 1} as uploaded",
                     "; ".join(f"seq {seq}: {', '.join(k)} differ" for seq, k in bad)
                     or f"{len(got)} items of {len(items)}",
                     [f"uploaded {items[seq]}" for seq, _ in bad[:2]])


def drive_upload(node, count, answer, *, mission_type=MISSION, wait=None, until=None):
    """MISSION_COUNT ``count`` of ``mission_type`` (resent, as a ground station must, up to
    mission_retries times while nothing answers it), then ``answer(request)`` for each
    MISSION_REQUEST_INT or MISSION_REQUEST the vehicle sends (``node.mission_requests``: until
    a MISSION_ACK that ends the upload, any but MAV_MISSION_INVALID_SEQUENCE: E-1, or ``wait``
    s (mission_reply_max_s) with nothing new; bounded by 3 x count + 10 replies), or until
    ``until()`` holds after an answer; a request already answered after it came is not answered
    again (``ItemAnswers``: the vehicle re-requested while the runner was late), and after
    an upload in which its last item went again, the vehicle's answer to it is waited for
    (``settle``). The first MISSION_COUNT's send time and the vehicle's requests and ACKs
    up to the one that ended the upload (``upload_replies``), in order."""
    wait = float(node.params["mission_reply_max_s"]) if wait is None else wait
    since = 0.0
    for _ in range(1 + int(node.params["mission_retries"])):
        t = node.send("MISSION_COUNT", target_system=node.sysid, target_component=node.compid, count=count,
                      mission_type=mission_type)
        since = since or t
        if node.link.wait_for(lambda since=since: bool(node.mission_replies(since)),
                              float(node.params["mission_reply_max_s"])):
            break
    answers = ItemAnswers()
    for reply in node.mission_requests(since, 3 * count + 10, wait):
        if not answers.due(reply):
            continue
        sent = len(node.link.sent)
        answer(reply)
        if len(node.link.sent) > sent:
            answers.sent(reply.msg.seq, node.link.sent[-1][0])
        if until is not None and until():
            break
    node.settle(answers, count - 1)
    return since, upload_replies(node.mission_replies(since))


def send_item(node, item, **changes):
    """MISSION_ITEM_INT ``item`` (with ``changes``) to the vehicle."""
    return node.send("MISSION_ITEM_INT", target_system=node.sysid, target_component=node.compid,
                     **{**item, **changes})


def ask(node, name, answered, **fields):
    """``name`` with ``fields`` sent to the vehicle, and sent again (a ground station's
    resend: mavlink.io's "the request must be resent") up to mission_retries times, each
    after mission_reply_max_s with no frame for which ``answered(frame)`` holds; those
    frames (none: unanswered) and how many resends it took."""
    wait = float(node.params["mission_reply_max_s"])
    for resends in range(1 + int(node.params["mission_retries"])):
        t = node.send(name, target_system=node.sysid, target_component=node.compid, **fields)

        def got(t=t):
            return [r for r in node.from_vehicle(t) if answered(r)]
        if node.link.wait_for(lambda got=got: bool(got()), wait):
            return got(), resends
    return [], resends


def download(node, *, mission_type=MISSION, request="MISSION_REQUEST_INT"):
    """A download of ``mission_type``, each item asked for with ``request``
    (MISSION_REQUEST_INT, or the deprecated MISSION_REQUEST), each request resent as a
    ground station resends it (``ask``): (the MISSION_COUNT frame or None, the items that
    came, MISSION_ITEM_INT or MISSION_ITEM frames); MISSION_ACK ACCEPTED sent at the end. A
    request answered only when resent is noted."""
    got, resent = ask(node, "MISSION_REQUEST_LIST", lambda r: r.name == "MISSION_COUNT", mission_type=mission_type)
    if not got:
        return None, []
    head, items = got[0], []
    for seq in range(int(head.msg.count)):
        item, again = ask(node, request, lambda r, seq=seq: r.name in ITEMS and r.msg.seq == seq, seq=seq,
                          mission_type=mission_type)
        resent += again
        if not item:
            break
        items.append(item[0])
    node.send("MISSION_ACK", target_system=node.sysid, target_component=node.compid,
              type=MAV.MAV_MISSION_ACCEPTED, mission_type=mission_type)
    if resent:
        node.info(f"a download of mission_type {mission_type} needed {resent} resend(s) of its requests")
    return head, items


def shown(replies):
    return [f"{r.name} {r.msg.seq if r.name != 'MISSION_ACK' else result_name_mission(r.msg.type)}"
            for r in replies]


def idle_again(node, since, deadline):
    """Downloads tried until one is answered with MISSION_COUNT or ``deadline`` passes
    (a vehicle still in an upload refuses them: MAV_MISSION_DENIED); the time the
    MISSION_COUNT came, or None."""
    while node.now() < deadline:
        t = node.send("MISSION_REQUEST_LIST", target_system=node.sysid, target_component=node.compid,
                      mission_type=MISSION)
        if node.link.wait_for(lambda t=t: bool(node.from_vehicle(t, "MISSION_COUNT")),
                              min(1.0, max(0.0, deadline - node.now()))):
            node.send("MISSION_ACK", target_system=node.sysid, target_component=node.compid,
                      type=MAV.MAV_MISSION_ACCEPTED, mission_type=MISSION)
            return node.from_vehicle(t, "MISSION_COUNT")[0].t
        node.watch(min(0.5, max(0.0, deadline - node.now())))
    return None


def out_of_sequence_upload(node):
    """An upload of 4 items whose request for seq 1 is answered, once, with item 2: (the
    items, when the stray item was sent, the vehicle's replies)."""
    items, stray = node.plan(4), []

    def answer(reply):
        seq = reply.msg.seq
        if seq == 1 and not stray:
            stray.append(send_item(node, items[2]))
        elif 0 <= seq < len(items):
            send_item(node, items[seq])
    _, replies = drive_upload(node, len(items), answer, wait=float(node.params["mission_rerequest_max_s"]))
    return items, (stray[0] if stray else None), replies


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
    expect_plan(node, items, got, "MAV-MIS-9")


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


@rules("MAV-MIS-4")
def test_out_of_sequence_item_is_recovered(node):
    """MAV-MIS-4: the request for seq 1 answered with item 2 (out of sequence): the vehicle
    drops it, requests seq 1 again (within mission_rerequest_max_s), and the upload
    completes ACCEPTED; a download then gives the items uploaded, each at its seq (command
    and position)."""
    items, stray, replies = out_of_sequence_upload(node)
    after = [r for r in replies if stray is not None and r.t > stray]
    seqs = [r.msg.seq for r in after if r.name != "MISSION_ACK"]
    done = [r for r in after if r.name == "MISSION_ACK" and r.msg.type != MAV.MAV_MISSION_INVALID_SEQUENCE]
    node.expect_true(seqs[:1] == [1] and done and done[0].msg.type == MAV.MAV_MISSION_ACCEPTED, "MAV-MIS-4",
                     "after item 2 sent for the request of seq 1: seq 1 requested again, the upload "
                     "completed MAV_MISSION_ACCEPTED", ", ".join(shown(after)) or "nothing", shown(replies))
    head, got = download(node)
    node.expect_true(head is not None and head.msg.count == len(items), "MAV-MIS-4",
                     f"a download of {len(items)} items after it",
                     f"MISSION_COUNT {head.msg.count}" if head is not None else "no MISSION_COUNT")
    expect_plan(node, items, [r.msg for r in got], "MAV-MIS-4", fields=WHICH)


@rules("MAV-MIS-5")
def test_out_of_sequence_item_is_no_error(node):
    """MAV-MIS-5 (SHOULD): an item out of sequence is answered with no error MISSION_ACK
    (ArduPilot sends MAV_MISSION_INVALID_SEQUENCE: E-1)."""
    _, stray, replies = out_of_sequence_upload(node)
    acks = [r for r in replies if r.name == "MISSION_ACK"]
    if not acks or acks[-1].msg.type != MAV.MAV_MISSION_ACCEPTED:
        raise Inconclusive("MAV-MIS-5: the upload with an item out of sequence did not complete (MAV-MIS-4's)")
    errors = [r for r in acks if stray is not None and r.t > stray and r.msg.type != MAV.MAV_MISSION_ACCEPTED]
    node.expect_true(not errors, "MAV-MIS-5", "no error MISSION_ACK for the item out of sequence",
                     ", ".join(f"MISSION_ACK {result_name_mission(r.msg.type)}" for r in errors), shown(replies))


@rules("MAV-MIS-6")
def test_abandoned_upload_ends(node):
    """MAV-MIS-6: MISSION_COUNT 3, then no item at all: the vehicle's requests stop and
    within mission_abandon_max_s it serves a download (MISSION_COUNT), with no request
    after that."""
    abandon = float(node.params["mission_abandon_max_s"])
    since = node.send("MISSION_COUNT", target_system=node.sysid, target_component=node.compid, count=3,
                      mission_type=MISSION)
    deadline = since + abandon
    quiet = float(node.params["mission_rerequest_max_s"])

    def requests():
        return [r for r in node.mission_replies(since) if r.name != "MISSION_ACK"]

    def ended():
        reqs, acks = requests(), [r for r in node.mission_replies(since) if r.name == "MISSION_ACK"]
        return bool(acks) or node.now() - (reqs[-1].t if reqs else since) > quiet
    node.link.wait_for(ended, abandon)
    idle = idle_again(node, since, deadline)
    late = [r for r in requests() if idle is not None and r.t > idle]
    node.expect_true(idle is not None and not late, "MAV-MIS-6",
                     f"within {abandon:g} s of the abandoned MISSION_COUNT, a download answered and no request after it",
                     (f"{len(late)} request(s) after the download" if idle is not None else
                      f"no MISSION_COUNT for a download within {abandon:g} s") + f" ({len(requests())} requests in all)",
                     shown(node.mission_replies(since))[-6:])


@rules("MAV-MIS-7")
def test_failed_upload_keeps_the_plan(node):
    """MAV-MIS-7 (SHOULD): a plan of 4 uploaded; an upload of 3 whose item 2 has a command
    no MAV_CMD has ends with an error MISSION_ACK; a download then gives the plan of 4
    (command and position of each item; ArduPilot's uploads are not atomic: E-2)."""
    items = node.plan(4)
    node.expect_upload(node.upload(items), len(items))
    other = [dict(it, x=it["x"] + 900, z=it["z"] + 5.0) for it in node.plan(3)]

    def answer(reply):
        seq = reply.msg.seq
        if 0 <= seq < len(other):
            send_item(node, other[seq], **({"command": UNKNOWN_COMMAND} if seq == 2 else {}))
    since, replies = drive_upload(node, len(other), answer)
    acks = [r for r in replies if r.name == "MISSION_ACK"]
    if not acks or acks[-1].msg.type == MAV.MAV_MISSION_ACCEPTED:
        raise Inconclusive(f"MAV-MIS-7: the vehicle did not refuse an item with command {UNKNOWN_COMMAND} "
                           f"({', '.join(shown(replies))}): no failed upload to judge")
    idle_again(node, since, since + float(node.params["mission_abandon_max_s"]))
    head, got = download(node)
    node.expect_true(head is not None and head.msg.count == len(items), "MAV-MIS-7",
                     f"after the failed upload, the plan of {len(items)} items as it was",
                     f"MISSION_COUNT {head.msg.count}" if head is not None else "no MISSION_COUNT", shown(replies))
    expect_plan(node, items, [r.msg for r in got], "MAV-MIS-7", fields=WHICH)


@rules("MAV-MIS-18")
def test_cancelled_upload_stops(node):
    """MAV-MIS-18 (SHOULD): the request for seq 1 answered with MISSION_ACK
    MAV_MISSION_OPERATION_CANCELLED: no request comes after it within
    mission_rerequest_max_s (ArduPilot cannot be cancelled: E-2). The runner then ends the
    vehicle's upload with MISSION_COUNT 0."""
    items, cancel = node.plan(3), []

    def answer(reply):
        if reply.msg.seq == 1 and not cancel:
            cancel.append(node.send("MISSION_ACK", target_system=node.sysid, target_component=node.compid,
                                    type=MAV.MAV_MISSION_OPERATION_CANCELLED, mission_type=MISSION))
        elif reply.msg.seq == 0:
            send_item(node, items[0])
    since, replies = drive_upload(node, len(items), answer, until=lambda: bool(cancel))
    if not cancel:
        raise Inconclusive(f"MAV-MIS-18: the vehicle never requested seq 1 ({', '.join(shown(replies))})")
    node.watch(float(node.params["mission_rerequest_max_s"]))
    replies = node.mission_replies(since)
    after = [r for r in replies if r.t > cancel[0] and r.name != "MISSION_ACK"]
    node.upload([])  # the vehicle idle again, whatever it did with the cancel
    node.expect_true(not after, "MAV-MIS-18", "no MISSION_REQUEST after MAV_MISSION_OPERATION_CANCELLED",
                     f"{len(after)} request(s) after it: {', '.join(shown(after))}", shown(replies))


@rules("MAV-MIS-10")
def test_deprecated_item_messages_still_work(node):
    """MAV-MIS-10: an upload answered with MISSION_ITEM (degrees as floats) completes
    ACCEPTED, and a download asking with MISSION_REQUEST gets each item (MISSION_ITEM or
    MISSION_ITEM_INT) at the positions uploaded (to float32's precision)."""
    items = node.plan(3)

    def answer(reply):
        seq = reply.msg.seq
        if 0 <= seq < len(items):
            it = items[seq]
            node.send("MISSION_ITEM", target_system=node.sysid, target_component=node.compid, seq=seq,
                      frame=MAV.MAV_FRAME_GLOBAL_RELATIVE_ALT, command=it["command"], current=0, autocontinue=1,
                      param1=it["param1"], param2=it["param2"], param3=it["param3"], param4=it["param4"],
                      x=it["x"] * 1e-7, y=it["y"] * 1e-7, z=it["z"], mission_type=MISSION)
    _, replies = drive_upload(node, len(items), answer)
    acks = [r for r in replies if r.name == "MISSION_ACK"]
    node.expect_true(bool(acks) and acks[-1].msg.type == MAV.MAV_MISSION_ACCEPTED, "MAV-MIS-10",
                     "an upload answered with MISSION_ITEM completed MAV_MISSION_ACCEPTED",
                     ", ".join(shown(replies)) or "nothing")
    head, got = download(node, request="MISSION_REQUEST")
    node.expect_true(head is not None and len(got) == head.msg.count == len(items), "MAV-MIS-10",
                     f"MISSION_COUNT {len(items)}, each MISSION_REQUEST answered with its item",
                     f"MISSION_COUNT {head.msg.count}, {len(got)} items" if head is not None else "no MISSION_COUNT")
    first = home_items(node)
    bad = [r for r in got[first:] if abs(r.msg.x * (1e-7 if r.name == "MISSION_ITEM_INT" else 1.0)
                                         - items[r.msg.seq]["x"] * 1e-7) > 1e-5
           or r.msg.command != items[r.msg.seq]["command"]]
    node.expect_true(not bad, "MAV-MIS-10", "each item's command and latitude as uploaded",
                     "; ".join(r.describe() for r in bad[:2]))


@rules("MAV-MIS-11")
def test_deprecated_request_gets_the_int_item(node):
    """MAV-MIS-11 (SHOULD): MISSION_REQUEST answered with MISSION_ITEM_INT (ArduPilot
    answers MISSION_ITEM: E-6)."""
    items = node.plan(3)
    node.expect_upload(node.upload(items), len(items))
    since = node.send("MISSION_REQUEST", target_system=node.sysid, target_component=node.compid, seq=1,
                      mission_type=MISSION)
    node.link.wait_for(lambda: any(r.name in ITEMS and r.msg.seq == 1 for r in node.from_vehicle(since)),
                       float(node.params["mission_reply_max_s"]))
    got = [r for r in node.from_vehicle(since) if r.name in ITEMS and r.msg.seq == 1]
    if not got:
        raise Inconclusive("MAV-MIS-11: MISSION_REQUEST for seq 1 got no item (MAV-MIS-10's)")
    node.expect_true(got[0].name == "MISSION_ITEM_INT", "MAV-MIS-11",
                     "MISSION_REQUEST seq 1 answered with MISSION_ITEM_INT", got[0].name)


@rules("MAV-MIS-12")
def test_no_deprecated_messages_unasked(node):
    """MAV-MIS-12 (SHOULD): over the run (an upload of its own included), the vehicle sent
    no MISSION_REQUEST, and a MISSION_ITEM only to answer the runner's MISSION_REQUEST for
    that seq (ArduPilot requests upload items with MISSION_REQUEST: E-9)."""
    items = node.plan(2)
    node.expect_upload(node.upload(items), len(items))
    asked = [(t, data) for t, name, data in node.link.sent if name == "MISSION_REQUEST"]

    def problem(r):
        if r.name == "MISSION_REQUEST":
            return f"MISSION_REQUEST seq {r.msg.seq}"
        if r.name == "MISSION_ITEM" and not any(t < r.t for t, _ in asked):
            return f"MISSION_ITEM seq {r.msg.seq} unasked"
        return None
    frames = [r for r in node.from_vehicle() if r.name in ("MISSION_REQUEST", "MISSION_ITEM")]
    node.expect_true(not [r for r in frames if problem(r)], "MAV-MIS-12",
                     "no MISSION_REQUEST, no MISSION_ITEM but as an answer to MISSION_REQUEST",
                     f"{sum(1 for r in frames if problem(r))} frame(s): "
                     + ", ".join(sorted({problem(r) for r in frames if problem(r)})[:4]))


@rules("MAV-MIS-16")
def test_plan_types_are_kept_apart(node):
    """MAV-MIS-16: a mission of 3 uploaded; an upload of one rally point
    (MAV_MISSION_TYPE_RALLY) is either served with requests and an ACK all of mission_type
    RALLY, or refused with an error MISSION_ACK of mission_type RALLY; the mission downloaded
    after it is the mission uploaded (command and position of each item), and an accepted
    rally download counts 1."""
    rally = MAV.MAV_MISSION_TYPE_RALLY
    items = node.plan(3)
    node.expect_upload(node.upload(items), len(items))
    point = dict(items[2], seq=0, command=MAV.MAV_CMD_NAV_RALLY_POINT, param1=0.0, mission_type=rally)
    _, replies = drive_upload(node, 1, lambda r: send_item(node, point) if r.msg.seq == 0 else None,
                              mission_type=rally)
    wrong = [r for r in replies if r.msg.mission_type != rally]
    acks = [r for r in replies if r.name == "MISSION_ACK"]
    node.expect_true(bool(acks) and not wrong, "MAV-MIS-16",
                     "the rally upload's requests and MISSION_ACK, all with mission_type MAV_MISSION_TYPE_RALLY",
                     (f"{len(wrong)} of mission_type {sorted({r.msg.mission_type for r in wrong})}: "
                      + ", ".join(shown(wrong)[:4])) if acks else "no MISSION_ACK", shown(replies))
    head, got = download(node)
    node.expect_true(head is not None and head.msg.count == len(items) and head.msg.mission_type == MISSION,
                     "MAV-MIS-16", f"the mission after the rally upload: MISSION_COUNT {len(items)}, mission_type 0",
                     f"MISSION_COUNT {head.msg.count}, mission_type {head.msg.mission_type}" if head else "no MISSION_COUNT")
    expect_plan(node, items, [r.msg for r in got], "MAV-MIS-16", fields=WHICH)
    if acks[-1].msg.type == MAV.MAV_MISSION_ACCEPTED:
        head, _ = download(node, mission_type=rally)
        node.expect_true(head is not None and head.msg.count == 1 and head.msg.mission_type == rally, "MAV-MIS-16",
                         "a rally download: MISSION_COUNT 1 of mission_type RALLY",
                         f"MISSION_COUNT {head.msg.count} of mission_type {head.msg.mission_type}" if head
                         else "no MISSION_COUNT")
        ask(node, "MISSION_CLEAR_ALL", lambda r: r.name == "MISSION_ACK" and r.msg.mission_type == rally,
            mission_type=rally)  # its MISSION_ACK awaited, not left to the next case's upload
    else:
        node.info(f"MAV-MIS-16: rally points refused, {result_name_mission(acks[-1].msg.type)}")


@rules("MAV-MIS-19")
def test_positions_are_kept_to_the_unit(node):
    """MAV-MIS-19: waypoints at positions that use every digit of degE7 (one unit, 1e-7
    degree, off the vehicle's; south-east; near the poles' and the antimeridian's bounds)
    come back from a download with the same integers."""
    items = node.plan(5)
    spots = [(items[2]["x"] + 1, items[2]["y"] - 1), (-338567844, 1512152967), (899999999, -1799999999)]
    for it, (x, y) in zip(items[2:], spots, strict=True):
        it.update(x=x, y=y)
    node.expect_upload(node.upload(items), len(items))
    head, got = download(node)
    node.expect_true(head is not None and len(got) == len(items), "MAV-MIS-19", f"{len(items)} items downloaded",
                     f"{len(got)} items")
    bad = [(items[r.msg.seq]["x"], items[r.msg.seq]["y"], r.msg.x, r.msg.y) for r in got[2:]
           if (r.msg.x, r.msg.y) != (items[r.msg.seq]["x"], items[r.msg.seq]["y"]) or r.name != "MISSION_ITEM_INT"]
    node.expect_true(not bad, "MAV-MIS-19", "x, y as uploaded, in degE7",
                     "; ".join(f"{x}, {y} came back {gx}, {gy}" for x, y, gx, gy in bad))


@rules("MAV-MIS-17", phase="end")
def test_mission_types_are_mav_mission_types(node):
    """MAV-MIS-17: every mission_type the vehicle sent over the run (a download of its own
    included) is a MAV_MISSION_TYPE other than MAV_MISSION_TYPE_ALL (kept for
    MISSION_CLEAR_ALL, which a vehicle does not send)."""
    download(node)
    types = {v for v, e in MAV.enums["MAV_MISSION_TYPE"].items() if not e.name.endswith("_ENUM_END")}
    types.discard(MAV.MAV_MISSION_TYPE_ALL)
    frames = [r for r in node.from_vehicle() if r.name.startswith("MISSION_") and hasattr(r.msg, "mission_type")]
    node.expect_frames(frames, lambda r: None if r.msg.mission_type in types
                       else f"{r.name} mission_type {r.msg.mission_type}", "MAV-MIS-17",
                       "mission_type MISSION, FENCE or RALLY")


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

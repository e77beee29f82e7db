"""MSG — the UPDATE stream (NSQD-MSG-1, D-8), each command's effect on the flight state
(NSQD-MSG-3: the messages table of spec/nsqd.yaml), unknown ids (NSQD-MSG-4/5/6, D-2) and
malformed bodies (NSQD-MSG-7, D-3, D-7)."""

from __future__ import annotations

import struct
import time

import pytest

from mcp_conform.conformance.marks import rules
from mcp_conform.harness.errors import CaseFailure
from mcp_conform.spec import NSQD

GPX = ('<?xml version="1.0"?><gpx version="1.1" creator="mcp-conform"><rte>'
       '<rtept lat="55.3676" lon="10.4321"/><rtept lat="55.3680" lon="10.4330"/></rte></gpx>')

VALID = {
    "TAKEOFF": {}, "LAND": {}, "STOP_TEST": {}, "STOP_HOVER_TEST": {}, "CAPTURE_IMAGES": {},
    "STOP_CAPTURE_IMAGES": {},
    "SET_RPYTFF": {"roll": "1.5", "pitch": "-2", "yaw": "90", "thrust": "40", "flag": 1, "file_name": "test.csv"},
    "SET_HOVERHEIGHT": {"height": 12, "file_name": "hover.csv"},
    "UPLOAD_FLIGHTPATH": {"gpx": GPX},
}
EFFECTS = [m.name for m in NSQD.messages if m.effect.to]


@rules("NSQD-MSG-1")
def test_update_stream_keeps_its_period(node):
    conn = node.open()
    t0 = conn.opened
    conn.wait_for(lambda: len(conn.updates()) >= 4, 4 * node.gap_max)
    ups = [u.t for u in conn.updates()]
    period = (ups[-1] - ups[0]) / (len(ups) - 1) if len(ups) > 1 else node.gap_max
    # twelve periods: a stream that stops shows as a gap over the allowance; and never less than
    # twice the allowance, or at a fast period (under 0.125 s: 12 periods < 1.5 s) no gap over it
    # could fit in the watch, and a stream that stops could not fail here
    watch = max(12 * period, 2 * node.gap_max)
    conn.watch(max(0.0, t0 + watch - time.monotonic()))
    watch = time.monotonic() - t0
    node.check_stream(conn)
    times = [t0] + [u.t for u in conn.updates()]
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)] + [time.monotonic() - times[-1]]
    worst = max(gaps)
    if worst > node.gap_max:
        raise node.fail("NSQD-MSG-1", f"UPDATE at least every {node.gap_max:g} s while connected",
                        f"a gap of {worst:.2f} s ({len(times) - 1} UPDATEs in {watch:g} s)")


@rules("NSQD-MSG-3")
@pytest.mark.parametrize("name", EFFECTS)
def test_command_takes_its_effect(node, name):
    msg = node.spec.message(name)
    conn = node.open()
    _, start = node.start_outside(conn, msg.effect.to)
    since = time.monotonic()
    conn.send(node.encode(name, **VALID[name]))
    node.expect_state(conn, msg.effect.to, since, "NSQD-MSG-3", name if start == "settled" else f"{name} ({start})",
                      or_error=msg.effect.or_error)


@rules("NSQD-MSG-4")
def test_unknown_id_is_consumed_by_its_length(node):
    conn = node.open()
    name, state = node.probe(conn)
    node.settle(conn, avoid=(state,))
    conn.send(node.frame(200, bytes(range(12))))
    time.sleep(0.1)
    since = time.monotonic()
    conn.send(node.encode(name))
    node.expect_state(conn, (state,), since, "NSQD-MSG-4", f"a 17-byte frame with id 200, then {name}")


@rules("NSQD-MSG-5")
def test_unknown_id_is_answered_with_error(node):
    conn = node.open()
    since = time.monotonic()
    conn.send(node.frame(201, b""))
    node.expect_error(conn, since, "NSQD-MSG-5", "a frame with id 201")


@rules("NSQD-MSG-6")
def test_unknown_id_leaves_the_flight_state(node):
    conn = node.open()
    prior = node.settle(conn, avoid=(node.state_value("HOVER"),))
    since = time.monotonic()
    conn.send(node.frame(99, b"\x01\x02"))
    node.expect_unchanged(conn, prior, since, "NSQD-MSG-6", "a frame with id 99")


def _s(n: int, data: bytes = b"") -> bytes:
    return struct.pack(">h", n) + data


def _str(data: bytes) -> bytes:
    return _s(len(data), data)


def _rpytff(roll: bytes) -> bytes:
    return roll + _str(b"0") + _str(b"0") + _str(b"40") + struct.pack(">i", 1) + _str(b"t.csv")


MALFORMED = [
    ("string-length-negative", "SET_RPYTFF", _rpytff(_s(-1, b"1.5"))),
    ("string-length-past-frame", "SET_RPYTFF", _rpytff(_s(30000, b"1.5"))),
    ("body-cut-short", "SET_HOVERHEIGHT", b"\x00\x00"),
    ("number-text-not-a-number", "SET_RPYTFF", _rpytff(_str(b"abc"))),
    ("number-text-nan", "SET_RPYTFF", _rpytff(_str(b"nan"))),
    ("gpx-not-xml", "UPLOAD_FLIGHTPATH", _str(b"<gpx><rtept la")),
    ("gpx-no-points", "UPLOAD_FLIGHTPATH", _str(b'<gpx version="1.1"></gpx>')),
    ("gpx-out-of-range", "UPLOAD_FLIGHTPATH", _str(b'<gpx><wpt lat="123.5" lon="10.0"></wpt></gpx>')),
    ("gpx-deeply-nested", "UPLOAD_FLIGHTPATH", _str(b"<gpx>" + b"<rte>" * 400 + b"</rte>" * 400 + b"</gpx>")),
]


@rules("NSQD-MSG-7", "NSQD-ROB-1")
@pytest.mark.parametrize("label,name,body", MALFORMED, ids=[m[0] for m in MALFORMED])
def test_malformed_body_is_not_applied(node, label, name, body):
    msg = node.spec.message(name)
    conn = node.open()
    prior = node.settle(conn, avoid=msg.effect.to)
    since = time.monotonic()
    conn.send(node.frame(msg.id, body))
    node.expect_unchanged(conn, prior, since, "NSQD-MSG-7", f"{name} with {label.replace('-', ' ')}")
    node.expect_alive("NSQD-ROB-1", f"{name} with {label.replace('-', ' ')}")


def _large_gpx(limit: int) -> str:
    """A valid path as long as a frame allows (D-7: the 8192-byte bound holds it)."""
    head, tail = '<?xml version="1.0"?><gpx version="1.1" creator="mcp-conform"><rte>', "</rte></gpx>"
    pts, i = "", 0
    while True:
        pt = f'<rtept lat="55.{3676 + i:05d}" lon="10.{4321 + i:05d}"/>'
        if len(head) + len(pts) + len(pt) + len(tail) > limit:
            return head + pts + tail
        pts, i = pts + pt, i + 1


@rules("NSQD-MSG-3", "NSQD-FRM-5", "NSQD-ROB-1")
def test_large_flight_path_is_taken(node):
    msg = node.spec.message("UPLOAD_FLIGHTPATH")
    conn = node.open()
    _, start = node.start_outside(conn, msg.effect.to)
    gpx = _large_gpx(node.spec.framing.max_length - node.spec.framing.header_size - 2)
    since = time.monotonic()
    data = node.encode("UPLOAD_FLIGHTPATH", gpx=gpx)
    conn.send(data)
    what = f"UPLOAD_FLIGHTPATH with a {len(gpx)}-byte path" + ("" if start == "settled" else f" ({start})")
    try:
        node.expect_state(conn, msg.effect.to, since, "NSQD-MSG-3", what)
    except CaseFailure:
        if conn.closed_at is not None and node.session.death(grace=0.5) is None:  # the frame's size, not the path
            raise node.fail("NSQD-FRM-5", f"a frame of {len(data)} bytes accepted and the connection kept",
                            "the backend closed the connection") from None
        raise


IN_SYNC = [
    ("pid-flag-out-of-range", "SET_PID", _str(b"1") + _str(b"2") + _str(b"3") + struct.pack(">i", 3)),
    ("string-length-negative", "SET_RPYTFF", _rpytff(_s(-1, b"1.5"))),
    ("number-text-not-a-number", "SET_PID", _str(b"x") + _str(b"2") + _str(b"3") + struct.pack(">i", 1)),
]


@rules("NSQD-MSG-7")
@pytest.mark.parametrize("label,name,body", IN_SYNC, ids=[m[0] for m in IN_SYNC])
def test_rejected_frame_leaves_the_stream_in_sync(node, label, name, body):
    """A rejected frame is consumed by its length: the frame after it, on the same connection,
    is handled (E-6: the published code returns early and reads the next frame with the old size)."""
    conn = node.open()
    probe, state = node.probe(conn)
    node.settle(conn, avoid=(state,))
    conn.send(node.frame(node.spec.message(name).id, body))
    conn.watch(0.05)
    if conn.closed_at is not None:
        return  # D-3: a backend may close on a malformed body; that it lives on is NSQD-ROB-1's (conclude)
    since = time.monotonic()
    conn.send(node.encode(probe))
    node.expect_state(conn, (state,), since, "NSQD-MSG-7", f"{name} with {label.replace('-', ' ')}, then {probe}")

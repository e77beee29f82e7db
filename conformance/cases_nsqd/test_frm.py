"""FRM — framing: the 32-bit length that counts itself (E-1), reassembly, batching, bounds."""

from __future__ import annotations

import time

import pytest

from mcp_conform.conformance.marks import rules


@rules("NSQD-FRM-1", "NSQD-MSG-2")
def test_backend_frames_are_well_formed(node):
    """Three UPDATEs read and judged: length, id, layout, state (``check_stream``)."""
    conn = node.open()
    conn.wait_for(lambda: len(conn.updates()) >= 3, 3 * node.gap_max)
    node.check_stream(conn)
    if len(conn.updates()) < 3:
        raise node.fail("NSQD-MSG-1", "three UPDATEs", f"{len(conn.updates())} UPDATE(s) in {3 * node.gap_max:g} s")


@rules("NSQD-FRM-2")
def test_frame_split_byte_by_byte(node):
    conn = node.open()
    name, state = node.probe(conn)
    node.settle(conn, avoid=(state,))
    since = time.monotonic()
    conn.send(node.encode(name), split=1, gap=0.01)
    node.expect_state(conn, (state,), since, "NSQD-FRM-2", f"{name} sent one byte per segment")


@rules("NSQD-FRM-3")
def test_several_frames_in_one_segment(node):
    conn = node.open()
    name, state = node.probe(conn)
    node.settle(conn, avoid=(state,))
    since = time.monotonic()
    conn.send(node.encode("FOLLOW_LINE") + node.encode("SET_AUTH") + node.encode(name))
    node.expect_state(conn, (state,), since, "NSQD-FRM-3",
                      f"FOLLOW_LINE, SET_AUTH and {name} in one segment (the last one's effect)")


BAD_LENGTHS = [0, 1, 4, -1, -2**31, 8193, 2**31 - 1]


@rules("NSQD-FRM-4", "NSQD-ROB-1")
@pytest.mark.parametrize("length", BAD_LENGTHS)
def test_length_out_of_bounds_closes(node, length):
    conn = node.open()
    conn.send(node.frame(node.spec.message("TAKEOFF").id, b"\0" * 8, length=length))
    node.expect_closed(conn, "NSQD-FRM-4", f"a frame of length {length}")
    node.expect_alive("NSQD-ROB-1", f"a frame of length {length}")


@rules("NSQD-FRM-5")
def test_largest_frame_is_accepted(node):
    conn = node.open()
    name, state = node.probe(conn)
    node.settle(conn, avoid=(state,))
    mx = node.spec.framing.max_length
    text = "x" * (mx - node.spec.framing.header_size - 2)
    big = node.encode("ERROR", text=text)
    assert len(big) == mx
    since = time.monotonic()
    conn.send(big)
    time.sleep(0.1)  # apart from the probe, which would otherwise judge NSQD-FRM-3 too
    conn.send(node.encode(name))
    node.expect_state(conn, (state,), since, "NSQD-FRM-5", f"an ERROR frame of {mx} bytes, then {name}")

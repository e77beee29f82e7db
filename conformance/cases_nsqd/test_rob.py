"""ROB — robustness: no input ends the backend (NSQD-ROB-1), a client that leaves mid-frame
by FIN or RST (NSQD-ROB-2), and each connection a new stream (NSQD-ROB-3)."""

from __future__ import annotations

import random
import struct
import time

import pytest

from mcp_conform.conformance.marks import rules

GARBAGE_FRAMES = 200


@rules("NSQD-ROB-1")
def test_random_frames_leave_the_backend_serving(node):
    """Seeded frames of valid length with random ids and bodies, then a new connection."""
    rng = random.Random(node.session.cfg.seed or 4)
    conn = node.open()
    for _ in range(GARBAGE_FRAMES):
        msg_id = rng.choice([rng.randrange(256), rng.choice([m.id for m in node.spec.messages])])
        if msg_id == node.spec.message("UPLOAD_FLIGHTPATH").id:
            msg_id = node.spec.message("FOLLOW_LINE").id  # a random valid path would start a route
        body = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 40)))
        if not conn.send(node.frame(msg_id, body)) or node.session.death() is not None:
            break  # closed (D-3 allows it) or dead: the last frame sent is the evidence
    conn.watch(0.3)
    node.expect_alive("NSQD-ROB-1", f"{GARBAGE_FRAMES} random frames")


@rules("NSQD-ROB-2")
@pytest.mark.parametrize("how", ["fin", "rst"])
def test_client_leaving_mid_frame(node, how):
    conn = node.open()
    whole = node.encode("SET_RPYTFF", roll="1", pitch="2", yaw="3", thrust="4", flag=1, file_name="x.csv")
    conn.send(whole[: len(whole) // 2])
    time.sleep(0.05)
    conn.close(rst=how == "rst")
    node.session.conns.remove(conn)
    node.expect_alive("NSQD-ROB-2", f"a client that sent half a frame and left by {how.upper()}")


@rules("NSQD-ROB-3")
def test_a_cut_frame_is_not_joined_to_the_next_connection(node):
    conn = node.open()
    name, state = node.probe(conn)
    node.settle(conn, avoid=(state,))
    conn.send(struct.pack(">i", 256)[:3])  # three bytes of a length prefix, then gone
    time.sleep(0.05)
    conn.close()
    node.session.conns.remove(conn)
    fresh = node.open()
    since = time.monotonic()
    fresh.send(node.encode(name))
    node.expect_state(fresh, (state,), since, "NSQD-ROB-3",
                      f"3 bytes of a prefix on a closed connection, then {name} on a new one")

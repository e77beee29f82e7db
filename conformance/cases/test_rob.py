"""ROB — robustness to bad input.

Every malformed input comes from a fixed, seeded corpus drawn from the spec's strategies
(``spec.generators.malformed_corpus``) plus explicit edge cases, so every run sends the
same bytes. Each input is followed by a liveness probe (a fresh WP_Off awaited across
retransmissions, MCP-ROB-5); "no ACK" is judged over the ACK window (D-6).
"""

from __future__ import annotations

import random

from mcp_conform.conformance.drone_case import Attempt
from mcp_conform.conformance.marks import rules
from mcp_conform.harness.driver import Sent
from mcp_conform.harness.rx_queue import FLOOD_READ_S, wait_read
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import HEADER_SIZE, MAX_DATAGRAM, PREAMBLE, Action, build_datagram
from mcp_conform.spec.generators import malformed_corpus

PER_KIND = 6


def _random_bytes(rnd: random.Random, n: int) -> bytes:
    """``bytes(rnd.getrandbits(8) for _ in range(n))``, the same bytes and ``rnd`` left in the
    same state, ~30x cheaper: ``getrandbits(8)`` is the top byte of one 32-bit draw, and
    ``getrandbits(32 * n)`` is n draws, the first lowest (tests/sim/test_random_bytes.py)."""
    return rnd.getrandbits(32 * n).to_bytes(4 * n, "little")[3::4]


def _corpus(node, *kinds: str) -> list[tuple[str, bytes]]:
    """Seeded entries addressed to the node, with seqs reserved from the runner's counter."""
    drv = node.driver
    with drv.seq_lock:  # reserved at once: cases of a batch draw seqs meanwhile
        first = drv.peek_seq()
        entries = malformed_corpus(node.session.cfg.seed, PER_KIND, dst=node.target_id, src=drv.our_id,
                                   first_seq=first, kinds=list(kinds))
        drv.set_seq(first + len(entries) + 1)
    return [(f"{kind} #{i}", data) for i, (kind, data) in enumerate(entries)]


@rules("MCP-ROB-1", "MCP-ROB-5")
def test_short_datagrams_are_discarded(node):
    inputs = [("empty datagram", b""), ("preamble only", PREAMBLE),
              ("16 bytes", build_datagram(node.target_id, 0, 1, int(Action.WP_OFF))[:HEADER_SIZE - 1])]
    attempts = node.try_inputs(inputs + _corpus(node, "short"))
    node.expect_discarded(attempts, "MCP-ROB-1", died_rule="MCP-ROB-1")


@rules("MCP-ROB-2", "MCP-ROB-5")
def test_bad_preamble_is_discarded(node):
    attempts = node.try_inputs(_corpus(node, "bad_preamble"))
    node.expect_discarded(attempts, "MCP-ROB-2")


@rules("MCP-ROB-3", "MCP-ROB-5")
def test_unknown_action_code_is_discarded(node):
    drv = node.driver
    edge = [(f"action {a}", build_datagram(node.target_id, drv.our_id, drv.next_seq(), a))
            for a in (int(Action.ANY), 10, 0xFFFF)]
    attempts = node.try_inputs(edge + _corpus(node, "unknown_action"))
    node.expect_discarded(attempts, "MCP-ROB-3")


@rules("MCP-ROB-4", "MCP-ROB-5")
def test_payload_that_does_not_fit_is_not_acked(node):
    attempts = node.try_inputs(_corpus(node, "wrong_payload_length", "count_mismatch", "bad_mavlink_crc"))
    node.expect_discarded(attempts, "MCP-ROB-4")


@rules("MCP-ROB-5")
def test_unexpected_messages_are_survived(node):
    """Well-formed but unexpected input: a second Start_Mission, a Mission_Ready sent to a
    drone, an ACK of nothing, WP_Off with no active waypoint, empty lists."""
    drv = node.driver
    t = node.target_id

    def msg(action, payload=None):
        from mcp_conform.spec.codec import Message, encode
        return encode(Message(t, drv.our_id, drv.next_seq(), action, payload))
    inputs = [("Start_Mission again", msg(Action.START_MISSION)),
              ("Mission_Ready to a drone", msg(Action.MISSION_READY)),
              ("ACK of nothing", msg(Action.ACK, (drv.peek_seq() + 0x3000) & 0xFFFF)),
              ("WP_Off twice", msg(Action.WP_OFF)), ("WP_Off twice (2)", msg(Action.WP_OFF)),
              ("empty WP_List", msg(Action.WP_LIST, ())), ("empty Obstacles_List", msg(Action.OBSTACLES_LIST, ()))]
    node.expect_discarded(node.try_inputs(inputs), "MCP-ROB-5", silent=False)


@rules("MCP-ROB-6", "MCP-ROB-1")
def test_datagrams_of_0_and_65507_bytes_are_survived(node):
    """A crash on the empty datagram breaks MCP-ROB-1 (shorter than 17 bytes, "no crash");
    on the large ones MCP-ROB-6."""
    drv = node.driver
    rnd = random.Random(node.session.cfg.seed)
    head = build_datagram(node.target_id, drv.our_id, drv.next_seq(), int(Action.WP_LIST), b"\x00\x01")
    big = head + _random_bytes(rnd, MAX_DATAGRAM - len(head))
    junk = _random_bytes(rnd, MAX_DATAGRAM)
    attempts = node.try_inputs([("0 bytes", b"", "MCP-ROB-1"), (f"{len(big)}-byte WP_List", big),
                                (f"{len(junk)} random bytes", junk)])
    node.expect_discarded(attempts, "MCP-ROB-6", died_rule="MCP-ROB-6", live_rule="MCP-ROB-6", silent=False)


@rules("MCP-ROB-7", phase="late")
def test_flood_of_malformed_datagrams(node):
    """10 000 malformed datagrams as fast as loopback takes them, then a liveness probe
    (retried across retransmissions before it is judged), sent (D-8) once the node has read what
    its socket holds of the flood (``harness.rx_queue``; at most FLOOD_READ_S): "ACKs
    normally right after" is judged on the node's answers, not on the CPU a loaded host gave
    it for the backlog. A node that stops reading is probed at the bound, and judged."""
    # short datagrams are MCP-ROB-1's (a node that dies on them is caught there)
    corpus = [data for _, data in _corpus(node, "bad_preamble", "unknown_action", "count_mismatch")]
    node.prove_live("node not live before the flood: nothing to judge")
    count = int(SPEC.params["flood_count"])
    sock = node.driver.open_side_socket()
    try:
        sent = node.driver.flood(corpus, count, sock=sock, limit=30.0)
    finally:
        sock.close()
    node.info(f"flooded {sent} malformed datagrams")
    # the probe goes once the node has read the flood (its socket's queue empty: a node a
    # loaded host starves of CPU works through its backlog first), at most FLOOD_READ_S later
    host, port = node.driver.target[:2]
    took = wait_read(host, port, FLOOD_READ_S)
    if took is not None:
        node.info(f"the node read the flood's backlog {took:.2f} s after it")
    probe, died = node.probe_after_input()
    flood = Sent(node.session.clock.monotonic(), node.session.clock.time_ns(), corpus[0], node.driver.target, -1, -1, -1, -1)
    attempts = [Attempt(f"flood of {sent} malformed datagrams", flood, probe, died or probe is None)]
    if probe is None or not probe.acked:
        node.node_silent = not died
    node.expect_discarded(attempts, "MCP-ROB-7", died_rule="MCP-ROB-7", live_rule="MCP-ROB-7", silent=False)

"""Tests of the blocking API (reference_impl.api): two ``Mcp`` objects on loopback.

Free ports only (``local_port=0``), unicast to 127.0.0.1 except where loopback broadcast is
the point; short retransmission timeouts so every test takes a fraction of a second.
"""

from __future__ import annotations

import socket
import threading

import pytest

from mcp_conform.reference_impl import (
    Action,
    DeliveryFailed,
    LocalProtocolError,
    Mcp,
    McpException,
    MissionItem,
    MissionMessageHandlerBase,
)
from mcp_conform.spec.codec import BROADCAST_ID, Message, build_datagram, decode, encode

RTO = 0.05
LOOP = "127.0.0.1"


class Recorder(MissionMessageHandlerBase):
    """Records every handler call as (method, buffer, msg)."""

    def __init__(self) -> None:
        super().__init__(None)
        self.calls: list[tuple[str, object, object]] = []
        self.lock = threading.Lock()

    def _rec(self, name: str, buffer: object, msg: object = None) -> None:
        with self.lock:
            self.calls.append((name, buffer, msg))

    def handle_start_mission_message(self, buffer, msg):  # type: ignore[override]
        self._rec("start", buffer, msg)

    def handle_wp_list_message(self, buffer):  # type: ignore[override]
        self._rec("wp_list", buffer)

    def handle_wp_off_message(self, buffer=None, msg=None):  # type: ignore[override]
        self._rec("wp_off", buffer, msg)

    def handle_mission_ready_message(self, buffer, msg):  # type: ignore[override]
        self._rec("ready", buffer, msg)

    def handle_end_mission_message(self):  # type: ignore[override]  # the description's shape
        self._rec("end", None)


def make_pair(**kw):
    """A manager (ID 0) and a drone (ID 1) on free loopback ports, each sending to the other."""
    mgr_h, drone_h = Recorder(), Recorder()
    mgr = Mcp(mgr_h, 0, 9, LOOP, 0, bind_host=LOOP, timeout=RTO, retries=20, **kw)
    drone = Mcp(drone_h, 0, mgr.local_port, LOOP, 1, bind_host=LOOP, timeout=RTO, retries=20, **kw)
    mgr.remote_address = (LOOP, drone.local_port)
    return mgr, mgr_h, drone, drone_h


@pytest.fixture
def pair():
    mgr, mgr_h, drone, drone_h = make_pair()
    yield mgr, mgr_h, drone, drone_h
    drone.close()
    mgr.close()


ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.5, -78.25, 10.0, 0, 16, 1, 1, 3, 0, 1)


def test_unicast_both_directions_blocks_until_acked_and_runs_handlers(pair):
    mgr, mgr_h, drone, drone_h = pair
    drone.send_unicast_message(Action.MISSION_READY, None, 0)  # returns only once ACKed
    got = mgr.recv_message(Action.MISSION_READY, timeout=2)
    assert got is not None and got.src == 1 and got.dst == 0 and got.payload is None
    mgr.send_unicast_message(Action.START_MISSION, None, 1)
    mgr.send_unicast_message(Action.WP_LIST, (ITEM, ITEM), 1)
    assert drone.recv_message(Action.START_MISSION, timeout=2).action == Action.START_MISSION
    wp = drone.recv_message(Action.WP_LIST, timeout=2)
    assert wp.payload == (ITEM, ITEM)
    # handlers ran before recv_message returned, with (buffer, msg) or (buffer) as declared
    assert [c[0] for c in drone_h.calls] == ["start", "wp_list"]
    assert drone_h.calls[0][2].src == 0
    assert drone_h.calls[1][1] == (ITEM, ITEM)
    assert mgr_h.calls[0][0] == "ready"


def test_handler_with_no_parameters_is_called(pair):
    mgr, _, drone, drone_h = pair
    mgr.send_unicast_message(Action.END_MISSION, None, 1)
    assert drone.recv_message(Action.END_MISSION, timeout=2) is not None
    assert drone_h.calls == [("end", None, None)]


def test_unicast_to_absent_peer_raises_after_retries(pair):
    mgr, _, drone, _ = pair
    with pytest.raises(McpException, match="MCP-RTX-1"):
        drone.send_unicast_message(Action.MISSION_READY, None, 42, timeout=0.02, retries=2)
    # the node is still usable afterwards
    drone.send_unicast_message(Action.MISSION_READY, None, 0)


def test_per_call_timeout_and_retries_count_copies():
    """retries=N sends N+1 copies spaced by the timeout, then gives up (MCP-RTX-1)."""
    rx = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    rx.bind((LOOP, 0))
    rx.settimeout(1.0)
    failed: list[DeliveryFailed] = []
    ev_cb = lambda ev: failed.append(ev) if isinstance(ev, DeliveryFailed) else None  # noqa: E731
    with Mcp(Recorder(), 0, rx.getsockname()[1], LOOP, 1, bind_host=LOOP, on_event=ev_cb) as node:
        with pytest.raises(McpException):
            node.send_unicast_message(Action.MISSION_READY, None, 0, timeout=0.02, retries=3)
    copies = []
    rx.settimeout(0.2)
    try:
        while True:
            copies.append(rx.recv(2048))
    except TimeoutError:
        pass
    rx.close()
    assert len(copies) == 4 and len(set(copies)) == 1  # MCP-SEQ-2: the same bytes each time
    assert failed and failed[0].copies == 4


def test_broadcast_not_acked_and_delivered_over_loopback_broadcast():
    """Two wildcard-bound nodes; the manager broadcasts to 127.255.255.255 (MCP-TRN-1)."""
    h = Recorder()
    acks: list[object] = []
    drone = Mcp(h, 0, 9, "127.255.255.255", 1, timeout=RTO, retries=3)
    mgr = Mcp(Recorder(), 0, drone.local_port, "127.255.255.255", 0, timeout=RTO, retries=3,
              on_event=acks.append)
    try:
        mgr.send_broadcast_message(Action.WP_OFF, None)
        got = drone.recv_message(Action.WP_OFF, timeout=2)
        assert got is not None and got.dst == BROADCAST_ID
        assert drone.recv_message(timeout=0.2) is None  # sent once (MCP-RTX-4)
        assert not any(type(e).__name__ in ("AckReceived", "Unexpected") for e in acks)  # no ACK came back
    finally:
        mgr.close()
        drone.close()


def test_recv_message_filters_by_action_and_times_out(pair):
    mgr, _, drone, _ = pair
    assert drone.recv_message(timeout=0.05) is None
    mgr.send_unicast_message(Action.WP_OFF, None, 1)
    mgr.send_unicast_message(Action.START_MISSION, None, 1)
    # the WP_Off is taken and ignored while waiting for Start_Mission (the description's rule)
    got = drone.recv_message(Action.START_MISSION, timeout=2)
    assert got is not None and got.action == Action.START_MISSION
    assert drone.recv_message(Action.ANY, timeout=0.05) is None
    mgr.send_unicast_message(Action.WP_OFF, None, 1)
    assert drone.recv_message(Action.START_MISSION, timeout=0.1) is None


def test_acks_while_application_is_not_receiving_and_handler_is_slow():
    """MCP-ACK-1/7: the network thread ACKs even while a handler blocks."""
    gate = threading.Event()

    class Slow(MissionMessageHandlerBase):
        def handle_wp_off_message(self, buffer=None, msg=None):
            gate.wait(2)

    mgr, _, _, _ = make_pair()
    drone = Mcp(Slow(), 0, mgr.local_port, LOOP, 1, bind_host=LOOP, timeout=RTO, retries=20)
    mgr.remote_address = (LOOP, drone.local_port)
    try:
        for _ in range(3):  # each blocks until ACKed, although the first handler still waits
            mgr.send_unicast_message(Action.WP_OFF, None, 1, timeout=0.2, retries=3)
    finally:
        gate.set()
        drone.close()
        mgr.close()


def test_raw_peer_gets_correct_ack_and_duplicates_are_delivered_once():
    """A plain socket plays the manager: ACK fields (MCP-ACK-2/3) and duplicate discard (DUP-1)."""
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind((LOOP, 0))
    peer.settimeout(2.0)
    with Mcp(Recorder(), 0, peer.getsockname()[1], LOOP, 7, bind_host=LOOP) as node:
        cmd = encode(Message(7, 0, 500, Action.WP_OFF, None))
        for _ in range(2):
            peer.sendto(cmd, (LOOP, node.local_port))
            ack = decode(peer.recv(2048))
            assert (ack.action, ack.dst, ack.src, ack.payload) == (Action.ACK, 0, 7, 500)
        peer.sendto(build_datagram(7, 0, 501, Action.WP_OFF, b"junk"), (LOOP, node.local_port))
        peer.sendto(b"short", (LOOP, node.local_port))
        assert node.recv_message(timeout=1).seq == 500
        assert node.recv_message(timeout=0.1) is None  # copy and malformed ones not delivered
    peer.close()


def test_reply_to_source_sends_acks_to_the_datagram_source():
    peer = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    peer.bind((LOOP, 0))
    peer.settimeout(2.0)
    with Mcp(Recorder(), 0, 9, LOOP, 3, bind_host=LOOP, reply_to_source=True) as node:
        peer.sendto(encode(Message(3, 0, 1, Action.START_MISSION, None)), (LOOP, node.local_port))
        assert decode(peer.recv(2048)).payload == 1
    peer.close()


def test_misuse_raises_locally_and_close_is_idempotent(pair):
    mgr, _, drone, _ = pair
    with pytest.raises(LocalProtocolError):
        drone.send_unicast_message(Action.ANY, None, 0)
    with pytest.raises(LocalProtocolError):
        drone.send_unicast_message(Action.WP_ON, "not an item", 0)
    with pytest.raises(McpException):
        drone.send_unicast_message(Action.WP_OFF, None, BROADCAST_ID)
    drone.close()
    drone.close()
    assert drone.recv_message(timeout=1) is None
    with pytest.raises(McpException):
        drone.send_broadcast_message(Action.WP_OFF, None)


def test_port_in_use_is_a_one_line_mcp_exception():
    blocker = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    blocker.bind((LOOP, 0))  # no SO_REUSEADDR: nobody may share it
    try:
        with pytest.raises(McpException, match="cannot open UDP socket"):
            Mcp(Recorder(), blocker.getsockname()[1], 9, LOOP, 1, bind_host=LOOP)
    finally:
        blocker.close()

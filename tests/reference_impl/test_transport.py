"""Tests of the asyncio UDP transport (reference_impl.transport) on loopback, free ports only."""

from __future__ import annotations

import asyncio
import socket

import pytest

from mcp_conform.reference_impl import (
    DeliveryConfirmed,
    DeliveryFailed,
    Endpoint,
    Malformed,
    MessageDelivered,
    Retransmitted,
)
from mcp_conform.reference_impl.transport import create_transport, open_udp_socket
from mcp_conform.spec.codec import BROADCAST_ID, Action, Message, decode, encode

LOOP = "127.0.0.1"


def run(coro):
    return asyncio.run(asyncio.wait_for(coro, timeout=10))


async def _wait_for(events: list, cls: type, n: int = 1, within: float = 2.0) -> list:
    loop = asyncio.get_running_loop()
    end = loop.time() + within
    while loop.time() < end:
        got = [e for e in events if isinstance(e, cls)]
        if len(got) >= n:
            return got
        await asyncio.sleep(0.005)
    raise AssertionError(f"no {n} {cls.__name__} within {within}s: {events}")


def test_open_udp_socket_options_and_port_sharing():
    a = open_udp_socket("", 0, reuse=True)
    try:
        port = a.getsockname()[1]
        assert a.getsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR)
        assert a.getsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST)
        assert a.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF) >= 200_000  # enlarged (ROB-7)
        assert a.gettimeout() == 0.0  # non-blocking
        b = open_udp_socket("", port, reuse=True)  # a second node on the same port (several drones, one host)
        b.close()
    finally:
        a.close()


def test_a_port_in_use_is_refused_unless_sharing_is_asked_for():
    """A stale node left running must not silently take part of the traffic (issue 8)."""
    a = open_udp_socket("", 0)
    try:
        assert not a.getsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR)
        with pytest.raises(OSError):
            open_udp_socket("", a.getsockname()[1])
        with pytest.raises(OSError):  # asking on one side only is not enough
            open_udp_socket("", a.getsockname()[1], reuse=True)
    finally:
        a.close()
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as blocker:
        blocker.bind((LOOP, 0))
        with pytest.raises(OSError):
            open_udp_socket(LOOP, blocker.getsockname()[1])


def test_loopback_broadcast_reaches_every_node_sharing_a_port():
    """MCP-TRN-1: "At the IP level, they are local subnet IP broadcasts" (127.255.255.255)."""
    a = open_udp_socket("", 0, reuse=True)
    port = a.getsockname()[1]
    b = open_udp_socket("", port, reuse=True)
    tx = open_udp_socket(LOOP, 0)
    try:
        tx.sendto(b"hello", ("127.255.255.255", port))
        for s in (a, b):
            s.settimeout(2.0)
            assert s.recv(100) == b"hello"
    finally:
        for s in (a, b, tx):
            s.close()


def test_two_transports_exchange_unicast_both_ways_with_acks():
    async def main():
        ev0: list = []
        ev1: list = []
        p0 = await create_transport(Endpoint(0, timeout=0.1, retries=20), bind_host=LOOP,
                                    remote_host=LOOP, remote_port=9, on_event=ev0.append)
        port0 = p0.transport.get_extra_info("sockname")[1]
        p1 = await create_transport(Endpoint(1, timeout=0.1, retries=20), bind_host=LOOP,
                                    remote_host=LOOP, remote_port=port0, on_event=ev1.append)
        p0.remote = (LOOP, p1.transport.get_extra_info("sockname")[1])
        h0 = p0.send(Action.START_MISSION, None, 1)
        h1 = p1.send(Action.MISSION_READY, None, 0)
        (c0,) = await _wait_for(ev0, DeliveryConfirmed)
        (c1,) = await _wait_for(ev1, DeliveryConfirmed)
        assert (c0.handle, c1.handle) == (h0, h1)
        assert [e.msg.action for e in ev1 if isinstance(e, MessageDelivered)] == [Action.START_MISSION]
        assert [e.msg.action for e in ev0 if isinstance(e, MessageDelivered)] == [Action.MISSION_READY]
        assert p0.endpoint.get_timer() is None and p1.endpoint.get_timer() is None
        p0.close()
        p1.close()

    run(main())


def test_timer_retransmits_then_fails_with_loop_clock():
    """MCP-RTX-1/SEQ-2 through call_at: retries=2 gives 3 identical copies, then DeliveryFailed."""
    async def main():
        sink = open_udp_socket(LOOP, 0)
        events: list = []
        p = await create_transport(Endpoint(1, timeout=0.03, retries=2), bind_host=LOOP,
                                   remote_host=LOOP, remote_port=sink.getsockname()[1],
                                   on_event=events.append)
        p.send(Action.MISSION_READY, None, 0)
        (fail,) = await _wait_for(events, DeliveryFailed)
        assert fail.copies == 3
        assert len([e for e in events if isinstance(e, Retransmitted)]) == 2
        copies = []
        while True:
            try:
                copies.append(sink.recv(100))
            except BlockingIOError:
                break
        assert len(copies) == 3 and len(set(copies)) == 1
        p.close()
        sink.close()

    run(main())


def test_callback_exception_does_not_kill_the_transport_and_garbage_is_survived():
    """MCP-ROB-5: after malformed input and a failing callback the node still ACKs."""
    async def main():
        calls: list = []

        def bad_callback(ev):
            calls.append(ev)
            raise RuntimeError("application bug")

        peer = open_udp_socket(LOOP, 0)
        p = await create_transport(Endpoint(2), bind_host=LOOP, remote_host=LOOP,
                                   remote_port=peer.getsockname()[1], on_event=bad_callback)
        node = (LOOP, p.transport.get_extra_info("sockname")[1])
        peer.sendto(b"\x00" * 5, node)
        peer.sendto(encode(Message(2, 0, 10, Action.WP_OFF, None)), node)
        loop = asyncio.get_running_loop()
        ack = await asyncio.wait_for(loop.sock_recv(peer, 100), 2)
        assert decode(ack).payload == 10
        assert any(isinstance(e, Malformed) for e in calls)
        p.close()
        peer.close()

    run(main())


def test_reply_to_source_and_default_remote():
    """ACKs go to the remote by default, to the datagram's source with reply_to_source."""
    async def main():
        remote = open_udp_socket(LOOP, 0)
        src = open_udp_socket(LOOP, 0)
        loop = asyncio.get_running_loop()
        for to_source, expect in ((False, remote), (True, src)):
            p = await create_transport(Endpoint(3), bind_host=LOOP, remote_host=LOOP,
                                       remote_port=remote.getsockname()[1], reply_to_source=to_source)
            node = (LOOP, p.transport.get_extra_info("sockname")[1])
            src.sendto(encode(Message(3, 0, 77, Action.START_MISSION, None)), node)
            ack = decode(await asyncio.wait_for(loop.sock_recv(expect, 100), 2))
            assert (ack.dst, ack.src, ack.payload) == (0, 3, 77)
            p.close()
        remote.close()
        src.close()

    run(main())


def test_broadcast_goes_to_the_broadcast_address_once():
    async def main():
        rx = open_udp_socket("", 0)
        port = rx.getsockname()[1]
        p = await create_transport(Endpoint(0), bind_host=LOOP, remote_port=port)  # default remote
        assert p.remote == ("127.255.255.255", port)
        p.send(Action.WP_OFF, None, BROADCAST_ID)
        loop = asyncio.get_running_loop()
        msg = decode(await asyncio.wait_for(loop.sock_recv(rx, 100), 2))
        assert msg.dst == BROADCAST_ID and p.endpoint.get_timer() is None
        p.close()
        rx.close()

    run(main())

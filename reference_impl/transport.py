"""The asyncio UDP transport that drives a sans-I/O :class:`~reference_impl.endpoint.Endpoint`.

The clock is the event loop's (``loop.time()``); the endpoint's retransmit deadline is one
``loop.call_at`` timer. A datagram is handled and its ACK written inside
``datagram_received`` itself, before any event callback runs, so the ACK leaves at once
(MCP-ACK-7: "The ACK leaves within 100 ms of the message's arrival") whatever the
application does with the message.

Where datagrams go: our own messages to ``remote`` (by default the broadcast address and
the peer's port, as the description's nodes do: "At the IP level, they are local subnet IP
broadcasts", MCP-TRN-1); ACKs to ``remote`` too, unless ``reply_to_source`` is set, in which
case an ACK goes back to the source address of the datagram it acknowledges. Datagrams
are accepted from any source address (MCP-TRN-2).

Several nodes can share one host and one port when asked to (``reuse=True``, the CLI's
``--reuse-port``): :func:`open_udp_socket` then sets SO_REUSEADDR (and SO_REUSEPORT where
the system has it). It always sets SO_BROADCAST and binds the wildcard by default so that
loopback broadcasts to 127.255.255.255 reach every node on the port. Unasked, a port in use
is an error: a stale node left running must not silently take part of the traffic.

An exception raised by an event callback is logged and swallowed: it never stops the
transport (MCP-ROB-5: "After any malformed or unexpected input the node stays live").
"""

from __future__ import annotations

import asyncio
import logging
import socket
from collections.abc import Callable
from typing import Any

from mcp_conform.reference_impl.endpoint import Endpoint
from mcp_conform.reference_impl.events import Event
from mcp_conform.spec import SPEC

__all__ = [
    "DEFAULT_RCVBUF",
    "DatagramTap",
    "McpDatagramProtocol",
    "create_transport",
    "open_udp_socket",
]

log = logging.getLogger(__name__)

#: Receive buffer asked for (MCP-ROB-7: a flood of 10 000 datagrams must not bury the ACKs).
DEFAULT_RCVBUF = 4 * 1024 * 1024

Addr = tuple[str, int]
EventCallback = Callable[[Event], Any]
#: ``tap(direction, data, addr)``: every datagram received ("rx", from addr) and sent ("tx", to addr)
DatagramTap = Callable[[str, bytes, Addr], Any]


def open_udp_socket(bind_host: str, bind_port: int, *, broadcast: bool = True, reuse: bool = False,
                    rcvbuf: int = DEFAULT_RCVBUF) -> socket.socket:
    """A non-blocking IPv4 UDP socket bound to ``(bind_host, bind_port)``.

    ``bind_host`` "" (or "0.0.0.0") is the wildcard, which also receives loopback
    broadcasts; ``bind_port`` 0 picks a free port. With ``reuse``, SO_REUSEADDR and (where
    available) SO_REUSEPORT let several nodes share the port; with ``broadcast``,
    SO_BROADCAST allows sending to 127.255.255.255. Raises ``OSError`` (e.g. port in use).
    """
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        if reuse:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            if hasattr(socket, "SO_REUSEPORT"):
                try:
                    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEPORT, 1)
                except OSError:  # pragma: no cover - some kernels refuse it
                    pass
        if broadcast:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        if rcvbuf:
            try:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, rcvbuf)
            except OSError:  # pragma: no cover - capped by the system; not fatal
                pass
        sock.bind((bind_host, bind_port))
        sock.setblocking(False)
    except BaseException:
        sock.close()
        raise
    return sock


class McpDatagramProtocol(asyncio.DatagramProtocol):
    """Drives one :class:`Endpoint` from a datagram socket and the loop clock.

    ``remote``: where our messages go (and ACKs, unless ``reply_to_source``).
    ``on_event``: called in the loop thread for every endpoint event, in order; its
    exceptions are logged, never propagated. ``tap``: called with every datagram received
    and sent (a capture; it must be quick: ``traceio.background.BackgroundRecorder.datagram``). Use :meth:`send` only from the loop thread
    (other threads: ``loop.call_soon_threadsafe``).
    """

    def __init__(self, endpoint: Endpoint, remote: Addr, *, reply_to_source: bool = False,
                 on_event: EventCallback | None = None, tap: DatagramTap | None = None,
                 impairment: Any = None) -> None:
        self.endpoint = endpoint
        self.tap = tap
        #: ``--impair``: a ``harness.impair.Impairment`` deciding what this node's own socket
        #: edge does to each datagram it sends (``tx``) and receives (``rx``): a node on a bad
        #: link; a corrupted ``rx`` copy is discarded, as the UDP checksum would discard it
        self.impairment = impairment
        self.remote = remote
        self.reply_to_source = reply_to_source
        self.on_event = on_event
        self.transport: asyncio.DatagramTransport | None = None
        self.closed: asyncio.Future[None] | None = None
        self._loop: asyncio.AbstractEventLoop | None = None
        self._timer: asyncio.TimerHandle | None = None
        self._timer_when: float | None = None

    # ------------------------------------------------------------------ asyncio callbacks
    def connection_made(self, transport: asyncio.BaseTransport) -> None:
        self.transport = transport  # type: ignore[assignment]
        self._loop = asyncio.get_running_loop()
        self.closed = self._loop.create_future()

    def connection_lost(self, exc: Exception | None) -> None:
        self._cancel_timer()
        self.transport = None
        if self.closed is not None and not self.closed.done():
            self.closed.set_result(None)

    def datagram_received(self, data: bytes, addr: Addr) -> None:
        """Hot path: decode, ACK at once, then hand the events over."""
        imp = self.impairment
        if imp is None:
            self._received(data, addr)
            return
        loop = self._loop
        assert loop is not None
        for d in imp.decide("rx", data, loop.time()).deliveries:
            if "corrupt" in d.kinds or "cut" in d.kinds:
                continue
            if d.delay_s <= 0:
                self._received(d.data, addr)
            else:
                loop.call_later(d.delay_s, self._received, d.data, addr)

    def _received(self, data: bytes, addr: Addr) -> None:
        if self.transport is None:
            return
        ep = self.endpoint
        now = self._loop.time()  # type: ignore[union-attr]
        if self.tap is not None:
            self.tap("rx", data, addr)
        ep.receive_datagram(data, addr, now)
        self._flush()
        self._after(now)

    def error_received(self, exc: Exception) -> None:
        # e.g. ICMP port unreachable for a unicast remote with nobody listening: harmless,
        # the retransmit timer covers it (MCP-RTX-1).
        log.debug("socket error ignored: %s", exc)

    # ------------------------------------------------------------------ sending
    def send(self, action: int, payload: Any, dst: int, *, timeout: float | None = None,
             retries: int | None = None) -> int:
        """Hand a message to the endpoint (loop thread only); returns its handle."""
        now = self._loop.time() if self._loop is not None else 0.0
        handle = self.endpoint.send(action, payload, dst, now=now, timeout=timeout, retries=retries)
        self._flush()
        self._after(now)
        return handle

    def _flush(self) -> None:
        out = self.endpoint.datagrams_to_send()
        if not out:
            return
        tr = self.transport
        if tr is None:
            return
        remote, to_source, tap = self.remote, self.reply_to_source, self.tap
        for data, addr in out:
            dest = addr if (to_source and addr is not None) else remote
            if self.impairment is not None:
                self._impaired_send(data, dest)
                continue
            try:
                tr.sendto(data, dest)
            except (OSError, ValueError, RuntimeError) as exc:  # closing, unreachable, ...
                log.warning("sendto failed: %s", exc)
                continue
            if tap is not None:
                tap("tx", data, dest)

    def _impaired_send(self, data: bytes, dest: Addr) -> None:
        """One datagram through the impairment: its copies now or later, none if dropped
        (the tap sees what the node sent, once, as it does on a clean link)."""
        loop = self._loop
        assert loop is not None and self.impairment is not None
        if self.tap is not None:
            self.tap("tx", data, dest)

        def out(body: bytes) -> None:
            tr = self.transport
            if tr is None:
                return
            try:
                tr.sendto(body, dest)
            except (OSError, ValueError, RuntimeError) as exc:
                log.warning("sendto failed: %s", exc)

        for d in self.impairment.decide("tx", data, loop.time()).deliveries:
            if d.delay_s <= 0:
                out(d.data)
            else:
                loop.call_later(d.delay_s, out, d.data)

    def _after(self, now: float) -> None:
        """Dispatch pending events and re-arm the retransmit timer."""
        ep = self.endpoint
        cb = self.on_event
        while (ev := ep.next_event()) is not None:
            if cb is not None:
                try:
                    cb(ev)
                except Exception:  # noqa: BLE001 - MCP-ROB-5: never kill the transport
                    log.exception("event callback failed on %r", ev)
        self._arm_timer(ep.get_timer())

    # ------------------------------------------------------------------ retransmit timer
    def _arm_timer(self, when: float | None) -> None:
        if when == self._timer_when:
            return
        self._cancel_timer()
        if when is not None and self._loop is not None and self.transport is not None:
            self._timer_when = when
            self._timer = self._loop.call_at(when, self._on_timer, when)

    def _cancel_timer(self) -> None:
        if self._timer is not None:
            self._timer.cancel()
        self._timer = None
        self._timer_when = None

    def _on_timer(self, when: float) -> None:
        self._timer = None
        self._timer_when = None
        # The loop runs a call_at callback up to its clock resolution early; it is due.
        now = max(self._loop.time(), when)  # type: ignore[union-attr]
        self.endpoint.handle_timer(now)
        self._flush()
        self._after(now)

    def close(self) -> None:
        """Close the socket and stop the timer."""
        self._cancel_timer()
        if self.transport is not None:
            self.transport.close()


async def create_transport(endpoint: Endpoint, *, bind_host: str = "", bind_port: int = 0,
                           remote_host: str | None = None, remote_port: int = SPEC.protocol["ports"]["manager"],
                           reply_to_source: bool = False, on_event: EventCallback | None = None,
                           sock: socket.socket | None = None, tap: DatagramTap | None = None,
                           reuse_port: bool = False, impairment: Any = None,
                           ) -> McpDatagramProtocol:
    """Open (or adopt ``sock``) and start a transport for ``endpoint`` in the running loop.

    ``remote_host`` defaults to the spec's broadcast address; ``reuse_port`` lets other
    nodes share the bound port (several drones on one host). Returns the protocol; its
    ``transport.get_extra_info("sockname")`` is the bound address.
    """
    loop = asyncio.get_running_loop()
    if sock is None:
        sock = open_udp_socket(bind_host, bind_port, reuse=reuse_port)
    remote = (remote_host if remote_host is not None else SPEC.protocol["broadcast_address"], remote_port)
    proto = McpDatagramProtocol(endpoint, remote, reply_to_source=reply_to_source, on_event=on_event,
                                tap=tap, impairment=impairment)
    await loop.create_datagram_endpoint(lambda: proto, sock=sock)
    return proto

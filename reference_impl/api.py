"""The blocking MCP API with the description's shape: ``Mcp`` and ``McpException``.

::

    mcp = Mcp(handler, local_port, remote_port, broadcast_address, source_id)
    mcp.send_unicast_message(Action.MISSION_READY, None, 0)   # blocks until ACKed
    msg = mcp.recv_message(Action.START_MISSION)              # blocks until one arrives

Threads. ``Mcp`` runs the asyncio transport (:mod:`reference_impl.transport`) in a
background *network thread*, which receives, ACKs and retransmits whether or not the
application is inside ``recv_message``: the ACK leaves from ``datagram_received`` itself
(MCP-ACK-1, and MCP-ACK-7: "The ACK leaves within 100 ms of the message's arrival").
Each delivered message is then passed to a *handler thread*, which calls the handler's
``handle_*_message`` method (:func:`reference_impl.handler.dispatch`) in delivery order and
afterwards queues the message for ``recv_message``. So a slow handler (one that arms and
climbs) never delays an ACK, a handler may itself call ``send_unicast_message``, and a
message returned by ``recv_message`` has already been handled. Handler exceptions are
logged and do not stop the node.

``recv_message(action)`` follows the description: "If a particular action code is specified
and a message with some other action code is received, then the received message is
ignored and the call blocks till the expected message is received" — messages of other
types taken off the queue meanwhile are dropped (their handlers have run). ACKs are never
delivered (MCP-ACK-6: "If an ACK is received, ignore and continue listening").

``timeout`` arguments: ``None`` blocks (the description's "If timeout is not specified, the
call blocks"); a number waits at most that many seconds. ``send_unicast_message``'s
``timeout`` and ``retries`` are the retransmission timeout and retry limit of that message
(MCP-RTX-1), defaulting to the object's (5 s and 1000 from the spec).
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import logging
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

from mcp_conform.reference_impl.endpoint import Endpoint
from mcp_conform.reference_impl.events import (
    DeliveryConfirmed,
    DeliveryFailed,
    Event,
    MessageDelivered,
)
from mcp_conform.reference_impl.handler import dispatch
from mcp_conform.reference_impl.transport import DatagramTap, McpDatagramProtocol, create_transport
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import BROADCAST_ID, Action, Message

__all__ = ["Mcp", "McpException"]

log = logging.getLogger(__name__)

_PORTS = SPEC.protocol["ports"]
_STOP = object()


class McpException(Exception):
    """An MCP operation failed: a unicast ran out of retries (MCP-RTX-1), the socket could
    not be opened, or the ``Mcp`` object is closed."""


class Mcp:
    """One MCP node on UDP: the description's ``Mcp`` class (see the module docstring).

    ``local_port`` is where we listen (0 picks a free one, see :attr:`local_port`),
    ``remote_port`` and ``broadcast_address`` (or ``remote_host``) where we send; by
    default on the wildcard address, so loopback broadcasts reach us too. ``source_id``
    is our MCP ID. ``timeout``/``retries`` default to the spec's parameters. With
    ``reply_to_source`` an ACK goes back to the datagram's source address instead of the
    remote. With ``reuse_port`` other nodes may bind the same port (several drones on one
    host); without it a port in use is an error. ``on_event`` is called in the network thread for every endpoint event (for
    logging); it must not block. ``max_queued`` bounds the messages waiting for
    ``recv_message`` (the oldest are dropped beyond it). ``tap(direction, data, addr)`` sees
    every datagram received and sent, in the network thread (a capture; it must be quick).
    """

    def __init__(self, handler: Any, local_port: int = _PORTS["drone"],
                 remote_port: int = _PORTS["manager"],
                 broadcast_address: str = SPEC.protocol["broadcast_address"],
                 source_id: int = 1, *, bind_host: str = "", remote_host: str | None = None,
                 timeout: float | None = None, retries: int | None = None,
                 reply_to_source: bool = False, broadcast_id: int = BROADCAST_ID,
                 initial_seq: int | None = None, on_event: Callable[[Event], Any] | None = None,
                 max_queued: int = 10000, tap: DatagramTap | None = None,
                 reuse_port: bool = False, impairment: Any = None) -> None:
        self.handler = handler
        self.source_id = source_id
        self.on_event = on_event
        self._endpoint = Endpoint(
            source_id,
            timeout=SPEC.params["timeout_s"] if timeout is None else timeout,
            retries=int(SPEC.params["retries"]) if retries is None else retries,
            broadcast_id=broadcast_id, initial_seq=initial_seq)
        self._pending: dict[int, concurrent.futures.Future[DeliveryConfirmed]] = {}
        self._inbox: deque[Message] = deque(maxlen=max_queued)
        self._inbox_cond = threading.Condition()
        self._handler_queue: queue.SimpleQueue[Any] = queue.SimpleQueue()
        self._closed = False
        #: messages dropped because nobody called recv_message and the queue was full
        self.dropped = 0
        self._close_lock = threading.Lock()
        self._proto: McpDatagramProtocol | None = None
        self._loop = asyncio.new_event_loop()
        started: concurrent.futures.Future[McpDatagramProtocol] = concurrent.futures.Future()
        remote = remote_host if remote_host is not None else broadcast_address
        self._net_thread = threading.Thread(
            target=self._run_loop, name=f"mcp-net-{source_id}", daemon=True,
            args=(started, bind_host, local_port, remote, remote_port, reply_to_source, tap, reuse_port,
                  impairment))
        self._net_thread.start()
        try:
            self._proto = started.result()
        except Exception as exc:
            self._net_thread.join()
            self._loop.close()
            self._closed = True
            where = f"{bind_host or '0.0.0.0'}:{local_port}"
            raise McpException(f"cannot open UDP socket on {where}: {exc}") from exc
        self._handler_thread = threading.Thread(
            target=self._run_handlers, name=f"mcp-handler-{source_id}", daemon=True)
        self._handler_thread.start()

    # ------------------------------------------------------------------ properties
    @property
    def local_address(self) -> tuple[str, int]:
        """The bound ``(host, port)``."""
        assert self._proto is not None and self._proto.transport is not None
        return self._proto.transport.get_extra_info("sockname")[:2]

    @property
    def local_port(self) -> int:
        """The bound port (useful after ``local_port=0``)."""
        return self.local_address[1]

    @property
    def remote_address(self) -> tuple[str, int]:
        """Where our messages (and, unless ``reply_to_source``, our ACKs) go."""
        assert self._proto is not None
        return self._proto.remote

    @remote_address.setter
    def remote_address(self, addr: tuple[str, int]) -> None:
        host, port = addr
        assert self._proto is not None
        self._proto.remote = (str(host), int(port))  # one atomic attribute store

    @property
    def closed(self) -> bool:
        return self._closed

    # ------------------------------------------------------------------ sending
    def send_unicast_message(self, action: int, payload: Any, dst: int, timeout: float | None = None,
                             retries: int | None = None) -> None:
        """Send to ``dst`` and block until it ACKs (MCP-BLK-1).

        Raises :class:`McpException` when the retry limit runs out without the matching
        ACK (MCP-RTX-1, MCP-RTX-2) or the object is closed; ``LocalProtocolError`` on a
        message the spec does not allow.
        """
        fut = self._call(self._start_unicast, action, payload, dst, timeout, retries)
        fut.result()

    def send_broadcast_message(self, action: int, payload: Any) -> None:
        """Send to the broadcast ID, once, unacknowledged (MCP-ACK-4, MCP-RTX-4)."""
        fut: concurrent.futures.Future[Any] = self._call(self._start_broadcast, action, payload)
        fut.result()

    def _call(self, fn: Callable[..., Any], *args: Any) -> concurrent.futures.Future[Any]:
        """Run ``fn(fut, *args)`` in the network thread; it settles ``fut``."""
        if self._closed:
            raise McpException("the Mcp object is closed")
        if threading.current_thread() is self._net_thread:
            raise McpException("blocking Mcp calls cannot be made from the network thread (on_event)")
        fut: concurrent.futures.Future[Any] = concurrent.futures.Future()

        def run() -> None:
            if not fut.set_running_or_notify_cancel():
                return
            try:
                fn(fut, *args)
            except BaseException as exc:  # noqa: BLE001 - handed to the caller's thread
                fut.set_exception(exc)

        try:
            self._loop.call_soon_threadsafe(run)
        except RuntimeError:  # the loop is closed
            raise McpException("the Mcp object is closed") from None
        return fut

    def _start_unicast(self, fut: concurrent.futures.Future[Any], action: int, payload: Any, dst: int,
                       timeout: float | None, retries: int | None) -> None:
        if self._proto is None or self._proto.transport is None:
            raise McpException("the Mcp object is closed")
        if dst == self._endpoint.broadcast_id:
            raise McpException(f"dst {dst} is the broadcast ID: use send_broadcast_message")
        handle = self._proto.send(action, payload, dst, timeout=timeout, retries=retries)
        self._pending[handle] = fut

    def _start_broadcast(self, fut: concurrent.futures.Future[Any], action: int, payload: Any) -> None:
        if self._proto is None or self._proto.transport is None:
            raise McpException("the Mcp object is closed")
        self._proto.send(action, payload, self._endpoint.broadcast_id)
        fut.set_result(None)

    # ------------------------------------------------------------------ receiving
    def recv_message(self, action: int = Action.ANY, timeout: float | None = None) -> Message | None:
        """The next delivered message of type ``action`` (any with ``Action.ANY``), or None.

        Messages of other types taken meanwhile are dropped (the description's "the
        received message is ignored"); their handlers have already run. ``timeout`` None
        blocks; otherwise None is returned after ``timeout`` seconds, or at once when the
        object is closed.
        """
        want = int(action)
        any_action = want == int(Action.ANY)
        deadline = None if timeout is None else time.monotonic() + max(0.0, timeout)
        with self._inbox_cond:
            while True:
                while self._inbox:
                    msg = self._inbox.popleft()
                    if any_action or msg.action == want:
                        return msg
                if self._closed:
                    return None
                if deadline is None:
                    self._inbox_cond.wait()
                else:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0:
                        return None
                    self._inbox_cond.wait(remaining)

    # ------------------------------------------------------------------ threads
    def _run_loop(self, started: concurrent.futures.Future[McpDatagramProtocol], bind_host: str,
                  bind_port: int, remote_host: str, remote_port: int, reply_to_source: bool,
                  tap: DatagramTap | None, reuse_port: bool = False, impairment: Any = None) -> None:
        loop = self._loop
        asyncio.set_event_loop(loop)
        try:
            proto = loop.run_until_complete(create_transport(
                self._endpoint, bind_host=bind_host, bind_port=bind_port, remote_host=remote_host,
                remote_port=remote_port, reply_to_source=reply_to_source, on_event=self._on_event,
                tap=tap, reuse_port=reuse_port, impairment=impairment))
        except BaseException as exc:  # noqa: BLE001 - reported to the constructor
            started.set_exception(exc)
            return
        started.set_result(proto)
        try:
            loop.run_forever()
        finally:
            proto.close()
            loop.run_until_complete(asyncio.sleep(0))  # let connection_lost run
            loop.close()

    def _on_event(self, ev: Event) -> None:
        """Network thread: settle blocked senders, hand deliveries to the handler thread."""
        if isinstance(ev, MessageDelivered):
            self._handler_queue.put(ev.msg)
        elif isinstance(ev, DeliveryConfirmed):
            fut = self._pending.pop(ev.handle, None)
            if fut is not None and not fut.done():
                fut.set_result(ev)
        elif isinstance(ev, DeliveryFailed):
            fut = self._pending.pop(ev.handle, None)
            if fut is not None and not fut.done():
                fut.set_exception(McpException(f"{ev.rule}: {ev.reason}"))
        if self.on_event is not None:
            self.on_event(ev)

    def _run_handlers(self) -> None:
        cache: dict[Any, int] = {}
        while True:
            msg = self._handler_queue.get()
            if msg is _STOP:
                return
            try:
                dispatch(self.handler, msg, cache)
            except Exception:  # noqa: BLE001 - a handler bug must not stop the node
                log.exception("handler failed on %r", msg)
            with self._inbox_cond:
                if len(self._inbox) == self._inbox.maxlen:
                    self.dropped += 1
                    if self.dropped % 1000 == 1:  # the first, then every 1000th: no log flood
                        log.warning("recv_message queue full (%d): dropped the oldest message "
                                    "(%d so far)", self._inbox.maxlen, self.dropped)
                self._inbox.append(msg)
                self._inbox_cond.notify_all()

    # ------------------------------------------------------------------ lifetime
    def close(self) -> None:
        """Stop the network and handler threads and close the socket; idempotent.

        Blocked ``send_unicast_message`` calls raise :class:`McpException`; blocked
        ``recv_message`` calls return None.
        """
        with self._close_lock:
            if self._closed:
                return
            self._closed = True
        err = McpException("the Mcp object was closed before the ACK arrived")

        def shutdown() -> None:
            for fut in self._pending.values():
                if not fut.done():
                    fut.set_exception(err)
            self._pending.clear()
            self._loop.stop()

        try:
            self._loop.call_soon_threadsafe(shutdown)
        except RuntimeError:  # pragma: no cover - loop already closed
            pass
        if threading.current_thread() is not self._net_thread:
            self._net_thread.join(timeout=5.0)
        self._handler_queue.put(_STOP)
        if threading.current_thread() is not self._handler_thread:
            self._handler_thread.join(timeout=1.0)  # a handler may still be busy; it is a daemon
        with self._inbox_cond:
            self._inbox_cond.notify_all()

    def __enter__(self) -> Mcp:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __del__(self) -> None:
        try:
            if not self._closed:
                self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown
            pass

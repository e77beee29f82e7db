"""The reference Nsqd backend: a sans-I/O core and its TCP server edge.

:class:`BackendCore` is the protocol: bytes and ``now`` in, events and bytes out, and the
time of its next UPDATE. Everything it does comes from ``spec/nsqd.yaml``: the deframer
(NSQD-FRM-1..5), the bodies (NSQD-MSG-7, D-3, D-7), each message's effect on the flight
state (NSQD-MSG-3: the ``effect`` column is the transition table), unknown ids
(NSQD-MSG-4/5/6, D-2) and the UPDATE period (NSQD-MSG-1, D-8). A peer's input the table does
not allow is survived and reported as an event naming the rule; only our own misuse raises.

:class:`BackendServer` is the edge: one TCP client at a time (NSQD-CON-2, D-4: a second one
waits in the listen backlog), a new deframer per connection (NSQD-ROB-3), the core's timer
driving UPDATE with ``selectors``.
"""

from __future__ import annotations

import logging
import selectors
import socket
import time
from dataclasses import dataclass

from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd import StreamSpec
from mcp_conform.spec.nsqd_codec import (
    BodyError,
    Deframer,
    Frame,
    FramingError,
    decode_body,
    encode,
)

__all__ = ["BackendCore", "BackendServer", "Handled", "Rejected"]

log = logging.getLogger("mcp.nsqd.backend")


@dataclass(frozen=True)
class Handled:
    """A command applied: its name and the flight state after it."""

    name: str
    state: int


@dataclass(frozen=True)
class Rejected:
    """Input the backend did not act on, with the rule that says so and why."""

    rule: str
    reason: str
    closes: bool = False


class BackendCore:
    """One backend's protocol state: the flight state (kept across connections) and the
    current connection's deframer."""

    def __init__(self, spec: StreamSpec = NSQD, *, update_period: float | None = None) -> None:
        self.spec = spec
        self.period = float(update_period if update_period is not None else spec.params["update_period_s"])
        self.state = spec.states["GROUNDED"]
        self._deframer: Deframer | None = None
        self._next_update: float | None = None

    # -- connection life --------------------------------------------------------------
    @property
    def connected(self) -> bool:
        return self._deframer is not None

    def connect(self, now: float) -> None:
        """A client was accepted: a new stream (NSQD-ROB-3); the first UPDATE is due now."""
        self._deframer = Deframer(self.spec)
        self._next_update = now

    def disconnect(self) -> int:
        """The client left (FIN, RST or our close): the bytes of a cut frame are dropped; how many."""
        dropped = self._deframer.pending if self._deframer is not None else 0
        self._deframer, self._next_update = None, None
        return dropped

    def next_timer(self) -> float | None:
        return self._next_update

    # -- input and time ---------------------------------------------------------------
    def receive(self, data: bytes, now: float) -> tuple[list[Handled | Rejected], bytes, bool]:
        """Bytes from the client: the events, the bytes to send, and whether to close."""
        if self._deframer is None:
            raise RuntimeError("receive() without a connection")
        events: list[Handled | Rejected] = []
        out = b""
        for item in self._deframer.feed(data):
            if isinstance(item, FramingError):
                events.append(Rejected(item.rule, item.reason, closes=True))
                return events, out, True
            ev = self._handle(item)
            events.append(ev)
            if isinstance(ev, Rejected):
                out += self.error_frame(ev.reason)
        return events, out, False

    def poll(self, now: float) -> bytes:
        """The UPDATE frames due by ``now`` (NSQD-MSG-1): one per period, none while idle."""
        if self._next_update is None or now < self._next_update:
            return b""
        self._next_update = max(self._next_update + self.period, now)
        return self.update_frame()

    # -- frames -----------------------------------------------------------------------
    def update_frame(self) -> bytes:
        flying = self.state != self.spec.states["GROUNDED"]
        return encode(self.spec, "UPDATE", roll=0, pitch=0, yaw=0, thrust=0, lat=0, lon=0,
                      alt=10 if flying else 0, state=self.state)

    def error_frame(self, text: str) -> bytes:
        return encode(self.spec, "ERROR", text=text[:500])

    def _handle(self, fr: Frame) -> Handled | Rejected:
        if not self.spec.has_message(fr.msg_id):  # D-2: consumed, kept, state unchanged
            return Rejected("NSQD-MSG-4", f"unknown message id {fr.msg_id}")
        msg = self.spec.message(fr.msg_id)
        if msg.sent_by == "backend":
            return Rejected("NSQD-MSG-2", f"{msg.name} is sent by a backend, not to it")
        try:
            decode_body(self.spec, fr.msg_id, fr.body)
        except BodyError as exc:  # D-3: not applied
            return Rejected(exc.rule, str(exc))
        if msg.effect.to:
            self.state = msg.effect.to[0]
        return Handled(msg.name, self.state)


class BackendServer:
    """The core on a TCP port: one client at a time, UPDATE on the core's timer."""

    def __init__(self, host: str, port: int, *, core: BackendCore | None = None, backlog: int = 5) -> None:
        self.core = core or BackendCore()
        self._lsock = socket.create_server((host, port), backlog=backlog, reuse_port=False)
        self._lsock.setblocking(False)
        self.address = self._lsock.getsockname()[:2]
        self._sel = selectors.DefaultSelector()
        self._sel.register(self._lsock, selectors.EVENT_READ, "listen")
        self._client: socket.socket | None = None
        self._stopped = False

    def stop(self) -> None:
        self._stopped = True

    def close(self) -> None:
        self._drop_client()
        self._sel.close()
        self._lsock.close()

    def serve(self, *, duration: float | None = None) -> None:
        """Serve until :meth:`stop` (or ``duration`` seconds)."""
        end = None if duration is None else time.monotonic() + duration
        while not self._stopped and (end is None or time.monotonic() < end):
            now = time.monotonic()
            due = self.core.next_timer()
            timeout = 0.2 if due is None else max(0.0, min(0.2, due - now))
            for key, _ in self._sel.select(timeout):
                if key.data == "listen":
                    self._accept()
                else:
                    self._read()
            if self._client is not None:
                self._send(self.core.poll(time.monotonic()))

    def _accept(self) -> None:
        try:
            conn, peer = self._lsock.accept()
        except OSError:
            return
        conn.setblocking(False)
        self._client = conn
        self._sel.unregister(self._lsock)  # one client at a time: the next waits in the backlog
        self._sel.register(conn, selectors.EVENT_READ, "client")
        self.core.connect(time.monotonic())
        log.info("client %s:%d connected", *peer[:2])

    def _read(self) -> None:
        assert self._client is not None
        try:
            data = self._client.recv(65536)
        except BlockingIOError:
            return
        except OSError:  # RST
            data = b""
        if not data:
            self._drop_client()
            return
        events, out, close = self.core.receive(data, time.monotonic())
        for ev in events:
            log.info("%s", ev)
        self._send(out)
        if close:
            self._drop_client()

    def _send(self, data: bytes) -> None:
        if not data or self._client is None:
            return
        try:
            self._client.sendall(data)
        except (BlockingIOError, OSError):
            self._drop_client()

    def _drop_client(self) -> None:
        if self._client is None:
            return
        dropped = self.core.disconnect()
        if dropped:
            log.info("client left mid-frame: %d bytes dropped", dropped)
        self._sel.unregister(self._client)
        self._client.close()
        self._client = None
        self._sel.register(self._lsock, selectors.EVENT_READ, "listen")

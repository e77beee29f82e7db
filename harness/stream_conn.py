"""One TCP connection of the runner to a node that serves connections, whatever its stream
protocol: bytes out in any split, frames in through the protocol's framing, every write and
every frame on the capture's stream channels of the protocol (with the connection's open and
close: who closed it, FIN or RST), and waits on predicates over what came.

It is the runner's one link core (``harness.link.Link``: the end, the read of it, a node's
close, the frames kept and the waits), read in the caller's thread (``threaded=False``:
:meth:`StreamConn.pump`), never by a thread of its own: a case or the fuzzer decides when the
node's bytes are read, and an embedded node that shares the runner's process is not starved.
The protocol is a parameter, never a copy: its :class:`StreamFraming` says how bytes become
frames and what the capture records of each (Nsqd's: ``harness.nsqd_session``).
"""

from __future__ import annotations

import contextlib
import socket
import struct
from typing import Any, Protocol

from mcp_conform.harness.link import Link

__all__ = ["StreamConn", "StreamFraming"]


class StreamFraming(Protocol):
    """A stream protocol as a connection's parameter, one per connection (its deframer keeps
    what a read cut short): ``deframe(data, t)``: each item in ``data`` (arrived at ``t``; its
    bytes ``raw``) as ``(item, frame, fields)``: the frame kept (with its time ``t``; None for
    bytes that are no frame) and what the capture records of it; ``sent(data)``: what the
    capture records of a write (its ``msg_id`` and ``name`` when it is one whole frame)."""

    def deframe(self, data: bytes, t: float) -> list[tuple[Any, Any, dict[str, Any]]]: ...

    def sent(self, data: bytes) -> dict[str, Any]: ...


class StreamConn(Link):
    """One client connection of the runner to the node at ``address`` (``sock``, connected),
    its frames cut by ``framing``; ``log``: the case's record of everything sent; ``recorder``:
    the run's capture (``traceio.recorder.McapRecorder`` or a Tee), if any; ``index``: the
    connection's number in the run; ``protocol``: the protocol's profile name (its stream
    channels); ``kw``: the core's (``clock``, ``net``, ``monitor``).
    :attr:`frames`: the node's frames; :attr:`framing_error`: the last bytes that were none."""

    framing: StreamFraming  # type: ignore[assignment]

    def __init__(self, framing: StreamFraming, transport: str, address: tuple[str, int], recorder: Any = None, *,
                 sock: socket.socket, log: list[tuple[float, bytes]] | None = None, index: int = 0, protocol: str = "",
                 **kw: Any) -> None:
        self.log, self.index, self.protocol = log, index, protocol
        self.framing_error: Any = None  # the last bytes that were no frame
        self.reset = False  # the node reset it (RST)
        self.fin_at: float | None = None  # when the runner half-closed it (:meth:`shutdown`)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # each write its own segment
        try:
            self.sock_peer: Any = sock.getpeername()
        except OSError:
            self.sock_peer = None
        super().__init__(framing, transport, address, recorder, sent_as="tx", got_as="rx",  # type: ignore[arg-type]
                         sock=sock, threaded=False, **kw)
        self.opened = self.clock.monotonic()
        self._event("open", local=self.sock.getsockname())

    def _event(self, event: str, **kw: Any) -> None:
        """The connection's open and close on the capture (its protocol's ``conn`` channel: a
        pcap of it shows the handshake and who closed, how)."""
        if self.recorder is not None:
            with contextlib.suppress(OSError, AttributeError):
                self.recorder.stream_event(event, protocol=self.protocol, conn=self.index, peer=self.sock_peer, **kw)

    def _stream_record(self, direction: str, raw: bytes, fields: dict[str, Any]) -> None:
        self.recorder.stream_frame(direction, raw, protocol=self.protocol, conn=self.index, peer=self.sock_peer,
                                   **fields)

    # -- out --------------------------------------------------------------------------
    def send(self, data: bytes, *, split: int | None = None, gap: float = 0.0) -> bool:  # type: ignore[override]
        """Send ``data`` whole or in ``split``-byte writes (``gap`` s apart, TCP_NODELAY);
        False when the node had closed the connection."""
        chunks = [data] if not split else [data[i:i + split] for i in range(0, len(data), split)]
        t = self.clock.monotonic()
        self.sent.append((t, "raw", data))  # bytes, whole frames or not
        if self.log is not None:
            self.log.append((t, data))
        if self.recorder is not None:
            self._stream_record(self.sent_as, data, self.framing.sent(data))
        try:
            for i, c in enumerate(chunks):
                self.sock.setblocking(True)
                self.sock.sendall(c)
                self.sock.setblocking(False)
                if gap and i + 1 < len(chunks):
                    self.clock.sleep(gap)
                    self.pump(0)
        except OSError:
            self.sock.setblocking(False)
            self.closed_at = self.closed_at or self.clock.monotonic()
            return False
        return True

    def shutdown(self) -> None:
        """Our FIN, the connection still read (a half-close): TCP delivers in order, so the
        node handles every byte sent before it sees the stream end."""
        if self.fin_at is not None or self.sock.fileno() == -1:
            return
        self.fin_at = self.clock.monotonic()
        self._event("close", by="client", how="fin")
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_WR)

    def close(self, *, rst: bool = False) -> None:  # type: ignore[override]
        if self.sock.fileno() != -1 and (rst or self.fin_at is None):
            self._event("close", by="client", how="rst" if rst else "fin")
        if rst:
            with contextlib.suppress(OSError):
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        super().close()

    # -- in ---------------------------------------------------------------------------
    def _ended(self, how: str | None) -> None:
        """The node closed the connection: its FIN or RST on the capture."""
        self.reset = self.reset or how == "rst"
        if how is not None:
            self._event("close", by="backend", how=how)
        super()._ended(how)

    def _record_frame(self, r: Any, t_ns: int) -> None:
        if self.recorder is not None:
            self._stream_record(self.got_as, r[0].raw, r[2])

    def _keep(self, got: list[Any]) -> None:
        """The frames kept, by their time and their message's name (the record's: :meth:`received`),
        bytes that were none in :attr:`framing_error` (read in this one thread: no waits to tell)."""
        for item, frame, fields in got:
            if frame is None:
                self.framing_error = item
            else:
                self._add(frame, fields.get("name"))

    def signs(self, since: float = 0.0) -> list[Any]:
        """The frames since ``since`` that show the node serving (its session's first frame,
        ``ConnSessionBase.first_sign``): every frame, unless the protocol says which."""
        return self.received(since)

    def violation(self) -> Any:
        """The first of the protocol's sender rules the node's frames on this connection
        break, with ``rule``, ``expected``, ``actual``, ``evidence``; None: none (or no such rules)."""
        return None

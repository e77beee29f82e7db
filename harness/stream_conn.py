"""One TCP connection of the runner to a node that serves connections, whatever its stream
protocol: bytes out in any split, frames in through the protocol's deframer, every write and
every frame on the capture's stream channels of the protocol (with the connection's open and
close: who closed it, FIN or RST), and waits on predicates over what came.

The connection is read in the caller's thread (:meth:`StreamConn.pump`), never by a thread of
its own: a case or the fuzzer decides when the node's bytes are read, and an embedded node
that shares the runner's process is not starved. The protocol is a parameter, never a copy:
its :class:`StreamFraming` says how bytes become frames and what the capture records of each
(Nsqd's: ``harness.nsqd_session``).
"""

from __future__ import annotations

import contextlib
import socket
import struct
import time
from typing import Any, Protocol

__all__ = ["StreamConn", "StreamFraming"]


class StreamFraming(Protocol):
    """A stream protocol as a connection's parameter: a fresh ``deframer()`` (``feed(data)``:
    the items in it, each with ``raw``), what the capture records of a write (``sent(data)``:
    its ``msg_id`` and ``name`` when it is one whole frame) and of an item that came
    (``received(item, t)``: the frame kept, None for bytes that are no frame, and the record's
    fields)."""

    def deframer(self) -> Any: ...

    def sent(self, data: bytes) -> dict[str, Any]: ...

    def received(self, item: Any, t: float) -> tuple[Any, dict[str, Any]]: ...


class StreamConn:
    """One client connection of the runner to the node (``sock``, connected), its frames cut
    by ``framing``; ``log``: the case's record of everything sent; ``recorder``: the run's
    capture (``traceio.recorder.McapRecorder`` or a Tee), if any; ``index``: the connection's
    number in the run; ``protocol``: the protocol's profile name (its stream channels)."""

    def __init__(self, sock: socket.socket, framing: StreamFraming, *, log: list[tuple[float, bytes]] | None = None,
                 recorder: Any = None, index: int = 0, protocol: str = "") -> None:
        self.sock, self.framing, self.log, self.recorder = sock, framing, log, recorder
        self.index, self.protocol = index, protocol
        self.opened = time.monotonic()
        self.frames: list[Any] = []
        self.sent: list[tuple[float, bytes]] = []
        self.framing_error: Any = None  # the last bytes that were no frame
        self.closed_at: float | None = None  # the node closed (FIN or RST)
        self.reset = False
        self.fin_at: float | None = None  # when the runner half-closed it (:meth:`shutdown`)
        self._deframer = framing.deframer()
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)  # each write its own segment
        self.sock.setblocking(False)
        try:
            self.sock_peer: Any = self.sock.getpeername()
        except OSError:
            self.sock_peer = None
        self._event("open", local=self.sock.getsockname())

    def _event(self, event: str, **kw: Any) -> None:
        """The connection's open and close on the capture (its protocol's ``conn`` channel: a
        pcap of it shows the handshake and who closed, how)."""
        if self.recorder is not None:
            with contextlib.suppress(OSError, AttributeError):
                self.recorder.stream_event(event, protocol=self.protocol, conn=self.index, peer=self.sock_peer, **kw)

    def _record(self, direction: str, raw: bytes, **kw: Any) -> None:
        self.recorder.stream_frame(direction, raw, protocol=self.protocol, conn=self.index, peer=self.sock_peer, **kw)

    # -- out --------------------------------------------------------------------------
    def send(self, data: bytes, *, split: int | None = None, gap: float = 0.0) -> bool:
        """Send ``data`` whole or in ``split``-byte writes (``gap`` s apart, TCP_NODELAY);
        False when the node had closed the connection."""
        chunks = [data] if not split else [data[i:i + split] for i in range(0, len(data), split)]
        self.sent.append((time.monotonic(), data))
        if self.log is not None:
            self.log.append(self.sent[-1])
        if self.recorder is not None:
            self._record("tx", data, **self.framing.sent(data))
        try:
            for i, c in enumerate(chunks):
                self.sock.setblocking(True)
                self.sock.sendall(c)
                self.sock.setblocking(False)
                if gap and i + 1 < len(chunks):
                    time.sleep(gap)
                    self.pump(0)
        except OSError:
            self.sock.setblocking(False)
            self.closed_at = self.closed_at or time.monotonic()
            return False
        return True

    def shutdown(self) -> None:
        """Our FIN, the connection still read (a half-close): TCP delivers in order, so the
        node handles every byte sent before it sees the stream end."""
        if self.fin_at is not None or self.sock.fileno() == -1:
            return
        self.fin_at = time.monotonic()
        self._event("close", by="client", how="fin")
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_WR)

    def close(self, *, rst: bool = False) -> None:
        if self.sock.fileno() != -1 and (rst or self.fin_at is None):
            self._event("close", by="client", how="rst" if rst else "fin")
        if rst:
            with contextlib.suppress(OSError):
                self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        with contextlib.suppress(OSError):
            self.sock.close()

    # -- in ---------------------------------------------------------------------------
    def pump(self, timeout: float) -> None:
        """Read what arrives within ``timeout`` s, returning once something came (0: read
        what is there now)."""
        end = time.monotonic() + timeout
        while self.closed_at is None:
            left = end - time.monotonic()
            self.sock.settimeout(max(left, 0.0) if left > 0 else 0.0)
            try:
                data = self.sock.recv(65536)
            except (BlockingIOError, TimeoutError):
                data = None
            except ConnectionResetError:
                self.closed_at, self.reset = time.monotonic(), True
                self._event("close", by="backend", how="rst")
                break
            except OSError:
                self.closed_at = time.monotonic()
                break
            finally:
                self.sock.setblocking(False)
            if data is None:
                if time.monotonic() >= end:
                    break
                continue
            if not data:
                self.closed_at = time.monotonic()
                self._event("close", by="backend", how="fin")
                break
            self._take(data)
            if timeout > 0:  # something came: let the caller look at it
                break

    def watch(self, duration: float) -> None:
        """Read everything that arrives over the next ``duration`` s."""
        end = time.monotonic() + duration
        while self.closed_at is None and (left := end - time.monotonic()) > 0:
            self.pump(left)

    def _take(self, data: bytes) -> None:
        now = time.monotonic()
        for item in self._deframer.feed(data):
            got, fields = self.framing.received(item, now)
            if got is None:
                self.framing_error = item
            else:
                self.frames.append(got)
            if self.recorder is not None:
                self._record("rx", item.raw, **fields)

    def signs(self, since: float = 0.0) -> list[Any]:
        """The frames since ``since`` that show the node serving (its session's first frame,
        ``ConnSessionBase.first_sign``): every frame, unless the protocol says which."""
        return [r for r in self.frames if r.t >= since]

    def violation(self) -> Any:
        """The first of the protocol's sender rules the node's frames on this connection
        break, with ``rule``, ``expected``, ``actual``, ``evidence``; None: none (or no such rules)."""
        return None

    def wait_for(self, pred: Any, timeout: float) -> bool:
        """Pump until ``pred()`` holds or ``timeout`` s pass (or the node closes)."""
        end = time.monotonic() + timeout
        while True:
            if pred():
                return True
            left = end - time.monotonic()
            if left <= 0 or self.closed_at is not None:
                return bool(pred())
            self.pump(min(left, 0.05))

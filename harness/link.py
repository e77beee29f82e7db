"""The runner's one link core to a node under test, whatever its protocol: the end it opens (a
TCP connection, a UDP socket either way: :class:`HostLinks`, or the simulator's net), read by
a thread of its own or in the caller's thread (:meth:`Link.pump`), what comes cut into frames
by the protocol's :class:`Framing`, every frame both ways stamped on the run's clock and
recorded, under one lock, to the capture and to the run's trace monitor (one judge, live and
offline), a node's close of the TCP link seen, and waits on predicates over what came.

The protocol is a parameter, never a copy: its :class:`Framing` says how bytes become frames
and how a frame is written to the capture; a protocol's link adds only how it packs what the
runner sends (MAVLink's: ``harness.mavlink_session.Link``, pymavlink's encoder, its reader a
thread). A stream protocol's connection (``harness.stream_conn.StreamConn``: Nsqd's, read in
the caller's thread) is this core with its writes, its half-close and reset, and its stream
channels on the capture. Transports
are named as pymavlink names them: ``tcp`` connects (or takes a connection the runner
accepted), ``udpin`` binds and answers whoever sent first, ``udpout`` sends to an address.
"""

from __future__ import annotations

import contextlib
import select
import socket
import threading
from bisect import bisect_left
from typing import Any, Protocol

from mcp_conform.harness.clock import REAL, Clock

__all__ = ["HOST_LINKS", "Framing", "HostLinks", "Link", "SocketEnd"]


class Framing(Protocol):
    """A protocol as a link's parameter. ``thread``: the reader thread's name;
    ``deframe(data, t)``: the frames in ``data`` (arrived at ``t``), each with ``t``, ``raw``,
    ``name`` and ``bad`` (bytes that are no good frame, kept, never raised); ``record``: one
    frame written to the capture (``direction`` from the node's side, ``name`` None when unknown)."""

    thread: str

    def deframe(self, data: bytes, t: float) -> list[Any]: ...

    def record(self, recorder: Any, direction: str, raw: bytes, t_ns: int, name: str | None) -> None: ...


class SocketEnd:
    """The runner's end of a link on the host: a TCP connection or a UDP socket, as
    :meth:`HostLinks.open` made it (``sock``: the socket, non-blocking)."""

    def __init__(self, transport: str, address: tuple[str, int], sock: socket.socket | None) -> None:
        self.transport = transport
        if sock is None:
            if transport == "tcp":
                sock = socket.create_connection(address, timeout=2.0)
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            else:
                sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
                sock.bind(address if transport == "udpin" else ("127.0.0.1", 0))
        sock.setblocking(False)
        self.sock = sock

    def send(self, data: bytes, peer: tuple[str, int]) -> None:
        """``data`` to the peer (TCP: all of it, within 2 s); OSError when it cannot."""
        if self.transport == "tcp":
            self.sock.setblocking(True)
            self.sock.settimeout(2.0)
            try:
                self.sock.sendall(data)
            finally:
                self.sock.setblocking(False)
        else:
            self.sock.sendto(data, peer)

    def ready(self, timeout: float) -> bool:
        """Whether something can be read within ``timeout`` s (OSError, ValueError: closed)."""
        poll = select.poll()  # not select(): a descriptor above 1023 is no error
        poll.register(self.sock, select.POLLIN)
        return bool(poll.poll(timeout * 1000.0))

    def read(self) -> tuple[bytes, Any]:
        """What came and from where (TCP: b"" at the connection's end); BlockingIOError:
        nothing after all."""
        if self.transport == "tcp":
            return self.sock.recv(65536), None
        data, addr = self.sock.recvfrom(65536)
        return data, addr

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.close()


class HostLinks:
    """Where a :class:`Link` opens its end: the host's sockets (the default; the simulator's
    nets are ``mcp_conform.sim``'s). ``open(transport, address, sock)`` returns an end with
    ``send(data, peer)``, ``ready(timeout)``, ``read()``, ``close()`` and ``sock`` (what
    ``getsockname()`` reads); OSError when it cannot be opened."""

    def open(self, transport: str, address: tuple[str, int], sock: socket.socket | None = None) -> Any:
        return SocketEnd(transport, address, sock)


#: The host's sockets, every link's default.
HOST_LINKS = HostLinks()


class Link:
    """The runner's link to the node under test over ``transport`` at ``address``, its frames
    cut by ``framing``: ``sent_as``/``got_as`` are the capture's directions of what the runner
    sends and gets, from the node's side; ``sock``: a TCP connection the runner accepted;
    ``on_frames``: called on the reader thread with each batch of frames that came (a node the
    runner plays answers them); ``monitor``: the run's trace monitor, fed each frame both ways
    as it is recorded (``monitor.frame(t_ns, raw, direction)``), with the capture's time and in
    the capture's order. ``clock``, ``net``: the run's clock (``harness.clock``) and where the
    link's end is opened (:class:`HostLinks`: the host's by default, the simulator's virtual
    ones in ``mcp_conform.sim``, issue 38); ``threaded``: read by a thread of its own (False:
    in the caller's, by :meth:`pump` and the waits)."""

    def __init__(self, framing: Framing, transport: str, address: tuple[str, int], recorder: Any = None, *,
                 sent_as: str = "rx", got_as: str = "tx", sock: socket.socket | None = None, on_frames: Any = None,
                 monitor: Any = None, clock: Clock = REAL, net: Any = HOST_LINKS, threaded: bool = True) -> None:
        self.framing = framing
        self.transport, self.address, self.recorder, self.monitor = transport, address, recorder, monitor
        self.sent_as, self.got_as, self.on_frames = sent_as, got_as, on_frames
        self.clock = clock
        self.frames: list[Any] = []
        #: :attr:`frames` indexed for :meth:`received` (its cases ask thousands of times a run,
        #: each for the few frames since a moment): their times (in arrival order, so sorted) and,
        #: per message name, the frames of that name and their times
        self._times: list[float] = []
        self._by_name: dict[str | None, tuple[list[float], list[Any]]] = {}
        self.sent: list[tuple[float, str, bytes]] = []
        self.closed_at: float | None = None
        self._cond = clock.condition()
        self._send_lock = threading.Lock()
        #: held while a frame is stamped and recorded: the capture and the monitor get frames in
        #: the order of their times
        self._record_lock = threading.Lock()
        self._stop = clock.event()
        self.peer: tuple[str, int] | None = None if transport == "udpin" else address
        self._end = net.open(transport, address, sock)
        self.sock = self._end.sock
        self._reader = clock.start_thread(self._read, framing.thread) if threaded else None

    # -- out ------------------------------------------------------------------------------
    def pack(self, msg: Any) -> tuple[bytes, str]:
        """``msg`` as the bytes of its frame and its name (the protocol's link packs)."""
        raise NotImplementedError(f"{type(self).__name__} packs no message")

    def send(self, msg: Any) -> float:
        """Pack ``msg`` (:meth:`pack`) and send it; its send time."""
        with self._send_lock:
            return self._send_locked(*self.pack(msg))

    def send_raw(self, data: bytes, name: str = "raw") -> float:
        """Send ``data`` as it is (``name``: what the capture calls it; "raw": nothing); its
        send time."""
        with self._send_lock:
            return self._send_locked(data, name)

    def _send_locked(self, data: bytes, name: str) -> float:
        """Stamped before it is sent and recorded under the record lock (:meth:`_record`): the
        answer, stamped once it came, is always after its request, in the capture as in the
        live monitor, however long the sending thread waits for the GIL."""
        with self._record_lock:
            t, t_ns = self.clock.monotonic(), self.clock.time_ns()
            if self.peer is None:
                return t  # udpin: nobody to send to until the node has sent
            try:
                self._end.send(data, self.peer)
            except OSError:
                self.closed_at = self.closed_at or self.clock.monotonic()
                return t
            self.sent.append((t, name, data))
            self._record(self.sent_as, data, t_ns, name if name != "raw" else None)
        return t

    def _record(self, direction: str, raw: bytes, t_ns: int, name: str | None) -> None:
        """One frame to the capture and the run's monitor, with the same time (the caller holds
        the record lock: both see the frames in the order of their times)."""
        if self.recorder is not None:
            with contextlib.suppress(Exception):
                self.framing.record(self.recorder, direction, raw, t_ns, name)
        if self.monitor is not None:
            self.monitor.frame(t_ns, raw, direction)

    # -- in -------------------------------------------------------------------------------
    def _read(self) -> None:
        """The reader thread: the link read until it closes or :meth:`close`."""
        while not self._stop.is_set() and self._read_once(0.05) is not False:
            pass

    def _read_once(self, timeout: float) -> bool | None:
        """One read of the link's end, in whichever thread reads it: what came within
        ``timeout`` s taken (True); nothing (None: not yet, or not the node's); the link can no
        longer be read (False: the node closed the TCP link, :meth:`_ended`, or the end is closed)."""
        try:
            if not self._end.ready(timeout):
                return None
        except (OSError, ValueError):
            return False
        try:
            data, addr = self._end.read()
        except (BlockingIOError, InterruptedError):
            return None
        except OSError as exc:
            if self.transport != "tcp":
                return None
            self._ended("rst" if isinstance(exc, ConnectionResetError) else None)
            return False
        if self.transport == "tcp":
            if not data:
                self._ended("fin")
                return False
        elif self.transport == "udpin" and self.peer is None:
            self.peer = addr  # the node's socket: where replies go
        elif addr != self.peer:
            return None  # another sender: not the node under test
        self._take(data)
        return True

    def _ended(self, how: str | None) -> None:
        """The node closed the TCP link (``how``: "fin", "rst"; None: it failed): the waits end."""
        self.closed_at = self.closed_at or self.clock.monotonic()
        with self._cond:
            self._cond.notify_all()

    def _take(self, data: bytes) -> None:
        with self._record_lock:  # stamped after any frame sent before (:meth:`_send_locked`)
            now, t_ns = self.clock.monotonic(), self.clock.time_ns()
            got = self.framing.deframe(data, now)
            for r in got:
                self._record_frame(r, t_ns)
        self._keep(got)
        if self.on_frames is not None and got:
            self.on_frames(got)

    def _record_frame(self, r: Any, t_ns: int) -> None:
        """A frame that came, to the capture and the monitor (the record lock held)."""
        self._record(self.got_as, r.raw, t_ns, None if r.bad else r.name)

    def _keep(self, got: list[Any]) -> None:
        """The frames that came, kept for :meth:`received`; the waits told."""
        with self._cond:
            for r in got:
                self._add(r, r.name)
            self._cond.notify_all()

    def _add(self, r: Any, name: str | None) -> None:
        """Frame ``r`` (message ``name``) kept, indexed by its time and its name."""
        self.frames.append(r)
        self._times.append(r.t)
        times, frames = self._by_name.setdefault(name, ([], []))
        times.append(r.t)
        frames.append(r)

    def received(self, since: float = 0.0, name: str | None = None) -> list[Any]:
        """The frames that came at or after ``since`` (of message ``name``, when given)."""
        with self._cond:
            times, frames = (self._times, self.frames) if name is None else self._by_name.get(name, ([], []))
            return frames[bisect_left(times, since):]

    def pump(self, timeout: float) -> None:
        """A link read in the caller's thread (``threaded=False``): read what arrives within
        ``timeout`` s, returning once something came (0: read all that is there now)."""
        end = self.clock.monotonic() + timeout
        while self.closed_at is None:
            got = self._read_once(max(0.0, end - self.clock.monotonic()))
            if got is False:
                self.closed_at = self.closed_at or self.clock.monotonic()  # its end closed: nothing more
                break
            if got is None:
                if self.clock.monotonic() >= end:
                    break
                continue
            if timeout > 0:  # something came: let the caller look at it
                break

    def wait_for(self, pred: Any, timeout: float) -> bool:
        """Wait until ``pred()`` holds or ``timeout`` s pass (or a TCP link closes); a link read
        in the caller's thread is pumped meanwhile."""
        end = self.clock.monotonic() + timeout
        if self._reader is None:
            while not pred():
                left = end - self.clock.monotonic()
                if left <= 0 or self.closed_at is not None:
                    return bool(pred())
                self.pump(min(left, 0.05))
            return True
        with self._cond:
            while not pred():
                left = end - self.clock.monotonic()
                if left <= 0 or self.closed_at is not None:
                    return bool(pred())
                self._cond.wait(min(left, 0.05))
            return True

    def watch(self, duration: float) -> None:
        """Let ``duration`` s pass (or the TCP link close), what arrives read meanwhile."""
        self.wait_for(lambda: False, duration)

    def close(self) -> None:
        self._stop.set()
        if self._reader is not None:
            self._reader.join(timeout=1.0)
        self._end.close()

"""``SimVehicle``: the vehicle model served over TCP and UDP the way ArduPilot SITL serves it.

TCP: the vehicle listens; a node connects with ``mavutil.mavlink_connection("tcp:HOST:PORT")``.
Either side may speak first: the vehicle sends a heartbeat and a telemetry snapshot as soon
as a client connects, then streams telemetry to every connected client. Clients may come
late, go away and come back (a restarted node), and several may be connected at once; each
has its own parser and sequence numbers. Garbage bytes are counted and kept
(``unparsed()``), never fatal.

UDP (``vehicle.udp``): ``udp_out`` destinations get the telemetry from one socket, which
answers whoever writes to it; ``udp_in`` listens and serves every sender. A UDP peer counts
as connected once a frame arrived from it (``connected``, ``connections``).

Every peer is answered in MAVLink 2 unless it speaks only MAVLink 1 (then in MAVLink 1), or
``mavlink1=True`` starts every link in MAVLink 1 (ArduPilot's SERIALn_PROTOCOL 1).

A parameter list (PARAM_REQUEST_LIST) is paced as ArduPilot paces it: its STATUSTEXT banner
at once, then its PARAM_VALUEs PARAM_BATCH at a time, one batch every PARAM_PERIOD s per link
(``GCS_Param.cpp`` ``queued_param_send``: "use at most 30% of bandwidth on parameters", and
without flow control at most 5 per update; mavlink.io's parameter page: "The drone should
allow a pause after sending each parameter"). A new list request restarts the list. Reads
and sets are answered at once.

Threads (all daemon): one accepting, one ticking telemetry, one reading per TCP client and
one per UDP socket. All access to the model goes through one re-entrant lock, so every
public method and property is thread-safe. Timestamps are the clock's ``monotonic()`` seconds:
the host's, unless ``clock`` and ``net`` (``vehicle.seam``) put the vehicle on a simulator's
clock and link.
"""

from __future__ import annotations

import contextlib
import dataclasses
import functools
import socket
import threading
from collections.abc import Callable
from typing import Any

from .codec import STALE, Decoder, Encoder, MAVLinkMessage, UnparsedBytes
from .model import VehicleConfig, VehicleModel
from .records import Event, Frame, Unparsed
from .seam import HOST_NET, REAL_CLOCK
from .udp import Address, UdpEndpoint

#: Seconds a blocked send may take before the client is considered dead.
SEND_TIMEOUT = 2.0
#: Poll interval of the accepting and reading threads on a simulator's net (``vehicle.seam``),
#: and of ``wait_for``.
POLL = 0.05
#: How long the accepting and reading threads wait on the host's sockets between looks at the
#: stop flag. ``close()`` wakes them at once (each socket is shut down before it is closed: a
#: reader's select returns), so this bounds only a wake that went missing; a poll every
#: ``POLL`` s cost an idle vehicle about 40 wakeups a second, half of its CPU between frames.
IDLE_WAIT = 1.0
#: A parameter list's pace: PARAM_VALUEs per batch (ArduPilot's 5 per update without flow
#: control) and seconds between batches.
PARAM_BATCH = 5
PARAM_PERIOD = 0.01

FrameTap = Callable[[float, str, int, bytes], None]


class _Client:
    """One link: a TCP connection or a UDP peer address; decoder, encoder, send lock."""

    def __init__(self, number: int, sock: Any, peer: Any, sysid: int,
                 compid: int, *, version: int = 2, udp: UdpEndpoint | None = None):
        self.number = number
        self.sock = sock
        self.udp = udp
        self.addr: Address | None = peer if udp is not None else None
        self.peer = f"{peer[0]}:{peer[1]}" if isinstance(peer, tuple) else str(peer)
        self.decoder = Decoder()
        self.encoder = Encoder(sysid, compid, version)
        self.send_lock = threading.Lock()
        self.alive = True
        #: A frame arrived from it (TCP clients count from the connection).
        self.heard = udp is None
        self.seen_v2 = False
        self.thread: Any = None
        #: PARAM_VALUEs of a list still to send, and when the next batch is due
        self.params: list[MAVLinkMessage] = []
        self.params_due = 0.0

    @property
    def transport(self) -> str:
        return "tcp" if self.udp is None else "udp"

    def send_raw(self, data: bytes) -> None:
        if self.udp is not None and self.addr is not None:
            self.udp.sendto(data, self.addr)
        elif self.sock is not None:
            self.sock.sendall(data)


class SimVehicle:
    """A simulated ArduCopter on TCP with a thread-safe observer API.

    ``SimVehicle(sysid=1, gps_fix_delay=0.0, climb_rate=20.0, fix_withheld=False)``: keyword
    settings are ``VehicleConfig`` fields (applied on top of ``config`` if one is given).
    ``on_event(event)`` is called for every recorded event and ``on_frame(t, direction,
    conn, raw)`` for every frame sent ("tx") or received ("rx"), and for the received bytes
    that did not parse (``unparsed()``; "rx", their ``seen`` time); both run on a vehicle
    thread with the vehicle's lock held, so they must be quick and must not wait for
    other vehicle threads (reading the vehicle's properties is fine). ``clock``, ``net``: the
    seam of ``vehicle.seam`` (default: the host's clock and sockets).
    """

    def __init__(
        self,
        config: VehicleConfig | None = None,
        *,
        on_event: Callable[[Event], None] | None = None,
        on_frame: FrameTap | None = None,
        clock: Any = None,
        net: Any = None,
        **settings: Any,
    ) -> None:
        cfg = dataclasses.replace(config or VehicleConfig(), **settings)
        self._clock = clock or REAL_CLOCK
        self._net = net or HOST_NET
        #: how long a reading or accepting thread blocks: the host's sockets are woken by close()
        self._idle = IDLE_WAIT if self._net is HOST_NET else POLL
        self._cond = self._clock.condition(threading.RLock())
        self._model = VehicleModel(cfg, now=self._clock.monotonic())
        self._model.listener = on_event
        self._on_frame = on_frame
        self._stop = self._clock.event()
        self._listener: Any = None
        self._threads: list[Any] = []
        self._clients: dict[int, _Client] = {}
        self._connections = 0
        self._numbers = 0
        self._host = "127.0.0.1"
        self._port: int | None = None
        self._udp: list[UdpEndpoint] = []
        self._udp_peers: dict[tuple[int, Address], _Client] = {}
        self._started = False
        self._version = 2
        self._frame_per_datagram = False

    # ------------------------------------------------------------------ lifecycle
    def start(self, host: str = "127.0.0.1", port: int | None = 0, *,
              udp_out: list[Address] | tuple[Address, ...] = (),
              udp_in: Address | None = None, mavlink1: bool = False,
              frame_per_datagram: bool = False) -> int | None:
        """Serve: TCP on ``host:port`` (0 picks a free port; ``None``: no TCP), UDP to each
        ``udp_out`` destination from one socket, UDP listening on ``udp_in``; return the TCP
        port. ``mavlink1`` starts every link in MAVLink 1. Over UDP the frames of one turn go
        out together in one datagram, as SITL packs them; ``frame_per_datagram`` sends each
        frame in its own datagram instead, for ground stations that read one frame per
        datagram (seed 001's programs look at the last frame of each).

        ``gps_fix_delay`` counts from here. Raises ``OSError`` if a port is taken and
        ``RuntimeError`` if already started.
        """
        if self._started:
            raise RuntimeError("vehicle already started")
        self._version = 1 if mavlink1 else 2
        self._frame_per_datagram = frame_per_datagram
        endpoints: list[UdpEndpoint] = []
        sock = None
        try:
            if port is not None:
                sock = self._net.listen(host, port)
            if udp_out:
                endpoints.append(self._net.open_out(list(udp_out)))
            if udp_in is not None:
                endpoints.append(self._net.open_in(*udp_in))
        except OSError:
            if sock is not None:
                sock.close()
            for ep in endpoints:
                ep.close()
            raise
        self._started = True
        self._listener = sock
        self._udp = endpoints
        self._host = "127.0.0.1" if host in ("", "0.0.0.0") else host
        self._port = sock.getsockname()[1] if sock is not None else None
        with self._cond:
            now = self._clock.monotonic()
            self._model.restart_fix_clock(now)
            for ep in endpoints:
                for dest in ep.destinations:
                    self._udp_peer(ep, dest)
        loops: list[tuple[Callable[[], None], str]] = [(self._tick_loop, "tick")]
        if sock is not None:
            loops.append((self._accept_loop, "accept"))
        loops += [(functools.partial(self._udp_loop, ep), f"udp-{ep.mode}") for ep in endpoints]
        for target, name in loops:
            self._threads.append(self._clock.start_thread(target, f"vehicle-{name}"))
        return self._port

    def close(self) -> None:
        """Stop serving: close every socket and join the threads (at once: a socket is shut
        down before it is closed, which wakes the thread reading it)."""
        self._stop.set()
        if self._listener is not None:
            if self._net is HOST_NET:  # wakes the accepting thread's select (accept: EINVAL)
                with contextlib.suppress(OSError):
                    self._listener.shutdown(socket.SHUT_RDWR)
            with contextlib.suppress(OSError):
                self._listener.close()
        for ep in self._udp:
            ep.close()
        deadline = self._clock.monotonic() + 1.0

        def join(threads: list[Any]) -> None:
            for thread in threads:
                if thread is not None and thread.ident != threading.get_ident():
                    thread.join(max(0.0, deadline - self._clock.monotonic()))

        # the accepting thread first: a connection it took just now is then a client with its
        # reading thread, not one whose thread starts after the clients were read (and is left)
        join(self._threads)
        with self._cond:
            clients = list(self._clients.values())
        for client in clients:
            self._drop(client)
        join([c.thread for c in clients])
        with self._cond:
            self._cond.notify_all()

    def __enter__(self) -> SimVehicle:
        if not self._started:
            self.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ addresses
    @property
    def port(self) -> int | None:
        """The bound TCP port (``None`` before ``start``)."""
        return self._port

    @property
    def url(self) -> str:
        """pymavlink connection string for a client, e.g. ``"tcp:127.0.0.1:5760"``."""
        if self._port is None:
            raise RuntimeError("vehicle not started on TCP")
        return f"tcp:{self._host}:{self._port}"

    @property
    def udp_in_url(self) -> str:
        """pymavlink connection string to reach the ``udp_in`` socket (``udpout:HOST:PORT``)."""
        for ep in self._udp:
            if ep.mode == "in":
                host = ep.sock.getsockname()[0]
                return f"udpout:{'127.0.0.1' if host == '0.0.0.0' else host}:{ep.port}"
        raise RuntimeError("vehicle not started with udp_in")

    @property
    def udp_out_port(self) -> int | None:
        """The local port the ``udp_out`` telemetry comes from (None without udp_out)."""
        return next((ep.port for ep in self._udp if ep.mode == "out"), None)

    # ------------------------------------------------------------------ control
    def withhold_fix(self, duration: float | None = None) -> None:
        """Report no GPS fix: until ``give_fix()``, or for ``duration`` seconds."""
        with self._cond:
            self._model.withhold_fix(self._clock.monotonic(), duration)
            self._cond.notify_all()

    def give_fix(self) -> None:
        """Report a 3D fix from now on."""
        with self._cond:
            self._model.give_fix(self._clock.monotonic())
            self._cond.notify_all()

    def reset_observations(self) -> None:
        """Forget recorded events, frames, probe counts and ``rtl_commanded``."""
        with self._cond:
            self._model.reset_observations()

    # ------------------------------------------------------------------ observation
    def _read(self, fn: Callable[[VehicleModel], Any]) -> Any:
        with self._cond:
            return fn(self._model)

    @property
    def has_fix(self) -> bool:
        """Whether the vehicle currently reports a 3D fix."""
        return bool(self._read(lambda m: m.has_fix(self._clock.monotonic())))

    @property
    def armed(self) -> bool:
        return bool(self._read(lambda m: m.armed))

    @property
    def mode(self) -> str:
        """The ArduCopter mode name, e.g. ``"GUIDED"``."""
        return str(self._read(lambda m: m.mode))

    @property
    def custom_mode(self) -> int:
        return int(self._read(lambda m: m.custom_mode))

    @property
    def altitude(self) -> float:
        """Metres above home (as last simulated)."""
        return float(self._read(lambda m: m.altitude))

    def pending_action(self) -> str | None:
        """What the vehicle is still carrying out of an earlier command (a take-off not at its
        altitude, an AUTO mission flying), as of its last simulation step; None when nothing
        (``VehicleModel.pending_action``)."""
        return self._read(lambda m: m.pending_action())

    @property
    def rtl_commanded(self) -> bool:
        """True once RTL was requested (RTL mode or NAV_RETURN_TO_LAUNCH), even if refused."""
        return bool(self._read(lambda m: m.rtl_commanded))

    @property
    def mission(self) -> list[dict[str, Any]]:
        """The last uploaded mission (decoded MISSION_ITEM[_INT] fields)."""
        return list(self._read(lambda m: [dict(i) for i in m.mission]))

    @property
    def connected(self) -> bool:
        """Whether a TCP client is connected now or a UDP peer has sent a frame."""
        return bool(self._read(lambda m: any(c.heard for c in self._clients.values())))

    @property
    def connections(self) -> int:
        """How many clients have connected (TCP) or been heard from (UDP) so far."""
        return int(self._read(lambda m: self._connections))

    def events(self, kind: str | None = None) -> list[Event]:
        """Recorded events in order (optionally only ``kind``)."""
        return list(self._read(lambda m: m.events(kind)))

    def frames(self, msg_type: str | None = None) -> list[Frame]:
        """Received frames in order (optionally only ``msg_type``, e.g. "COMMAND_LONG")."""
        return list(self._read(lambda m: m.frames(msg_type)))

    def unparsed(self, since: float | None = None) -> list[Unparsed]:
        """Received bytes that did not parse as a MAVLink frame, first byte at ``since`` or
        later (``vehicle.records.Unparsed``: how an altered passthrough frame arrives, MCP-PAY-8)."""
        return list(self._read(lambda m: m.unparsed(since)))

    def holding(self) -> int:
        """Bytes of incomplete frames the links hold, not yet reported as unparsed (they are,
        ``codec.STALE`` s after the last byte arrived, unless more bytes complete them)."""
        with self._cond:
            return sum(c.decoder.holding() for c in self._clients.values())

    def first_time(self, kind: str) -> float | None:
        """The clock's ``monotonic()`` of the first ``kind`` event since the last reset."""
        return self._read(lambda m: m.first_time(kind))

    def probe_count(self, token: str) -> int:
        """How many probe frames (``vehicle.make_probe(token)``) arrived."""
        return int(self._read(lambda m: m.probe_count(token)))

    def probe_tokens(self) -> dict[str, int]:
        """Every probe token seen, with its count."""
        return dict(self._read(lambda m: m.probe_tokens()))

    def wait_for(self, predicate: Callable[[], bool], timeout: float) -> bool:
        """Wait until ``predicate()`` is true (re-checked on every change and every 50 ms).

        Returns its last value; never waits longer than ``timeout`` seconds.
        """
        deadline = self._clock.monotonic() + timeout
        with self._cond:
            while True:
                if predicate():
                    return True
                remaining = deadline - self._clock.monotonic()
                if remaining <= 0 or self._stop.is_set():
                    return bool(predicate())
                self._cond.wait(min(remaining, POLL))

    def wait_past_pending(self, done: Callable[[], bool], window: float, bound: float,
                          pause: Callable[[float], object]) -> tuple[float, str | None]:
        """Until ``done()``, at most ``window`` s past the last moment :meth:`pending_action`
        showed an earlier command in progress (a node that waits for it is busy meanwhile), but
        for that never past ``bound`` (the clock's ``monotonic()``); ``pause(s)`` waits a moment.
        Returns how long it waited (s) and the first pending action seen (None: none)."""
        start = self._clock.monotonic()
        deadline, pending = start + window, None
        while not done():
            now = self._clock.monotonic()
            busy = self.pending_action()
            if busy is not None:
                pending = pending or busy
                deadline = max(deadline, min(now + window, bound))
            if now >= deadline:
                break
            pause(min(0.02, deadline - now))
        return self._clock.monotonic() - start, pending

    # ------------------------------------------------------------------ threads
    def _accept_loop(self) -> None:
        listener = self._listener
        assert listener is not None
        while not self._stop.is_set():
            try:
                got = self._net.accept(listener, self._idle)
            except (OSError, ValueError):
                if self._stop.is_set():
                    return
                self._clock.sleep(POLL)
                continue
            if got is not None:
                self._serve(*got)

    def _serve(self, sock: Any, peer: Any) -> None:
        sock.settimeout(SEND_TIMEOUT)
        with contextlib.suppress(OSError):
            sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        with self._cond:
            self._connections += 1
            self._numbers += 1
            cfg = self._model.config
            client = _Client(self._numbers, sock, peer, cfg.sysid, cfg.compid,
                             version=self._version)
            self._clients[client.number] = client
            now = self._clock.monotonic()
            self._model.record(now, "connect", conn=client.number, peer=client.peer,
                               transport="tcp")
            self._send(client, self._model.snapshot(now))
            self._cond.notify_all()
        client.thread = self._clock.start_thread(lambda: self._read_loop(client),
                                                 f"vehicle-conn{client.number}")

    def _read_loop(self, client: _Client) -> None:
        sock = client.sock
        assert sock is not None  # TCP clients only
        while client.alive and not self._stop.is_set():
            try:
                data = self._net.recv(sock, self._idle)
            except (OSError, ValueError):
                break
            if data is None:
                continue
            if not data:
                break
            self._receive(client, data)
        self._drop(client)

    def _receive(self, client: _Client, data: bytes) -> None:
        """Decode bytes from ``client``, let the model answer, send the replies."""
        msgs, bad, reason = client.decoder.feed(data, self._clock.monotonic())
        with self._cond:
            now = self._clock.monotonic()
            if bad:
                self._model.record_bad_data(now, bad, reason, client.number)
            self._keep_unparsed(client, client.decoder.take_unparsed(), now)
            for msg in msgs:
                raw = bytes(msg.get_msgbuf())
                if raw[:1] == b"\xfd":
                    client.seen_v2 = True
                    client.encoder.version = 2  # ArduPilot switches a link up to MAVLink 2
                elif not client.seen_v2:
                    client.encoder.version = 1  # a MAVLink 1 peer is answered in MAVLink 1
                if not client.heard:
                    client.heard = True
                    self._connections += 1
                    self._model.record(now, "connect", conn=client.number, peer=client.peer,
                                       transport=client.transport)
                if self._on_frame is not None:
                    self._on_frame(now, "rx", client.number, raw)
                try:
                    replies = self._model.handle(msg, now, raw=raw, conn=client.number)
                    if msg.get_type() == "PARAM_REQUEST_LIST":
                        replies = self._queue_params(client, replies, now)
                    self._send(client, replies)
                except Exception as exc:  # noqa: BLE001 - a vehicle bug must not stop the link
                    self._model.record(now, "error", conn=client.number, type=msg.get_type(),
                                       error=f"{type(exc).__name__}: {exc}")
            self._flush_outbox()
            self._cond.notify_all()

    def _queue_params(self, client: _Client, replies: list[MAVLinkMessage],
                      now: float) -> list[MAVLinkMessage]:
        """A list's replies to send now (the banner, the first batch); its other
        PARAM_VALUEs queued for the tick loop (a list in progress restarts)."""
        values = [m for m in replies if m.get_type() == "PARAM_VALUE"]
        client.params = values[PARAM_BATCH:]
        client.params_due = now + PARAM_PERIOD
        return [m for m in replies if m.get_type() != "PARAM_VALUE"] + values[:PARAM_BATCH]

    def _send_params(self, now: float) -> bool:
        """The due batch of every link's list sent; whether a list is still in progress
        (called with the lock held)."""
        pending = False
        for client in list(self._clients.values()):
            if client.params and now >= client.params_due:
                batch, client.params = client.params[:PARAM_BATCH], client.params[PARAM_BATCH:]
                client.params_due = now + PARAM_PERIOD
                self._send(client, batch)
            pending = pending or bool(client.params)
        return pending

    def _keep_unparsed(self, client: _Client, found: list[UnparsedBytes], now: float) -> None:
        """Record bytes that did not parse, and tap them as received (an unknown message id
        is tapped with the frames); called with the lock held."""
        for u in found:
            self._model.record_unparsed(now, u.t, u.raw, u.reason, client.number)
            if self._on_frame is not None and not u.frame:
                self._on_frame(now, "rx", client.number, u.raw)

    def _flush_outbox(self) -> None:
        for conn, msg in self._model.take_outbox():
            targets = list(self._clients.values()) if conn == 0 else (
                [self._clients[conn]] if conn in self._clients else [])
            for client in targets:
                self._send(client, [msg])

    def _udp_peer(self, ep: UdpEndpoint, addr: Address) -> _Client:
        """The link of ``addr`` on ``ep`` (created on first use; called with the lock held)."""
        key = (id(ep), addr)
        client = self._udp_peers.get(key)
        if client is None:
            self._numbers += 1
            cfg = self._model.config
            client = _Client(self._numbers, None, addr, cfg.sysid, cfg.compid,
                             version=self._version, udp=ep)
            self._udp_peers[key] = client
            self._clients[client.number] = client
        return client

    def _udp_loop(self, ep: UdpEndpoint) -> None:
        while not self._stop.is_set():
            got = ep.receive(self._idle)
            if got is None:
                continue
            data, addr = got
            with self._cond:
                client = self._udp_peer(ep, addr)
            self._receive(client, data)

    def _tick_loop(self) -> None:
        while not self._stop.is_set():
            with self._cond:
                now = self._clock.monotonic()
                msgs = self._model.tick(now)
                for client in list(self._clients.values()):
                    self._keep_unparsed(client, client.decoder.stale(now, STALE), now)
                    if client.heard or client.udp is None or client.udp.mode == "out":
                        self._send(client, msgs)
                self._flush_outbox()
                pacing = self._send_params(now)
                self._cond.notify_all()
                delay = self._model.next_deadline() - self._clock.monotonic()
            self._stop.wait(min(max(delay, 0.001), PARAM_PERIOD if pacing else POLL))

    def _send(self, client: _Client, msgs: list[MAVLinkMessage]) -> None:
        """Encode and send ``msgs`` to ``client`` (called with the lock held)."""
        if not msgs or not client.alive:
            return
        with client.send_lock:
            frames = [f for f in (client.encoder.encode(m) for m in msgs) if f]
            try:
                if self._frame_per_datagram and client.udp is not None:
                    for raw in frames:
                        client.send_raw(raw)
                else:
                    client.send_raw(b"".join(frames))
            except OSError:
                if client.udp is None:
                    client.alive = False
                return
        if self._on_frame is not None:
            now = self._clock.monotonic()
            for raw in frames:
                self._on_frame(now, "tx", client.number, raw)

    def _drop(self, client: _Client) -> None:
        """Close a client's socket and forget it (idempotent)."""
        client.alive = False
        if client.sock is not None:
            with contextlib.suppress(OSError):
                client.sock.shutdown(socket.SHUT_RDWR)
            with contextlib.suppress(OSError):
                client.sock.close()
        with self._cond:
            if self._clients.pop(client.number, None) is not None:
                self._model.record(self._clock.monotonic(), "disconnect", conn=client.number,
                                   peer=client.peer)
            self._cond.notify_all()

"""The runner's session with a MAVLink autopilot (``--protocol mavlink``, role ``vehicle``):
the runner is its ground station, on one link over the whole run, the way a ground station
reaches ArduPilot SITL.

The link is named as pymavlink names it (``mavutil.mavlink_connection``): ``--target
tcp:HOST:PORT`` connects (SITL's 5760; a bare ``HOST:PORT`` is TCP too), ``udp:HOST:PORT``
(``udpin``) listens there for a vehicle that sends to it (SITL's ``--out``), ``udpout:HOST:PORT``
sends to a vehicle that listens and answers each sender. ``--spawn CMD`` starts the vehicle
with ``{target_host}`` ``{target_port}`` filled in, its transport ``--mavlink tcp|udp|udpout``
(default tcp); with neither, the reference vehicle (``mcp-vehicle``) is spawned (embedded).

Frames are packed and parsed by pymavlink's dialect (``spec.MAVLINK.dialect``, ardupilotmega),
MAVLink 2 out; the runner is system 255, component MAV_COMP_ID_MISSIONPLANNER, and sends its
own HEARTBEAT every ``heartbeat_period_s`` (a ground station must, MAV-HB-2). A reader thread
keeps every frame the vehicle sent (:class:`Received`: arrival time, the message or
pymavlink's ``MAVLink_bad_data``, the raw bytes); every frame both ways goes to the capture's
``/mavlink`` channel, from the autopilot's side (``rx``: the vehicle received it from the
runner, ``tx``: the vehicle sent it). The vehicle's identity is taken from its first
HEARTBEAT (MAV-HB-1: the start fails in one line when none comes).
"""

from __future__ import annotations

import contextlib
import select
import shlex
import socket
import sys
import threading
from dataclasses import dataclass
from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.errors import SetupError, SpawnFailure
from mcp_conform.harness.procs import SPAWN_STARTUP_S
from mcp_conform.harness.session_base import SpawnedNode
from mcp_conform.harness.stream_session import StreamSessionBase
from mcp_conform.judge.mavlink_monitor import MavlinkMonitor
from mcp_conform.spec import MAVLINK
from mcp_conform.spec.mavlink import MavlinkSpec

__all__ = ["HOST_LINKS", "HostLinks", "Link", "MavlinkSession", "Received", "parse_address"]

DIALECT: Any = MAVLINK.dialect
GCS_SYSID = 255
GCS_COMPID = int(DIALECT.MAV_COMP_ID_MISSIONPLANNER)
#: the URL schemes of pymavlink a ground station reaches a vehicle by
SCHEMES = ("tcp", "udp", "udpin", "udpout")
#: how the spawned reference vehicle (``mcp-vehicle``) serves each transport
_VEHICLE_LINK = {"tcp": "--listen {target_host}:{target_port}",
                 "udpout": "--no-tcp --udp-in {target_host}:{target_port}",
                 "udpin": "--no-tcp --udp-out {target_host}:{target_port}"}


def parse_address(host: str, port: int, default: str = "tcp") -> tuple[str, tuple[str, int]]:
    """``--target``'s host as the grammar split it (``udp:127.0.0.1``, port 14550) -> the
    transport (tcp, udpin or udpout: ``udp`` is pymavlink's ``udpin``) and the address."""
    scheme, sep, bare = host.rpartition(":")
    if not sep:
        scheme, bare = default, host
    if scheme not in SCHEMES:
        raise SetupError(f"--target {host}:{port}: {scheme!r} is not one of {', '.join(SCHEMES)} "
                         "(tcp:HOST:PORT, udp:HOST:PORT, udpout:HOST:PORT)")
    return ("udpin" if scheme == "udp" else scheme), (bare or "127.0.0.1", port)


@dataclass(frozen=True)
class Received:
    """One frame the vehicle sent: when it arrived (the run clock's ``monotonic()``), pymavlink's message
    (``MAVLink_bad_data`` for bytes that are no good frame) and its raw bytes."""

    t: float
    msg: Any
    raw: bytes

    @property
    def name(self) -> str:
        return str(self.msg.get_type())

    @property
    def bad(self) -> bool:
        return self.name == "BAD_DATA"

    @property
    def version(self) -> int:
        return 2 if self.raw[:1] == bytes([DIALECT.PROTOCOL_MARKER_V2]) else 1

    def describe(self) -> str:
        if self.bad:
            return f"bad data ({self.msg.reason}): {self.raw[:32].hex(' ')}"
        fields = {k: v for k, v in self.msg.to_dict().items() if k != "mavpackettype"}
        return (f"{self.name} v{self.version} from {self.msg.get_srcSystem()}/{self.msg.get_srcComponent()} "
                f"seq {self.msg.get_seq()}: {fields}")


class _SocketEnd:
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
        readable, _, _ = select.select([self.sock], [], [], timeout)
        return bool(readable)

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
    net is ``mcp_conform.sim.vehicle_role``'s). ``open(transport, address, sock)`` returns an
    end with ``send(data, peer)``, ``ready(timeout)``, ``read()``, ``close()`` and ``sock``
    (what ``getsockname()`` reads); OSError when it cannot be opened."""

    def open(self, transport: str, address: tuple[str, int], sock: socket.socket | None = None) -> Any:
        return _SocketEnd(transport, address, sock)


#: The host's sockets, every link's default.
HOST_LINKS = HostLinks()


class Link:
    """The runner's one MAVLink link to the node under test (TCP, or UDP either way), shared by
    both roles: ``ids`` are the runner's own system and component (a ground station's by
    default); ``sent_as``/``got_as`` the capture's directions of what the runner sends and
    gets, always from the autopilot's side (the runner's ground station: ``rx``/``tx``; the
    runner's vehicle, ``--role gcs``: ``tx``/``rx``); ``sock``: a TCP connection the runner
    accepted (its vehicle listens); ``on_frames``: called on the reader thread with each
    batch of frames that came (the runner's vehicle answers them); ``monitor``: the run's
    trace monitor (``judge.mavlink_monitor``), fed each frame both ways as it is recorded,
    with the capture's time and in the capture's order (one judge, live and offline).
    ``clock``, ``net``: the run's clock (``harness.clock``) and where the link's end is opened
    (:class:`HostLinks`): the host's by default, the simulator's virtual ones in
    ``mcp_conform.sim.vehicle_role`` (issue 38)."""

    def __init__(self, transport: str, address: tuple[str, int], recorder: Any = None, *,
                 ids: tuple[int, int] = (GCS_SYSID, GCS_COMPID), sent_as: str = "rx", got_as: str = "tx",
                 sock: socket.socket | None = None, on_frames: Any = None, monitor: Any = None,
                 clock: Clock = REAL, net: Any = HOST_LINKS) -> None:
        self.transport, self.address, self.recorder, self.monitor = transport, address, recorder, monitor
        self.sent_as, self.got_as, self.on_frames = sent_as, got_as, on_frames
        self.clock = clock
        self.encoder = DIALECT.MAVLink(None, srcSystem=ids[0], srcComponent=ids[1])
        self.parser = DIALECT.MAVLink(None)
        self.parser.robust_parsing = True  # bad bytes are kept as BAD_DATA, never raised
        self.frames: list[Received] = []
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
        self._reader = clock.start_thread(self._read, "mavlink-link")

    # -- out ------------------------------------------------------------------------------
    def send(self, msg: Any) -> float:
        """Pack ``msg`` (MAVLink 2, the runner's IDs and next sequence number) and send it;
        its send time."""
        with self._send_lock:
            data = bytes(msg.pack(self.encoder))
            self.skip_seq()  # as pymavlink's MAVLink.send counts
            return self._send_locked(data, msg.get_type())

    def send_raw(self, data: bytes, name: str = "raw") -> float:
        with self._send_lock:
            return self._send_locked(data, name)

    def next_seq(self) -> int:
        """The sequence number the next frame packed takes (a raw frame built by hand uses it
        and :meth:`skip_seq` then)."""
        return int(self.encoder.seq)

    def skip_seq(self) -> None:
        self.encoder.seq = (self.encoder.seq + 1) % 256

    def _send_locked(self, data: bytes, name: str) -> float:
        """Stamped before it is sent and recorded under the record lock (:meth:`_record`): the
        answer, stamped once it came, is always after its request, in the capture as in the
        live monitor, however long the sending thread waits for the GIL."""
        with self._record_lock:
            t, t_ns = self.clock.monotonic(), self.clock.time_ns()
            if self.peer is None:
                return t  # udpin: nobody to send to until the vehicle has sent
            try:
                self._end.send(data, self.peer)
            except OSError:
                self.closed_at = self.closed_at or self.clock.monotonic()
                return t
            self.sent.append((t, name, data))
            self._record(self.sent_as, data, t_ns, name if name != "raw" else None)
        return t

    def _record(self, direction: str, raw: bytes, t_ns: int, msg_type: str | None) -> None:
        """One frame to the capture and the run's monitor, with the same time (the caller holds
        the record lock: both see the frames in the order of their times)."""
        if self.recorder is not None:
            with contextlib.suppress(Exception):
                self.recorder.mavlink(direction, raw, t_ns, msg_type=msg_type)
        if self.monitor is not None:
            self.monitor.frame(t_ns, raw, direction)

    # -- in -------------------------------------------------------------------------------
    def _read(self) -> None:
        while not self._stop.is_set():
            try:
                if not self._end.ready(0.05):
                    continue
            except (OSError, ValueError):
                return
            try:
                data, addr = self._end.read()
                if self.transport == "tcp":
                    if not data:
                        self.closed_at = self.clock.monotonic()
                        with self._cond:
                            self._cond.notify_all()
                        return
                elif self.transport == "udpin" and self.peer is None:
                    self.peer = addr  # the vehicle's socket: where replies go
                elif addr != self.peer:
                    continue  # another sender: not the vehicle under test
            except (BlockingIOError, InterruptedError):
                continue
            except OSError:
                if self.transport == "tcp":
                    self.closed_at = self.clock.monotonic()
                    return
                continue
            self._take(data)

    def _take(self, data: bytes) -> None:
        with self._record_lock:  # stamped after any frame sent before (:meth:`_send_locked`)
            now, t_ns = self.clock.monotonic(), self.clock.time_ns()
            msgs = self.parser.parse_buffer(data) or []
            got = [Received(now, m, bytes(m.get_msgbuf())) for m in msgs]
            for r in got:
                self._record(self.got_as, r.raw, t_ns, None if r.bad else r.name)
        with self._cond:
            self.frames.extend(got)
            self._cond.notify_all()
        if self.on_frames is not None and got:
            self.on_frames(got)

    def received(self, since: float = 0.0, name: str | None = None) -> list[Received]:
        with self._cond:
            return [r for r in self.frames if r.t >= since and (name is None or r.name == name)]

    def wait_for(self, pred: Any, timeout: float) -> bool:
        """Wait until ``pred()`` holds or ``timeout`` s pass (or a TCP link closes)."""
        end = self.clock.monotonic() + timeout
        with self._cond:
            while not pred():
                left = end - self.clock.monotonic()
                if left <= 0 or self.closed_at is not None:
                    return bool(pred())
                self._cond.wait(min(left, 0.05))
            return True

    def close(self) -> None:
        self._stop.set()
        self._reader.join(timeout=1.0)
        self._end.close()


def embedded_command(transport: str) -> str:
    """The reference vehicle (``mcp-vehicle``) as the embedded default, on ``transport``."""
    return f"{shlex.quote(sys.executable)} -m mcp_conform.vehicle -q {_VEHICLE_LINK[transport]}"


class MavlinkSession(StreamSessionBase):
    """The vehicle under test over the whole run, and the runner's link to it."""

    subject = "the vehicle"
    startup_note = ("startup: the runner joins the vehicle's link as a ground station (system 255) "
                    "and waits for its first HEARTBEAT", "startup: waiting for the vehicle's HEARTBEAT")

    def __init__(self, cfg: RunConfig, recorder: Any = None, spec: MavlinkSpec = MAVLINK, *,
                 clock: Clock = REAL, net: Any = HOST_LINKS) -> None:
        self.cfg, self.recorder, self.spec = cfg, recorder, spec
        #: the run's clock and where its link is opened (:class:`Link`): the host's, or the
        #: simulator's (``mcp_conform.sim.vehicle_role``)
        self.clock, self.net = clock, net
        self.params = spec.params
        self.node: SpawnedNode | None = None
        self.link: Link | None = None
        #: the run's trace monitor, fed by every link of the run, the vehicle's rules judged on
        #: a complete trace as ``mcp-capture check`` judges the run's capture; the report's
        #: monitor section (the runner finishes it once the session closed)
        self.monitor: Any = MavlinkMonitor(spec, roles=("vehicle",), complete=True)
        if cfg.target is not None:
            self.transport, self.address = parse_address(cfg.target[0], cfg.target[1])
        else:
            scheme = cfg.mavlink_transport if cfg.mavlink else "tcp"
            self.transport, self.address = ("udpin" if scheme == "udp" else scheme), ("127.0.0.1", 0)
        self._template = cfg.spawn or (embedded_command(self.transport) if cfg.target is None else None)
        #: the vehicle's system and component IDs (its first HEARTBEAT's)
        self.vehicle: tuple[int, int] = (0, 0)
        #: when the link opened, when the first HEARTBEAT came (MAV-HB-1)
        self.link_opened = 0.0
        self.first_heartbeat: float | None = None
        self._beat_stop = clock.event()
        self._beater: Any = None

    @property
    def url(self) -> str:
        return f"{self.transport}:{self.address[0]}:{self.address[1]}"

    # -- life -----------------------------------------------------------------------------
    def start(self, **_: Any) -> None:
        if self.spawned:
            self._spawn()
        else:  # attached: a TCP vehicle that is not listening yet is waited for (--startup-timeout)
            end = self.clock.monotonic() + float(self.cfg.extra.get("startup_timeout", 0.0))
            while True:
                try:
                    self._open()
                    break
                except SetupError:
                    if self.clock.monotonic() >= end:
                        raise
                    self.clock.sleep(0.2)
        how = " (spawned)" if self.cfg.spawn else (" (embedded reference vehicle)" if self.spawned else "")
        self.target_desc = self.url + how
        # the first HEARTBEAT's delay is MAV-HB-1's to judge; the wait is --startup-timeout's
        self._await_heartbeat(float(self.cfg.extra.get("startup_timeout", SPAWN_STARTUP_S)))

    def _open(self) -> None:
        try:
            self.link = Link(self.transport, self.address, self.recorder, monitor=self.monitor, clock=self.clock,
                             net=self.net)
        except OSError as exc:
            raise SetupError(f"{self.url}: cannot open the link: {exc.strerror or exc}") from None
        self.link_opened = self.clock.monotonic()
        self._beat_stop.clear()
        self._beater = self.clock.start_thread(self._beat, "mavlink-heartbeat")

    def _spawn(self) -> None:
        """The vehicle started with a free loopback port; TCP: connected once it listens;
        UDP: the runner's socket opened first (udpin) or sending to it (udpout)."""
        if self.transport != "tcp":
            self.spawn_at_free_port(socket.SOCK_DGRAM, before=self._open)
            return
        self.spawn_at_free_port()

        def connect() -> bool:
            with contextlib.suppress(SetupError):
                self._open()
                return True
            return False
        self.await_listening(connect, within=max(SPAWN_STARTUP_S, 10.0), pause=0.1)

    def _await_heartbeat(self, timeout: float) -> None:
        link = self.link
        assert link is not None
        if not link.wait_for(lambda: bool(link.received(name="HEARTBEAT")), timeout):
            if self.node is not None and not self.node.alive():
                raise SpawnFailure(f"the spawned vehicle {self.node.details()['exit']} before its first HEARTBEAT",
                                   self.node.details(20))
            raise SetupError(f"{self.url}: no HEARTBEAT from the vehicle within {timeout:g} s (MAV-HB-1)")
        hb = link.received(name="HEARTBEAT")[0]
        self.first_heartbeat = hb.t
        self.vehicle = (hb.msg.get_srcSystem(), hb.msg.get_srcComponent())

    def _beat(self) -> None:
        """The runner's HEARTBEAT as a ground station's (MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID),
        every ``heartbeat_period_s`` (quicker until the vehicle is heard, so a UDP vehicle
        learns the runner's address at once), until the link closes or the run's --timeout."""
        period = float(self.params["heartbeat_period_s"])
        end = self.clock.monotonic() + self.cfg.timeout
        link = self.link
        while link is not None and not self._beat_stop.is_set() and self.clock.monotonic() < end:
            link.send(link.encoder.heartbeat_encode(DIALECT.MAV_TYPE_GCS, DIALECT.MAV_AUTOPILOT_INVALID,
                                                    0, 0, DIALECT.MAV_STATE_ACTIVE))
            self._beat_stop.wait(period if self.first_heartbeat is not None else 0.2)

    def close(self) -> None:
        self._beat_stop.set()
        if self._beater is not None:
            self._beater.join(timeout=1.0)
        if self.link is not None:
            self.link.close()
        super().close()

    # -- case API -------------------------------------------------------------------------
    def before_case(self) -> None:
        """An attached vehicle that closed the TCP link is lost: the run's cases end (TargetLost)."""
        link = self.link
        if link is not None and link.closed_at is not None and not self.spawned and self.lost is None:
            self.lost = f"the vehicle at {self.url} closed the link"
        super().before_case()

    def case_ended(self, ctx: Any, outcome: str) -> None:
        """A spawned vehicle that died, or closed the link, is started afresh, with a new
        link, for the next case."""
        if self.node is None or (self.node.alive() and (self.link is None or self.link.closed_at is None)):
            return
        self.close()
        self.restarts += 1
        self.first_heartbeat = None
        self.start()

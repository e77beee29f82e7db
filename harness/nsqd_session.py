"""The runner's session with a stream-protocol node (``--protocol nsqd``: the node is a
backend, the runner its client), the TCP counterpart of ``harness.drone_session``.

The node is embedded (the reference backend on a free loopback port, spawned), attached
(``--target HOST:PORT``) or spawned (``--spawn CMD`` with ``{target_host}``,
``{target_port}``). What every node under test shares is ``harness.session_base``'s: the
spawned process and its placeholders, how it died, the case marks in the capture. The
session opens connections for the cases (:class:`Conn`: bytes out in any split, frames in
through the spec's deframer, timestamps kept), watches a spawned process (a death is
reported with its signal, a sanitizer's summary line and the tail of stderr, and the
backend is restarted for the next case) and says whether the backend is live (a new
connection accepted and an UPDATE received: NSQD-CON-1, NSQD-MSG-1).
"""

from __future__ import annotations

import contextlib
import os
import socket
import struct
import time
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.errors import SetupError
from mcp_conform.harness.procs import SPAWN_STARTUP_S, ManagedProcess
from mcp_conform.harness.session_base import Death, SpawnedNode, reference_command
from mcp_conform.harness.stream_session import StreamSessionBase, accepts
from mcp_conform.judge.nsqd_monitor import Received, SenderViolation, decode_frame, sender_violation
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd import StreamSpec
from mcp_conform.spec.nsqd_codec import Deframer, Frame, FramingError
from mcp_conform.spec.profiles import pick

__all__ = ["Conn", "Death", "Received", "SenderViolation", "StreamSession"]

#: The embedded reference backend's UPDATE period (the description's is 0.4 s: D-8).
EMBEDDED_UPDATE_PERIOD = 0.05


@dataclass
class Conn:
    """One client connection of the runner to the backend."""

    sock: socket.socket
    spec: StreamSpec
    opened: float = field(default_factory=time.monotonic)
    frames: list[Received] = field(default_factory=list)
    sent: list[tuple[float, bytes]] = field(default_factory=list)
    framing_error: FramingError | None = None
    closed_at: float | None = None  # the backend closed (FIN or RST)
    reset: bool = False
    log: list[tuple[float, bytes]] | None = None  # the case's record of everything sent
    recorder: Any = None  # the run's capture (traceio.recorder.McapRecorder or a Tee), if any
    index: int = 0  # the connection's number in the run
    protocol: str = ""  # the protocol's profile name: its stream channels on the capture
    fin_at: float | None = None  # when the runner half-closed it (:meth:`shutdown`)


    def __post_init__(self) -> None:
        self._deframer = Deframer(self.spec)
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

    # -- out --------------------------------------------------------------------------
    def send(self, data: bytes, *, split: int | None = None, gap: float = 0.0) -> bool:
        """Send ``data`` whole or in ``split``-byte writes (``gap`` s apart, TCP_NODELAY);
        False when the backend had closed the connection."""
        chunks = [data] if not split else [data[i:i + split] for i in range(0, len(data), split)]
        self.sent.append((time.monotonic(), data))
        if self.log is not None:
            self.log.append(self.sent[-1])
        if self.recorder is not None:
            head = Deframer(self.spec).feed(data)
            whole = len(head) == 1 and isinstance(head[0], Frame) and len(head[0].raw) == len(data)
            msg_id = head[0].msg_id if whole else None  # type: ignore[union-attr]
            name = self.spec.message(msg_id).name if msg_id is not None and self.spec.has_message(msg_id) else None
            self.recorder.stream_frame("tx", data, protocol=self.protocol, conn=self.index, peer=self.sock_peer, msg_id=msg_id, name=name)
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
        backend handles every byte sent before it sees the stream end (a one-client backend
        then closes it and serves the next client, NSQD-CON-2)."""
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
            if isinstance(item, FramingError):
                self.framing_error = item
                if self.recorder is not None:
                    self.recorder.stream_frame("rx", item.raw, protocol=self.protocol, conn=self.index, peer=self.sock_peer, problem=item.reason)
                continue
            values, problem = decode_frame(self.spec, item)
            self.frames.append(Received(now, item, values, problem))
            if self.recorder is not None:
                name = self.spec.message(item.msg_id).name if self.spec.has_message(item.msg_id) else None
                self.recorder.stream_frame("rx", item.raw, protocol=self.protocol, conn=self.index, peer=self.sock_peer,
                                           msg_id=item.msg_id, name=name, fields=values, problem=problem)

    def violation(self) -> SenderViolation | None:
        """The first rule the backend's frames on this connection break, if any (the one
        judgement: ``judge.nsqd_monitor.sender_violation``)."""
        return sender_violation(self.spec, self.frames, self.framing_error)

    def updates(self, since: float = 0.0) -> list[Received]:
        return [r for r in self.frames if r.t >= since and r.frame.msg_id == self.spec.message("UPDATE").id
                and r.values is not None]

    def errors(self, since: float = 0.0) -> list[Received]:
        return [r for r in self.frames if r.t >= since and r.frame.msg_id == self.spec.message("ERROR").id]

    def wait_for(self, pred: Any, timeout: float) -> bool:
        """Pump until ``pred()`` holds or ``timeout`` s pass (or the backend closes)."""
        end = time.monotonic() + timeout
        while True:
            if pred():
                return True
            left = end - time.monotonic()
            if left <= 0 or self.closed_at is not None:
                return bool(pred())
            self.pump(min(left, 0.05))


def embedded_command() -> str:
    """The reference backend as the embedded default, at a short UPDATE period."""
    return reference_command(*pick("nsqd", "backend"),
                             f"--listen {{target_host}}:{{target_port}} --update-period {EMBEDDED_UPDATE_PERIOD:g}")


class StreamSession(StreamSessionBase):
    """The node under test over the whole run, and the connections of its cases."""

    subject = "the backend"
    startup_note = ("startup: the runner connects to the backend and waits for its first UPDATE",
                    "startup: connecting and waiting for the first UPDATE")

    def __init__(self, cfg: RunConfig, recorder: Any = None, spec: StreamSpec = NSQD) -> None:
        self.cfg, self.recorder, self.spec = cfg, recorder, spec
        self.node: SpawnedNode | None = None
        self.driver = None  # no datagram socket: the cases' connections (:class:`Conn`)
        #: the command the backend is spawned with: --spawn, or the reference backend when
        #: nothing is attached (the embedded default); None in attach mode
        self._template: str | None = cfg.spawn or (embedded_command() if cfg.target is None else None)
        self.address: tuple[str, int] = cfg.target or ("127.0.0.1", 0)
        self.conns: list[Conn] = []
        self.sent_log: list[tuple[float, bytes]] = []  # what the current case sent, on any connection
        #: a command this backend was seen to take the effect of (found once per run by a case)
        self.proven_probe: tuple[str, int] | None = None
        self._conn_count = 0
        self._live_at: float | None = None  # when the last connection that proved it live opened

    # -- life -------------------------------------------------------------------------
    @property
    def proc(self) -> ManagedProcess | None:
        """The spawned backend's process (its output, its sanitizer report), None when attached."""
        return self.node.process if self.node is not None else None

    def start(self) -> None:
        if self.spawned:
            self._spawn()
            how = " (spawned)" if self.cfg.spawn else " (embedded reference backend)"
        else:
            how = ""
        self.target_desc = f"{self.address[0]}:{self.address[1]}{how}"
        # attached: the protocol's allowance; spawned: also the time a just-started process takes
        # on a loaded host (a CI run beside a fuzz campaign: the embedded reference backend missed
        # 3.5 s). How soon the first UPDATE follows accepting is the cases' (NSQD-MSG-1)
        allowance = float(self.spec.params["connect_timeout_s"]) + float(self.spec.params["update_gap_max_s"])
        if not self.live(max(allowance, SPAWN_STARTUP_S) if self.spawned else allowance):
            raise SetupError(f"the backend at {self.address[0]}:{self.address[1]} accepted no connection "
                             "or sent no UPDATE (NSQD-CON-1)")

    def _spawn(self) -> None:
        """The backend started on a free loopback port (``{target_host}`` ``{target_port}``
        filled in by the runner's one placeholder helper), and listening."""
        self.spawn_at_free_port()
        self.await_listening(lambda: accepts(self.address), within=10.0, pause=0.05)

    def close(self) -> None:
        for c in self.conns:
            c.close()
        self.conns.clear()
        super().close()

    # -- connections --------------------------------------------------------------------
    def connect(self, timeout: float | None = None) -> Conn | None:
        """A new connection (None: refused or not accepted within ``timeout``)."""
        timeout = timeout if timeout is not None else float(self.spec.params["connect_timeout_s"])
        try:
            sock = socket.create_connection(self.address, timeout=timeout)
        except OSError:
            return None
        self._conn_count += 1
        conn = Conn(sock, self.spec, log=self.sent_log, recorder=self.recorder, index=self._conn_count,
                    protocol=self.cfg.protocol)
        self.conns.append(conn)
        return conn

    def live(self, timeout: float) -> bool:
        """The backend accepts a new connection and sends UPDATE on it within ``timeout``."""
        conn = self.connect(min(timeout, float(self.spec.params["connect_timeout_s"])))
        if conn is None:
            return False
        try:
            # any bytes prove it live: frames the runner cannot parse are NSQD-FRM-1's to judge
            ok = conn.wait_for(lambda: bool(conn.frames) or conn.framing_error is not None, timeout)
            if ok:
                self._live_at = conn.opened
            return ok
        finally:
            conn.close()
            self.conns.remove(conn)

    def proven_alive(self) -> bool:
        """A round trip after the case's last write (NSQD-ROB-1): a connection opened after
        it was accepted and sent something (a backend serves a new client once it has read
        what the old ones sent; one that dies on a write never gets there). Nothing sent:
        nothing to prove."""
        if not self.sent_log:
            return True
        last = self.sent_log[-1][0]
        return (self._live_at is not None and self._live_at > last) or any(
            c.opened > last and (c.frames or c.framing_error is not None) for c in self.conns)

    def open_fds(self) -> int | None:
        """The spawned backend's open descriptors, from /proc (None when not observable)."""
        if self.node is None:
            return None
        try:
            return len(os.listdir(f"/proc/{self.node.proc.pid}/fd"))
        except OSError:
            return None

    def cycle_connections(self, cycles: int, within: float) -> int:
        """NSQD-CON-3's cycles: connections opened and closed with nothing sent, up to
        ``cycles`` within ``within`` s (a SYN a full listen backlog dropped is retried, not
        counted); how many were made. The conformance case and the fuzzer's leak check alike."""
        done, deadline = 0, time.monotonic() + within
        while done < cycles and time.monotonic() < deadline:
            try:
                with socket.create_connection(self.address, timeout=0.1):
                    pass
            except OSError:
                time.sleep(0.02)
                continue
            done += 1
            time.sleep(0.0005)  # yields: an embedded backend shares this process
        return done

    def settled_fds(self, quiet: float = 0.3, limit: float = 2.0) -> int | None:
        """:meth:`open_fds` once it held for ``quiet`` s (the backend has handled the closes
        before it), or at ``limit`` s."""
        last, since, end = self.open_fds(), time.monotonic(), time.monotonic() + limit
        while last is not None and time.monotonic() < end and time.monotonic() - since < quiet:
            time.sleep(0.02)
            now = self.open_fds()
            if now != last:
                last, since = now, time.monotonic()
        return last

    # -- case API (SessionBase.begin_case, end_case) --------------------------------------
    def before_case(self) -> None:
        super().before_case()  # a backend lost earlier: TargetLost
        self.sent_log.clear()

    def case_ended(self, ctx: Any, outcome: str) -> None:
        """The case's connections closed; a dead spawned backend revived, a live one that no
        longer serves after a failure (a hang) restarted: the next case gets one that serves."""
        for c in list(self.conns):
            c.close()
        self.conns.clear()
        if not self.spawned or self.revive():
            return
        if outcome in ("failed", "error") and not self.live(float(self.spec.params["update_gap_max_s"])):
            self.restart()

    def restart(self) -> None:
        """Stop the spawned backend (SIGTERM, then SIGKILL soon: a hung backend may ignore
        SIGTERM) and start it afresh."""
        if self.node is not None:
            self.respawn(grace=0.5)

"""What the sessions of the protocols the runner reaches over a connection or a link share
(Nsqd's ``harness.nsqd_session``, MAVLink's ``harness.mavlink_session`` and
``harness.mavlink_gcs_session``, on ``harness.link_session``), beside every session's
``harness.session_base``: the command their node is spawned with (``--spawn``, or the role's
embedded reference node), the node started on a free loopback port and waited for until it
listens (or dies: its exit and the tail of its output said), and its stop at the end of the run.

:class:`ConnSessionBase` is the session with a node that serves connections, whatever its
stream protocol (the runner its client): a connection of the protocol's
(``harness.stream_conn.StreamConn``, its ``link_class``) opened per case, the node live when a
new connection is accepted and sent its first frame, its descriptors watched, a dead or hung
spawned node restarted for the next case. A protocol declares its connection, its first frame
and the rule asking for it, and the parameter that bounds the gap between its frames.
"""

from __future__ import annotations

import contextlib
import os
import socket
import time
from collections.abc import Callable
from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.errors import SetupError, SpawnFailure
from mcp_conform.harness.link import HOST_LINKS
from mcp_conform.harness.procs import SPAWN_STARTUP_S, ManagedProcess
from mcp_conform.harness.session_base import SessionBase, SpawnedNode, fill_placeholders, free_port

__all__ = ["ConnSessionBase", "StreamSessionBase", "accepts"]

HOST = "127.0.0.1"


def accepts(address: tuple[str, int], timeout: float = 0.2) -> bool:
    """Whether a TCP connection to ``address`` is accepted within ``timeout`` s (closed at once)."""
    with socket.socket() as s, contextlib.suppress(OSError):
        s.settimeout(timeout)
        s.connect(address)
        return True
    return False


class StreamSessionBase(SessionBase):
    """A session whose node is reached at ``address`` over TCP (or UDP), spawned from
    ``_template`` with ``{target_host}`` ``{target_port}`` (None: attached), on the links of
    the runner's one link core (``harness.link.Link``: Nsqd's connections, :class:`ConnSessionBase`;
    MAVLink's link, ``harness.link_session``). A protocol declares its link (``link_class``),
    its node's first sign of life (``first_sign``: the frame whose arrival proves it there) and
    the rule asking for it (``first_rule``); a spawned node is reached once it listens
    (:meth:`reach`, tried every ``listen_pause`` s for ``listen_within`` s). ``monitor``: the
    run's trace monitor every link feeds (None: the protocol judges its frames otherwise);
    ``clock``, ``net``: the run's clock (``harness.clock``) and where its links are opened
    (``harness.link.HostLinks``: the host's, or the simulator's in ``mcp_conform.sim``)."""

    _template: str | None = None
    address: tuple[str, int] = (HOST, 0)
    first_sign = ""
    first_rule = ""
    listen_within, listen_pause = 10.0, 0.05
    #: the protocol's link (``harness.link.Link`` with its framing), made as
    #: ``link_class(transport, address, recorder, sock=sock, monitor=, clock=, net=, **kw)``
    link_class: Any = None

    def __init__(self, cfg: RunConfig, recorder: Any, spec: Any, *, monitor: Any = None, clock: Clock = REAL,
                 net: Any = HOST_LINKS) -> None:
        self.cfg, self.recorder, self.spec = cfg, recorder, spec
        self.node: SpawnedNode | None = None
        self.params = spec.params
        self.monitor, self.clock, self.net = monitor, clock, net

    def make_link(self, transport: str, address: tuple[str, int], sock: Any = None, **kw: Any) -> Any:
        """The protocol's link (:attr:`link_class`) to ``address``, on the run's clock and net,
        feeding its monitor; ``kw``: the link's own."""
        return self.link_class(transport, address, self.recorder, sock=sock, monitor=self.monitor, clock=self.clock,
                               net=self.net, **kw)

    def command(self, embedded: Callable[[], str]) -> str | None:
        """The command the node is spawned with: --spawn, or the role's reference node when
        nothing is attached (``embedded()``, the embedded default); None in attach mode."""
        return self.cfg.spawn or (embedded() if self.cfg.target is None else None)

    def started_as(self, reference: str = "") -> str:
        """What the report's target says after the node's address: " (spawned)" (--spawn),
        " (embedded reference NODE)" (``reference``, else the subject), nothing when attached."""
        if self.cfg.spawn:
            return " (spawned)"
        return f" (embedded reference {reference or self.subject.removeprefix('the ')})" if self.spawned else ""

    @property
    def spawn_command(self) -> str | None:
        return self._template

    def _spawn(self) -> None:
        """The node started on a free loopback port (``{target_host}`` ``{target_port}`` filled
        in by the runner's one placeholder helper), and reached once it listens."""
        self.spawn_at_free_port()
        self.await_listening(self.reach, within=self.listen_within, pause=self.listen_pause)

    def reach(self) -> bool:
        """Whether the spawned node listens: a connection to it accepted (closed at once)."""
        return accepts(self.address)

    def spawn_at_free_port(self, kind: int = socket.SOCK_STREAM,
                           before: Callable[[], None] | None = None) -> SpawnedNode:
        """The node spawned on a free loopback port of ``kind`` (its ``address``), ``before``
        called once the port is known and before the process starts (a UDP link opened first)."""
        assert self._template is not None
        port = free_port(HOST, kind)
        self.address = (HOST, port)
        argv = fill_placeholders(self._template, {"target_host": HOST, "target_port": str(port)})
        if before is not None:
            before()
        node = self.node = SpawnedNode(argv)
        return node

    def await_listening(self, connect: Callable[[], bool], within: float, pause: float) -> None:
        """Try ``connect()`` every ``pause`` s until it holds; a spawned node that ended first is
        a ``SpawnFailure`` (its exit, its output's tail), one not listening by ``within`` s a
        ``SetupError``."""
        node = self.node
        assert node is not None
        host, port = self.address
        noun = self.subject.removeprefix("the ")
        deadline = time.monotonic() + within
        while time.monotonic() < deadline:
            if not node.alive():
                raise SpawnFailure(f"the spawned {noun} {node.details()['exit']} before it listened on "
                                   f"{host}:{port}", node.details(20))
            if connect():
                return
            time.sleep(pause)
        raise SetupError(f"the spawned {noun} did not listen on {host}:{port} within {within:g} s")

    def accept_from_node(self, listener: socket.socket, wait: float, url: str) -> socket.socket:
        """The spawned node's connection to ``listener`` (the runner listens at ``url``, as a
        vehicle does), Nagle off, within ``wait`` s; a node that ended first is a
        ``SpawnFailure``, one that did not connect by then a ``SetupError``."""
        node = self.node
        assert node is not None
        listener.settimeout(0.1)
        end = time.monotonic() + wait
        while time.monotonic() < end:
            if not node.alive():
                raise SpawnFailure(f"{self.subject} {self.node_exit()} before it connected to {url}", node.details(20))
            try:
                conn, _ = listener.accept()
            except TimeoutError:
                continue
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            return conn
        raise SetupError(f"{self.subject} did not connect to {url} within {wait:g} s")

    def node_exit(self) -> str:
        """How the spawned node's process ended ("exited with status 1", "killed by SIGSEGV")."""
        return str(self.node.details()["exit"]) if self.node is not None else "ended"

    def close(self) -> None:
        """The spawned node stopped (SIGTERM, SIGKILL soon after: a hung node may ignore SIGTERM)."""
        if self.node is not None:
            self.node.stop(grace=0.5)


class ConnSessionBase(StreamSessionBase):
    """The node under test over the whole run, and the connections of its cases (see the
    module docstring). A protocol declares ``first_sign`` (its node's first frame on a new
    connection), ``first_rule`` (the rule asking for it), ``gap_param`` (the spec's parameter
    bounding the gap between its frames) and its connection (``link_class``: a
    ``harness.stream_conn.StreamConn``)."""

    gap_param = ""

    def __init__(self, cfg: RunConfig, recorder: Any, spec: Any, embedded: Callable[[], str]) -> None:
        super().__init__(cfg, recorder, spec)
        self.driver = None  # no datagram socket: the cases' connections
        self._template = self.command(embedded)
        self.address: tuple[str, int] = cfg.target or (HOST, 0)
        self.conns: list[Any] = []
        self.sent_log: list[tuple[float, bytes]] = []  # what the current case sent, on any connection
        self._conn_count = 0
        self._live_at: float | None = None  # when the last connection that proved it live opened
        self.cycles_stalled = False  # the last cycle_connections ended on a node that stopped accepting

    # -- life -------------------------------------------------------------------------
    @property
    def proc(self) -> ManagedProcess | None:
        """The spawned node's process (its output, its sanitizer report), None when attached."""
        return self.node.process if self.node is not None else None

    def start(self) -> None:
        if self.spawned:
            self._spawn()
        self.target_desc = f"{self.address[0]}:{self.address[1]}{self.started_as()}"
        # attached: the protocol's allowance; spawned: also the time a just-started process takes
        # on a loaded host (a CI run beside a fuzz campaign: the embedded reference backend missed
        # 3.5 s). How soon the first frame follows accepting is the cases' to judge
        allowance = float(self.spec.params["connect_timeout_s"]) + float(self.spec.params[self.gap_param])
        if not self.live(max(allowance, SPAWN_STARTUP_S) if self.spawned else allowance):
            raise SetupError(f"{self.subject} at {self.address[0]}:{self.address[1]} accepted no connection "
                             f"or sent no {self.first_sign} ({self.first_rule})")

    def close(self) -> None:
        for c in self.conns:
            c.close()
        self.conns.clear()
        super().close()

    # -- connections --------------------------------------------------------------------
    def connect(self, timeout: float | None = None) -> Any:
        """A new connection (None: refused or not accepted within ``timeout``)."""
        timeout = timeout if timeout is not None else float(self.spec.params["connect_timeout_s"])
        try:
            sock = socket.create_connection(self.address, timeout=timeout)
        except OSError:
            return None
        self._conn_count += 1
        conn = self.make_link("tcp", self.address, sock, log=self.sent_log, index=self._conn_count,
                              protocol=self.cfg.protocol)
        self.conns.append(conn)
        return conn

    def live(self, timeout: float) -> bool:
        """The node accepts a new connection and sends on it within ``timeout``."""
        conn = self.connect(min(timeout, float(self.spec.params["connect_timeout_s"])))
        if conn is None:
            return False
        try:
            # any bytes prove it live: frames the runner cannot parse are the framing rule's to judge
            ok = conn.wait_for(lambda: bool(conn.frames) or conn.framing_error is not None, timeout)
            if ok:
                self._live_at = conn.opened
            return ok
        finally:
            conn.close()
            self.conns.remove(conn)

    def proven_alive(self) -> bool:
        """A round trip after the case's last write: a connection opened after it was
        accepted and sent something (a node serves a new client once it has read what the
        old ones sent; one that dies on a write never gets there). Nothing sent: nothing to
        prove."""
        if not self.sent_log:
            return True
        last = self.sent_log[-1][0]
        return (self._live_at is not None and self._live_at > last) or any(
            c.opened > last and (c.frames or c.framing_error is not None) for c in self.conns)

    def open_fds(self) -> int | None:
        """The spawned node's open descriptors, from /proc (None when not observable)."""
        if self.node is None:
            return None
        try:
            return len(os.listdir(f"/proc/{self.node.proc.pid}/fd"))
        except OSError:
            return None

    def cycle_connections(self, cycles: int, within: float, stall: float | None = None) -> int:
        """Connections opened and closed with nothing sent, up to ``cycles`` within ``within``
        s (a SYN a full listen backlog dropped is retried, not counted); how many were made.
        ``stall``: stop early once no connection has been accepted for that long;
        :attr:`cycles_stalled` says whether that ended it (a node that stopped accepting),
        as against ``within`` running out while every attempt still got through (a slow host)."""
        done, now = 0, time.monotonic()
        deadline, last = now + within, now
        self.cycles_stalled = False
        while done < cycles and now < deadline:
            try:
                with socket.create_connection(self.address, timeout=0.1):
                    pass
            except OSError:
                time.sleep(0.02)
                now = time.monotonic()
                if stall is not None and now - last >= stall:
                    self.cycles_stalled = True
                    break
                continue
            done += 1
            time.sleep(0.0005)  # yields: an embedded node shares this process
            now = last = time.monotonic()
        return done

    def fds_down_to(self, bound: int, limit: float) -> int | None:
        """:meth:`open_fds` once it is at most ``bound`` (the node has handled the closes it was
        sent; a loaded host handles them late), or what it is at ``limit`` s."""
        fds, end = self.open_fds(), time.monotonic() + limit
        while fds is not None and fds > bound and time.monotonic() < end:
            time.sleep(0.05)
            fds = self.open_fds()
        return fds

    def settled_fds(self, quiet: float = 0.3, limit: float = 2.0) -> int | None:
        """:meth:`open_fds` once it held for ``quiet`` s (the node has handled the closes
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
        super().before_case()  # a node lost earlier: TargetLost
        self.sent_log.clear()

    def case_ended(self, ctx: Any, outcome: str) -> None:
        """The case's connections closed; a dead spawned node revived, a live one that no
        longer serves after a failure (a hang) restarted: the next case gets one that serves."""
        for c in list(self.conns):
            c.close()
        self.conns.clear()
        if not self.spawned or self.revive():
            return
        if outcome in ("failed", "error") and not self.live(float(self.spec.params[self.gap_param])):
            self.restart()

    def restart(self) -> None:
        """Stop the spawned node (SIGTERM, then SIGKILL soon: a hung node may ignore SIGTERM)
        and start it afresh."""
        if self.node is not None:
            self.respawn(grace=0.5)

"""The runner's sessions on one link (``harness.link.Link``), whatever the protocol, in either
of its roles: the runner is the judged node's peer over the whole run
(:class:`LinkSessionBase`: it reaches the node, attached or spawned, waits for its first sign
of life and sends its own periodic beat), or the runner plays a node in-process and starts
the judged peer afresh against it for each behaviour of that node (:class:`PlayedNodeSession`).

A protocol declares, never copies: its link (``link_class``), its node's first sign and the
rule that asks for it, the beat it sends, the model it plays and the ``--spawn`` placeholder
that carries the runner's URL. MAVLink's ``harness.mavlink_session.MavlinkSession`` (the
runner a ground station, a vehicle judged) and ``harness.mavlink_gcs_session.MavlinkGcsSession``
(the runner the vehicle, a ground station judged) are the two roles on it. The simulator
(``mcp_conform.sim``, issue 38) keeps its seams: ``clock``, ``net``, ``_spawn``, ``_open``.
"""

from __future__ import annotations

import contextlib
import socket
from collections.abc import Callable
from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.errors import SetupError, SpawnFailure
from mcp_conform.harness.link import HOST_LINKS, Link
from mcp_conform.harness.procs import SPAWN_STARTUP_S
from mcp_conform.harness.session_base import (
    Death,
    SpawnedNode,
    fill_placeholders,
    free_port,
    reference_command,
)
from mcp_conform.harness.stream_session import HOST, StreamSessionBase

__all__ = ["SCHEMES", "LinkSessionBase", "PlayedNodeSession", "parse_address"]

#: the URL schemes a link is named by (pymavlink's: ``tcp``, ``udp`` = ``udpin``, ``udpout``)
SCHEMES = ("tcp", "udp", "udpin", "udpout")
#: how often the played node's clock ticks (its telemetry, its held answers)
TICK_S = 0.02
#: how long the frames a peer sent before it ended are read for, once it has ended
DRAIN_S = 0.5


def await_sign(link: Link, seen: Callable[[], bool], ended: Callable[[], bool], timeout: float) -> bool:
    """Whether the peer's first sign came (``seen``) within ``timeout``, the wait ending early
    when it has ``ended``: what it sent before it ended is read for :data:`DRAIN_S` first."""
    link.wait_for(lambda: seen() or ended(), timeout)
    if not seen() and ended():
        link.wait_for(seen, DRAIN_S)
    return seen()


def parse_address(host: str, port: int, default: str = "tcp") -> tuple[str, tuple[str, int]]:
    """``--target``'s host as the grammar split it (``udp:127.0.0.1``, port 14550) -> the
    transport (tcp, udpin or udpout: ``udp`` is pymavlink's ``udpin``) and the address."""
    scheme, sep, bare = host.rpartition(":")
    if not sep:
        scheme, bare = default, host
    if scheme not in SCHEMES:
        raise SetupError(f"--target {host}:{port}: {scheme!r} is not one of {', '.join(SCHEMES)} "
                         "(tcp:HOST:PORT, udp:HOST:PORT, udpout:HOST:PORT)")
    return ("udpin" if scheme == "udp" else scheme), (bare or HOST, port)


class LinkSessionBase(StreamSessionBase):
    """The node under test over the whole run, and the runner's link to it. A role declares
    ``first_sign`` (the message whose first arrival proves the node there) and ``first_rule``
    (the rule that asks for it), ``beat_thread`` and :meth:`beat_message` (the runner's own
    periodic message, every ``heartbeat_period_s``) and :meth:`identified` (what the first
    sign tells of the node)."""

    beat_thread = "link-beat"
    listen_within, listen_pause = max(SPAWN_STARTUP_S, 10.0), 0.1

    def __init__(self, cfg: RunConfig, recorder: Any, spec: Any, monitor: Any, *, scheme: str,
                 embedded: Any, clock: Clock = REAL, net: Any = HOST_LINKS) -> None:
        super().__init__(cfg, recorder, spec, monitor=monitor, clock=clock, net=net)
        self.link: Link | None = None
        if cfg.target is not None:
            self.transport, self.address = parse_address(cfg.target[0], cfg.target[1])
        else:
            self.transport, self.address = ("udpin" if scheme == "udp" else scheme), (HOST, 0)
        self._template = self.command(lambda: embedded(self.transport))
        #: when the link opened, when the first sign came
        self.link_opened = 0.0
        self.first_heartbeat: float | None = None
        self._beat_stop = clock.event()
        self._beater: Any = None

    @property
    def url(self) -> str:
        return f"{self.transport}:{self.address[0]}:{self.address[1]}"

    def beat_message(self, link: Link) -> Any:
        """The runner's periodic message (a ground station's HEARTBEAT)."""
        raise NotImplementedError

    def identified(self, first: Any) -> None:
        """The node's first sign came (its frame ``first``)."""

    # -- life -----------------------------------------------------------------------------
    def start(self, **_: Any) -> None:
        if self.spawned:
            self._spawn()
        else:  # attached: a TCP node that is not listening yet is waited for (--startup-timeout)
            end = self.clock.monotonic() + float(self.cfg.extra.get("startup_timeout", 0.0))
            while True:
                try:
                    self._open()
                    break
                except SetupError:
                    if self.clock.monotonic() >= end:
                        raise
                    self.clock.sleep(0.2)
        self.target_desc = self.url + self.started_as()
        # the first sign's delay is its rule's to judge; the wait is --startup-timeout's
        self._await_first(float(self.cfg.extra.get("startup_timeout", SPAWN_STARTUP_S)))

    def _open(self) -> None:
        try:
            self.link = self.make_link(self.transport, self.address)
        except OSError as exc:
            raise SetupError(f"{self.url}: cannot open the link: {exc.strerror or exc}") from None
        self.link_opened = self.clock.monotonic()
        self._beat_stop.clear()
        self._beater = self.clock.start_thread(self._beat, self.beat_thread)

    def _spawn(self) -> None:
        """The node started with a free loopback port; TCP: connected once it listens;
        UDP: the runner's socket opened first (udpin) or sending to it (udpout)."""
        if self.transport != "tcp":
            self.spawn_at_free_port(socket.SOCK_DGRAM, before=self._open)
        else:
            super()._spawn()

    def reach(self) -> bool:
        """The link to the spawned node opened (it listens)."""
        with contextlib.suppress(SetupError):
            self._open()
            return True
        return False

    def _await_first(self, timeout: float) -> None:
        """The node's first sign within ``timeout``; a spawned node that ended with an error
        (an exit code but 0, a signal) is not waited for to the end: no sign will come (over
        UDP, where no connection is awaited, a vehicle that failed at once was waited for a
        minute). One that ended with 0 is, as a launcher that starts its node and exits."""
        link, sign = self.link, self.first_sign
        assert link is not None

        def failed() -> bool:
            return self.node is not None and not self.node.alive() and self.node.returncode != 0

        if not await_sign(link, lambda: bool(link.received(name=sign)), failed, timeout):
            if self.node is not None and not self.node.alive():
                raise SpawnFailure(f"the spawned {self.subject.removeprefix('the ')} {self.node.details()['exit']} "
                                   f"before its first {sign}", self.node.details(20))
            raise SetupError(f"{self.url}: no {sign} from {self.subject} within {timeout:g} s ({self.first_rule})")
        first = link.received(name=sign)[0]
        self.first_heartbeat = first.t
        self.identified(first)

    def _beat(self) -> None:
        """The runner's own message every ``heartbeat_period_s`` (quicker until the node is
        heard, so a UDP node learns the runner's address at once), until the link closes or
        the run's --timeout."""
        period = float(self.params["heartbeat_period_s"])
        end = self.clock.monotonic() + self.cfg.timeout
        link = self.link
        while link is not None and not self._beat_stop.is_set() and self.clock.monotonic() < end:
            link.send(self.beat_message(link))
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
        """An attached node that closed the TCP link is lost: the run's cases end (TargetLost)."""
        link = self.link
        if link is not None and link.closed_at is not None and not self.spawned and self.lost is None:
            self.lost = f"{self.subject} at {self.url} closed the link"
        super().before_case()

    def case_ended(self, ctx: Any, outcome: str) -> None:
        """A spawned node that died, or closed the link, is started afresh, with a new link,
        for the next case."""
        if self.node is None or (self.node.alive() and (self.link is None or self.link.closed_at is None)):
            return
        self.close()
        self.restarts += 1
        self.first_heartbeat = None
        self.start()


class PlayedNodeSession(StreamSessionBase):
    """The runner plays a node in-process (a model with ``lock``, ``ids``, ``answer(msg,
    now)`` and ``tick(now)``: the messages to send) on a fresh link for each run, and the judged
    peer is started afresh against it (``--spawn CMD`` with ``{placeholder}``: the URL it
    reaches the runner by; without ``--spawn``, the role's reference node, ``mcp-node``), its
    run kept while the cases ask for the same behaviour. A role declares ``placeholder``,
    ``tick_thread``, :meth:`make_model`, the behaviour of its first run (``first_behaviour``),
    what the node it plays is called (``played``) and its reference peer (``reference``)."""

    _template: str  # always a command: the peer is spawned for every run
    placeholder = ""
    tick_thread = "link-node"
    #: each run's session of the capture and the monitor: ``{segment}-N``
    segment = "run"
    first_behaviour: Any = None
    played = reference = "node"

    def __init__(self, cfg: RunConfig, recorder: Any, spec: Any, monitor: Any, *, scheme: str,
                 template: str | None = None, clock: Clock = REAL, net: Any = HOST_LINKS) -> None:
        super().__init__(cfg, recorder, spec, monitor=monitor, clock=clock, net=net)
        self.scheme = scheme
        self._template = template or cfg.spawn or reference_command(*cfg.profile(), f"{{{self.placeholder}}}")
        self.link: Link | None = None
        self.model: Any = None  # the played node
        self.behaviour: Any = None
        self.url = ""
        #: when the current run's link opened, and when the peer's first frame came
        self.run_started = 0.0
        self.first_frame: float | None = None
        self.runs = 0
        self._stop = clock.event()
        self._ticker: Any = None
        self._listener: socket.socket | None = None

    def make_model(self, behaviour: Any, now: float) -> Any:
        """The played node with ``behaviour``, its clock at ``now``."""
        raise NotImplementedError

    # -- life -----------------------------------------------------------------------------
    def start(self, **_: Any) -> None:
        """The peer's first run, against ``first_behaviour``; attach mode is refused in one line
        (the peer is started afresh for each behaviour)."""
        if self.cfg.target is not None:
            raise SetupError(f"--role {self.cfg.profile()[1].name}: attach mode is not supported: the runner starts "
                             f"{self.subject} for each behaviour of its {self.played} "
                             f"(--spawn 'CMD ... {{{self.placeholder}}}')")
        self.run(self.first_behaviour)
        self.target_desc = f"{self.url}{self.started_as(self.reference)}"

    def run(self, behaviour: Any, *, fresh: bool = False) -> float:
        """The peer's run against a played node that behaves so: the current one when it has
        this behaviour (unless ``fresh``), else the peer started afresh; when the run's link
        opened (the run clock's ``monotonic()``)."""
        if not fresh and behaviour == self.behaviour and self.link is not None:
            return self.run_started
        self._end_run()
        self.behaviour, self.model = behaviour, self.make_model(behaviour, self.clock.monotonic())
        self.first_frame = None
        self.runs += 1
        segment = f"{self.segment}-{self.runs}"  # each run a session of the capture and the monitor
        self.monitor.begin_segment(segment)  # (its parties start anew)
        if self.recorder is not None:
            with contextlib.suppress(Exception):  # a recorder without sessions records them as one
                self.recorder.begin_segment(segment)
        self._spawn()
        wait = float(self.cfg.extra.get("startup_timeout", SPAWN_STARTUP_S))
        link = self.link
        assert link is not None
        if not await_sign(link, lambda: self.first_frame is not None, lambda: not self.alive_process(), wait):
            # a peer that ended without a frame: its death, in either transport
            self.behaviour = None  # and the next case that needs this behaviour starts it afresh
            if not self.alive_process():  # (before, over UDP, its cases were skipped as "never exercised")
                raise SpawnFailure(f"{self.subject} {self.node_exit()} before it sent a frame to "
                                   f"{self.url}", self.node.details(20) if self.node else {})
            raise SetupError(f"{self.url}: no frame from {self.subject} within {wait:g} s")
        return self.run_started

    def _spawn(self) -> None:
        """A fresh link in the peer's transport, then the peer with ``{placeholder}``; TCP: its
        connection accepted (within --startup-timeout)."""
        if self.scheme == "tcp":
            lst = self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            lst.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            lst.bind((HOST, 0))
            lst.listen(1)
            self.url = f"tcp:{HOST}:{lst.getsockname()[1]}"
        elif self.scheme == "udpout":  # the peer sends first: the runner binds and answers
            self._open("udpin", (HOST, 0))
            assert self.link is not None
            self.url = f"udpout:{HOST}:{self.link.sock.getsockname()[1]}"
        else:  # udp / udpin: the peer listens, the runner sends to it
            port = free_port(HOST)
            self._open("udpout", (HOST, port))
            self.url = f"{self.scheme}:{HOST}:{port}"
        self.node = SpawnedNode(fill_placeholders(self._template, {self.placeholder: self.url}))
        if self.scheme == "tcp":
            assert self._listener is not None
            conn = self.accept_from_node(self._listener, float(self.cfg.extra.get("startup_timeout", SPAWN_STARTUP_S)),
                                         self.url)
            self._open("tcp", conn.getpeername(), conn)

    def _open(self, transport: str, address: tuple[str, int], sock: Any = None) -> None:
        assert self.model is not None
        self.link = self.make_link(transport, address, sock, ids=self.model.ids, sent_as="tx", got_as="rx",
                                   on_frames=self._answer)
        self.run_started = self.clock.monotonic()
        self._stop.clear()
        self._ticker = self.clock.start_thread(self._tick, self.tick_thread)

    def _answer(self, frames: list[Any]) -> None:
        """On the link's reader thread: the played node's answers to what the peer sent."""
        model, link = self.model, self.link
        if model is None or link is None:
            return
        for r in frames:
            if r.bad:
                continue
            if self.first_frame is None:
                self.first_frame = r.t
            with model.lock:
                replies = model.answer(r.msg, self.clock.monotonic())
            for m in replies:
                link.send(m)

    def _tick(self) -> None:
        """The played node's own messages (telemetry, its beat, held answers), until the run
        ends or --timeout."""
        model, link = self.model, self.link
        end = self.clock.monotonic() + self.cfg.timeout
        while model is not None and link is not None and not self._stop.is_set() and self.clock.monotonic() < end:
            with model.lock:
                out = model.tick(self.clock.monotonic())
            for m in out:
                link.send(m)
            self._stop.wait(TICK_S)

    def _end_run(self) -> None:
        self._stop.set()
        if self._ticker is not None:
            self._ticker.join(timeout=1.0)
        if self.node is not None:
            self.node.stop(grace=0.5)
        if self.link is not None:
            self.link.close()
        if self._listener is not None:
            with contextlib.suppress(OSError):
                self._listener.close()
        self.link = self._listener = self._ticker = None

    def close(self) -> None:
        self._end_run()

    # -- the peer's process -------------------------------------------------------------
    def alive_process(self) -> bool:
        return self.node is None or self.node.alive()

    def alive(self) -> bool:
        """A peer that did its work and exited is not lost: each case starts the run it needs."""
        return True

    def death(self, grace: float = 0.0) -> Death | None:
        """How the peer ended, when it ended badly (an exit status 0 is its work done)."""
        found = super().death(grace)
        return found if found is not None and (found.code != 0 or found.signal_name) else None

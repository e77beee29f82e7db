"""The node under fuzz over TCP, whatever its protocol (issue 39: MAVLink's vehicle,
``fuzz.mavlink_vehicle``; Nsqd's backend, ``fuzz.nsqd_backend`` and its stateful player
``fuzz.nsqd_player``): what a protocol's fuzz target does alike, so that each keeps only what is
its own (its framing, its probe, its liveness oracle's rule).

- :class:`TargetSpec`: how the target is reached, a command template spawned on a free loopback
  port (``--spawn CMD``, or the role's embedded reference node) or an address (``--target``);
- :class:`ProcessTarget`: the spawned process (none when attached), started from the template
  with ``{target_host}`` ``{target_port}`` and the protocol's own placeholders filled in and
  reached by the fuzzer's first connection (the connect itself is the readiness check: a node
  that serves one client at a time sees no other), and its end reported: how it ended (exit
  code or signal), the sanitizer's line and its output's tail (``harness.session_base.Death``),
  its evidence, its open descriptors;
- :class:`SyncLink`: one TCP connection read in the fuzzer's own thread, its frames cut by the
  protocol's ``harness.link.Framing`` on ``harness.link.SocketEnd`` (a write bounded by its 2 s),
  the traffic both ways kept for a finding's repro files, and the synchronous case runner's
  step (:meth:`SyncLink.exchange`: a case written with the protocol's probe right behind it,
  read until the probe's answer);
- :class:`LinkedTarget`: a target reached by one such link: its traffic, whether it is still
  there, its last beat, the fuzzer's own keep-alive sent once a period, and the synchronous
  case runner (a case and the probe written, read to the probe's answer, what came before it
  judged by the protocol; the protocol's liveness oracles when no answer or no beat comes);
- :class:`SpareTarget`: a worker's target (``fuzz.loop.WorkerTarget``) with spares started
  ahead (``fuzz.spares``; none when attached), restarted on one after a death (MAVLink's
  vehicle, Nsqd's backend);
- :func:`read_until`: several connections read until a predicate holds.

The protocol and the role are the parameters (a framing, a subject, the placeholders), never a
copy of this code.
"""

from __future__ import annotations

import contextlib
import os
import select
import socket
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, ClassVar

from mcp_conform.fuzz.loop import WorkerTarget
from mcp_conform.fuzz.spares import Spares
from mcp_conform.harness.errors import SetupError, SpawnFailure
from mcp_conform.harness.link import Framing, SocketEnd
from mcp_conform.harness.procs import ManagedProcess
from mcp_conform.harness.session_base import (
    Death,
    SpawnedNode,
    death_of,
    fill_placeholders,
    free_port,
)

__all__ = ["HOST", "LinkedTarget", "ProcessTarget", "SpareTarget", "SyncLink", "TargetSpec", "connect_when_listening",
           "read_until"]

HOST = "127.0.0.1"
#: how long a spawned (or attached) target is given to accept the fuzzer's connection
LISTEN_S = 10.0


@dataclass(frozen=True)
class TargetSpec:
    """How to reach a target: a spawn template (``spawn``: ``--spawn CMD`` or the embedded
    reference node's command), or an address (``target``: attached); neither: the protocol's
    session starts its reference node (Nsqd's, ``fuzz.nsqd_backend.Backend``)."""

    spawn: str | None = None
    target: tuple[str, int] | None = None

    @classmethod
    def of(cls, target: tuple[str, int] | None, spawn: str | None, embedded: Callable[[], str],
           address: Callable[[str, int], tuple[str, int]]) -> TargetSpec:
        """``--target`` read by the protocol (``address(host, port)``: where it listens;
        SetupError: an address it cannot reach), else ``--spawn``, else its reference node
        (``embedded()``: the command)."""
        if target is not None:
            return cls(None, address(*target))
        return cls(spawn or embedded(), None)

    @property
    def attached(self) -> bool:
        return self.target is not None and self.spawn is None

    def describe(self) -> str:
        return f"tcp:{self.target[0]}:{self.target[1]}" if self.target else "spawned"


def connect_when_listening(address: tuple[str, int], node: SpawnedNode | None, subject: str,
                           within: float = LISTEN_S) -> socket.socket:
    """The fuzzer's TCP connection to ``address`` (Nagle off), tried every 50 ms for up to
    ``within`` s: a spawned ``node`` that ended first is a ``SpawnFailure`` (its exit, its
    output's tail), no connection by then a ``SetupError``."""
    host, port = address
    deadline = time.monotonic() + within
    while True:
        try:
            sock = socket.create_connection(address, timeout=1.0)
            break
        except OSError as exc:
            if node is not None and not node.alive():
                raise SpawnFailure(f"the spawned {subject.removeprefix('the ')} {node.details()['exit']} before it "
                                   f"listened on {host}:{port}", node.details(20)) from None
            if time.monotonic() >= deadline:
                raise SetupError(f"tcp:{host}:{port}: cannot reach {subject}: {exc.strerror or exc}") from None
            time.sleep(0.05)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
    return sock


class ProcessTarget:
    """A fuzz target's process (``node``: None when attached) and its end. ``subject``: who is
    judged, in a report's words ("the vehicle", "the backend")."""

    subject = "the node"
    _node: SpawnedNode | None = None

    @property
    def node(self) -> SpawnedNode | None:
        """The spawned process (None: attached, or not started)."""
        return self._node

    def open(self, how: TargetSpec, placeholders: Callable[[str, int], dict[str, str]] | None = None) -> socket.socket:
        """The target spawned from ``how.spawn`` on a free loopback port (``{target_host}``
        ``{target_port}`` and the protocol's ``placeholders(host, port)`` filled in) or reached
        at ``how.target``, and the fuzzer's connection to it (:func:`connect_when_listening`;
        the process stopped when it fails). ``address``: where it listens."""
        host, port = how.target or (HOST, free_port(HOST, socket.SOCK_STREAM))
        if how.spawn is not None:
            extra = placeholders(host, port) if placeholders is not None else {}
            self._node = SpawnedNode(fill_placeholders(how.spawn, {"target_host": host, "target_port": str(port),
                                                                   **extra}))
        self.address = (host, port)
        try:
            return connect_when_listening(self.address, self._node, self.subject)
        except SetupError:
            self.stop()
            raise

    def stop(self) -> None:
        """The spawned process stopped (SIGTERM, SIGKILL after 0.5 s: a hung one may ignore SIGTERM)."""
        if self.node is not None:
            self.node.stop(grace=0.5)

    @property
    def process(self) -> ManagedProcess | None:
        """The spawned process (``harness.procs.ManagedProcess``: its output, its sanitizer
        report), None: attached."""
        node = self.node
        return node.process if node is not None else None

    def process_alive(self) -> bool:
        """The spawned process runs (attached: nothing to tell, True)."""
        proc = self.process
        return proc is None or proc.alive()

    def death(self, grace: float = 0.0) -> Death | None:
        """How the spawned process ended, if it did within ``grace`` s (a sanitizer takes a
        moment to write its report and exit; a closed connection may be the process exiting);
        None while it runs, or when none was spawned."""
        node = self.node
        if node is None:
            return None
        end = time.monotonic() + grace
        while node.alive() and time.monotonic() < end:
            time.sleep(0.005)
        return None if node.alive() else death_of(node, self.subject)

    def ending(self, grace: float = 0.0) -> tuple[str | None, tuple[str, ...]]:
        """How the spawned process ended, once it did within ``grace`` s ("the vehicle process
        killed by signal SIGSEGV"; None: it runs, or none was spawned), and its evidence (its
        command, its exit, its output's tails)."""
        node = self.node
        if node is None:
            return None, ()
        ended = self.death(grace) is not None
        return (f"{self.subject} process {node.details()['exit']}" if ended else None), tuple(node.evidence())

    def whole_report(self) -> list[str]:
        """The spawned process's sanitizer report (``harness.procs.ManagedProcess.
        sanitizer_report``) once it is whole: its SUMMARY line, which ASan writes last, or the
        process's end; up to 5 s, or 1 s without a new line (symbolising its stacks takes a
        while on a loaded machine)."""
        proc = self.process
        assert proc is not None
        report, end, quiet = proc.sanitizer_report(), time.monotonic() + 5.0, time.monotonic() + 1.0
        while time.monotonic() < min(end, quiet) and proc.alive() and not any("SUMMARY:" in x for x in report):
            time.sleep(0.01)
            now = proc.sanitizer_report()
            if len(now) > len(report):
                report, quiet = now, time.monotonic() + 1.0
        return report

    def fds(self) -> int | None:
        """The spawned process's open descriptors, from /proc (None when not observable)."""
        node = self.node
        if node is None:
            return None
        try:
            return len(os.listdir(f"/proc/{node.proc.pid}/fd"))
        except OSError:
            return None


class SyncLink:
    """One TCP connection (``sock``, connected) to the target, read in the caller's thread:
    its frames cut by ``framing`` (``harness.link.Framing``; bytes that are no good frame are
    dropped), each stamped with ``time.monotonic()`` as it came; ``traffic``: a list the
    traffic both ways goes to, ``(direction, time_ns, bytes)`` with the directions from the
    target's side (``sent_as``: what the fuzzer sent, ``got_as``: what the target did);
    ``beat``: which frames are the target's beat, the periodic frame its liveness rule bounds
    the gap between (:attr:`last_beat`, :meth:`wait_beat`)."""

    def __init__(self, sock: socket.socket, framing: Framing, *, traffic: list[Any] | None = None,
                 sent_as: str = "rx", got_as: str = "tx", beat: Callable[[Any], bool] | None = None) -> None:
        self.framing, self.traffic, self.sent_as, self.got_as, self.beat = framing, traffic, sent_as, got_as, beat
        self.last_beat = 0.0  # the target's last beat (time.monotonic)
        self.peer: tuple[str, int] = ("", 0)  # TCP: the connection's (a peer that reset it at once: unnamed)
        with contextlib.suppress(OSError):
            self.peer = sock.getpeername()
        self.end = SocketEnd("tcp", self.peer, sock)
        self.frames: list[Any] = []
        self.closed = False  # the target closed it, or a write failed

    def send(self, data: bytes) -> None:
        """``data`` written whole (within 2 s: a target that reads nothing ends the link, not the fuzzer)."""
        if self.traffic is not None:
            self.traffic.append((self.sent_as, time.time_ns(), data))
        try:
            self.end.send(data, self.peer)
        except OSError:
            self.closed = True

    def pump(self, timeout: float) -> None:
        """What the target sent within ``timeout`` s (at once when something is there)."""
        if self.closed:
            return
        try:
            if not self.end.ready(max(0.0, timeout)):
                return
            data, _ = self.end.read()
        except (BlockingIOError, InterruptedError):
            return
        except (OSError, ValueError):
            data = b""
        if not data:
            self.closed = True
            return
        for r in self.framing.deframe(data, time.monotonic()):
            if r.bad:
                continue
            if self.traffic is not None:
                self.traffic.append((self.got_as, time.time_ns(), r.raw))
            if self.beat is not None and self.beat(r):
                self.last_beat = r.t
            self.frames.append(r)

    def drain(self) -> None:
        """Everything the link holds now, read."""
        while True:
            n = len(self.frames)
            self.pump(0.0)
            if len(self.frames) == n or self.closed:
                return

    def until(self, pred: Callable[[Any], bool], timeout: float, start: int = 0) -> Any:
        """The first frame from ``start`` on that ``pred`` holds for, read for up to ``timeout``
        s (None: none came, or the link closed)."""
        i = self.index_until(pred, timeout, start)
        return self.frames[i] if i is not None else None

    def index_until(self, pred: Callable[[Any], bool], timeout: float, start: int = 0) -> int | None:
        """:meth:`until`'s frame's index in :attr:`frames` (None: none came, or the link closed)."""
        end = time.monotonic() + timeout
        i = start
        while True:
            while i < len(self.frames):
                i += 1
                if pred(self.frames[i - 1]):
                    return i - 1
            left = end - time.monotonic()
            if left <= 0 or self.closed:
                return None
            self.pump(min(left, 0.1))

    def exchange(self, data: bytes, answered: Callable[[Any], bool], timeout: float) -> int | None:
        """The synchronous case runner's step: what the link held dropped, ``data`` (a case
        with the probe right behind it) written, then read until the probe's answer
        (``answered``), for up to ``timeout`` s; its index in :attr:`frames` (a target handles a
        link's frames in order: the frames before it answer the case), None: no answer."""
        self.frames.clear()
        self.send(data)
        return self.index_until(answered, timeout)

    def wait_beat(self, since: float, gap: float) -> bool:
        """Whether a beat comes after ``since`` before ``gap`` s have passed since the last one."""
        while self.last_beat <= since:
            left = self.last_beat + gap - time.monotonic()
            if left <= 0 or self.closed:
                return False
            self.pump(min(left, 0.1))
        return True

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.end.close()


class LinkedTarget(ProcessTarget):
    """A :class:`ProcessTarget` the fuzzer reaches by one :class:`SyncLink` (``link``): the
    traffic it keeps, whether the target is still there (its process runs, the link is
    open), the target's last beat, the fuzzer's own keep-alive, and its end; and the
    synchronous case runner (:meth:`run`: a case written with the probe right behind it, what
    came before the probe's answer judged; :meth:`run_all`, :meth:`watch`, :meth:`beats_on`).

    The protocol declares what is its own: its beat (:meth:`is_beat`) and the gap its liveness
    rule allows between two (``BEAT_GAP_S``; 0: not watched), the fuzzer's keep-alive (its
    period ``KEEPALIVE_S``, :meth:`keepalive_frame`), its probe (:meth:`probe_frame`,
    :meth:`is_probe_answer`, answered within ``REPLY_S``), how a case's answers are judged
    (:meth:`judge`) and its liveness oracles (``oracles``: ``lost(target, case, answered=)``,
    ``silent(target, since)``, ``beats_on(target)``). A case is what ``wire()`` writes."""

    link: SyncLink
    _keepalive_at = 0.0
    BEAT_GAP_S: ClassVar[float] = 0.0
    KEEPALIVE_S: ClassVar[float] = 0.0
    REPLY_S: ClassVar[float] = 1.0
    #: the beat's name in a report ("HEARTBEAT"), and the rule that bounds its first one
    BEAT: ClassVar[tuple[str, str]] = ("beat", "")
    oracles: Any  # a module or an object: the protocol's liveness oracles

    def connect(self, how: TargetSpec, framing: Framing, log: list[Any] | None,
                placeholders: Callable[[str, int], dict[str, str]] | None = None, first_beat_s: float = 10.0) -> Any:
        """The target started or reached (:meth:`ProcessTarget.open`), its link, the fuzzer's
        keep-alive sent and the target's first beat read within ``first_beat_s`` s (its frame;
        none: the target closed, ``SetupError``); what the link held then, dropped."""
        self.link = SyncLink(self.open(how, placeholders), framing, traffic=log, beat=self.is_beat)
        self.keep_alive()
        first = self.link.until(lambda r: self.is_beat(r), first_beat_s)
        if first is None:
            self.close()
            name, rule = self.BEAT
            raise SetupError(f"tcp:{self.address[0]}:{self.address[1]}: no {name} from {self.subject} within "
                             f"{first_beat_s:g} s ({rule})")
        self.frames.clear()
        return first

    @property
    def log(self) -> list[Any] | None:
        """The traffic both ways, for a finding's repro files (None: not kept)."""
        return self.link.traffic

    @log.setter
    def log(self, log: list[Any] | None) -> None:
        self.link.traffic = log

    @property
    def closed(self) -> bool:
        return self.link.closed

    @property
    def frames(self) -> list[Any]:
        return self.link.frames

    @property
    def last_beat(self) -> float:
        """The target's last beat (time.monotonic)."""
        return self.link.last_beat

    @last_beat.setter
    def last_beat(self, t: float) -> None:
        self.link.last_beat = t

    def send(self, data: bytes) -> None:
        self.link.send(data)

    def keepalive(self, period: float, frame: Callable[[], bytes]) -> None:
        """The fuzzer's own periodic frame (``frame()``), sent when ``period`` s have passed
        since the last one (at a case's start: a peer that bounds the gap between ours)."""
        now = time.monotonic()
        if now - self._keepalive_at >= period:
            self._keepalive_at = now
            self.send(frame())

    def keep_alive(self) -> None:
        """The protocol's keep-alive (:meth:`keepalive` of ``KEEPALIVE_S``; none when 0)."""
        if self.KEEPALIVE_S:
            self.keepalive(self.KEEPALIVE_S, self.keepalive_frame)

    def alive(self) -> bool:
        return not self.closed and self.process_alive()

    def close(self) -> None:
        if hasattr(self, "link"):
            self.link.close()
        self.stop()

    # -- what the protocol declares ----------------------------------------------------------
    def is_beat(self, r: Any) -> bool:
        """Whether frame ``r`` is the target's beat."""
        return False

    def keepalive_frame(self) -> bytes:
        raise NotImplementedError

    def probe_frame(self) -> bytes:
        """The probe written behind a case (built anew each time: a sequence number may count)."""
        raise NotImplementedError

    def is_probe_answer(self, r: Any) -> bool:
        raise NotImplementedError

    def judge(self, case: Any, upto: int) -> Any:
        """The hit (or None) the frames before the probe's answer (``frames[:upto]``) show."""
        raise NotImplementedError

    # -- the synchronous case runner ---------------------------------------------------------
    def exchange(self, data: bytes, timeout: float) -> int | None:
        """The keep-alive, then ``data`` and the probe written (``SyncLink.exchange``); the
        probe's answer's index (None: no answer within ``timeout`` s)."""
        self.keep_alive()
        return self.link.exchange(data + self.probe_frame(), self.is_probe_answer, timeout)

    def run(self, case: Any) -> Any:
        """``case`` and the probe sent, what came judged: no answer, ``oracles.lost``; else
        :meth:`judge`, then a beat missing longer than ``BEAT_GAP_S`` (``oracles.lost``, answered)."""
        upto = self.exchange(case.wire(), self.REPLY_S)
        if upto is None:
            return self.oracles.lost(self, case)
        hit = self.judge(case, upto)
        if hit is None and self.BEAT_GAP_S and time.monotonic() - self.last_beat > self.BEAT_GAP_S:
            hit = self.oracles.lost(self, case, answered=True)
        del self.frames[:upto + 1]
        return hit

    def run_all(self, cases: list[Any]) -> bool:
        """``cases`` sent back to back, then the probe (no answer is judged: thousands of
        suspects take one write); whether the probe was answered."""
        answered = self.exchange(b"".join(c.wire() for c in cases), self.REPLY_S + 0.002 * len(cases)) is not None
        self.frames.clear()
        return answered

    def probe_answered(self, timeout: float) -> bool:
        return self.link.until(self.is_probe_answer, timeout) is not None

    def wait_beat(self, since: float) -> bool:
        """Whether a beat comes after ``since`` before the gap since the last one passes ``BEAT_GAP_S``."""
        return self.link.wait_beat(since, self.BEAT_GAP_S)

    def watch(self, since: float) -> Any:
        """After a replay: a beat after ``since`` (nothing), or ``oracles.silent``'s hang."""
        return self.oracles.silent(self, since)

    def beats_on(self) -> Any:
        """With nothing sent: what the link holds read, then ``oracles.beats_on``."""
        self.link.drain()
        return self.oracles.beats_on(self)


class SpareTarget(WorkerTarget):
    """A worker's target (``fuzz.loop.WorkerTarget``) kept with spares started in the
    background (``fuzz.spares``: ``n`` of them, none when attached; one waited for up to
    ``timeout`` s, one that ``alive`` tells has ended never handed on): ``make(log)`` starts
    another like the first (spawned: a new process; attached: a new link), its traffic to
    ``log`` (the target's ``log``), ``close`` ends one; the one now fuzzed (``current``) is
    replaced after a death (:meth:`restart`), made the campaign's own by :meth:`adopt`. Every
    protocol's worker target is one (MAVLink's ``fuzz.mavlink_vehicle.MavTarget``, Nsqd's
    ``fuzz.nsqd_backend.BackendTarget``)."""

    def __init__(self, first: Any, make: Callable[[list[Any] | None], Any], close: Callable[[Any], None], *,
                 attached: bool, timeout: float | None = 30.0, n: int = 1,
                 alive: Callable[[Any], bool] | None = None) -> None:
        super().__init__(first, attached=attached)
        self.make = make
        self.spares: Spares[Any] = Spares(lambda: make(None), close, alive, n=0 if attached else n, timeout=timeout)

    def fresh(self, log: list[Any] | None = None) -> Any:
        """Another target, the spare started in the background at the previous call (a
        replay then waits for no process to start), and the next spare started; its traffic
        to ``log`` (its ``log``; a spare's is None)."""
        t = self.spares.next(lambda: self.make(log))
        if log is not None:
            t.log = log
        return t

    def adopt(self, t: Any) -> Any:
        """``t`` made the one the campaign fuzzes (nothing to do, unless the protocol says)."""
        return t

    def restart(self, reason: str) -> Any:
        self.current.close()
        self.current = self.adopt(self.fresh())
        self.count_restart(reason)
        return self.current

    def close(self) -> None:
        self.current.close()
        self.spares.discard()


def read_until(conns: list[Any], pred: Callable[..., bool], timeout: float) -> bool:
    """Read every one of ``conns`` (``harness.stream_conn.StreamConn``s) until ``pred()``
    holds or ``timeout`` s pass (or all closed)."""
    end = time.monotonic() + timeout
    while True:
        if pred():
            return True
        live = [c for c in conns if c.closed_at is None]
        left = end - time.monotonic()
        if left <= 0 or not live:
            return bool(pred())
        ready, _, _ = select.select([c.sock for c in live], [], [], min(left, 0.05))
        for c in live:
            if c.sock in ready:
                c.pump(0)

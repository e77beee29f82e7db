"""What every session shares, whatever its protocol and role: the node spawned by
``--spawn`` with the runner's placeholders (``SpawnedNode``, ``fill_placeholders``), how it
died (``Death``), free ports, and ``SessionBase`` — the spawned node's liveness, death and
revival, the case's bounds and their marks in the capture, the case context the runner hands
it (``make_context``). What the datagram protocol's two roles (``harness.drone_session`` for a
drone, ``harness.manager_session`` for a Mission Manager) add is ``DatagramSessionBase``: MCP's
constants, the run's timings, the capture's observers on the runner's socket held against
signals, ``--impair``. The sessions over a connection or a link stand on
``harness.stream_session`` (a node serving connections: ``ConnSessionBase``, Nsqd's backend)
and ``harness.link_session`` (one link: MAVLink's two roles), the protocol their declared
parameter. No session imports another's module but a role's own protocol's."""

from __future__ import annotations

import contextlib
import re
import shlex
import signal
import socket
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.config import EMBEDDED_RTO, RunConfig  # noqa: F401 - EMBEDDED_RTO: its users import it here
from mcp_conform.harness.driver import Datagram, Sent, TargetDriver
from mcp_conform.harness.errors import SetupError, SpawnFailure, TargetLost
from mcp_conform.harness.interrupts import INTERRUPTS
from mcp_conform.harness.liveness import describe_exit
from mcp_conform.harness.node import NodeBase
from mcp_conform.harness.procs import ManagedProcess
from mcp_conform.spec import SPEC
from mcp_conform.spec.profiles import Profile, RoleProfile, resolve
from mcp_conform.traceio.recorder import NODE_METADATA, RUN_DELAY_METADATA, run_delay_metadata
from mcp_conform.vehicle.ports import free_port  # noqa: F401  (re-exported: the runner's and the tests' ports)

MANAGER_ID = int(SPEC.protocol["manager_id"])
DRONE_PORT = int(SPEC.protocol["ports"]["drone"])
MANAGER_PORT = int(SPEC.protocol["ports"]["manager"])
BROADCAST_ADDRESS = str(SPEC.protocol["broadcast_address"])
MIN_COPIES = int(SPEC.params["min_copies"])  # MCP-RTX-1: "at least 3 copies while the ACK is withheld"
EMBEDDED_ACK_WINDOW = 0.25

def _held(write: Any) -> Any:
    """A capture writer that a signal cannot cut in half (``INTERRUPTS.held``)."""
    def call(*args: Any, **kw: Any) -> Any:
        with INTERRUPTS.held():
            return write(*args, **kw)
    return call


def check_target(target: tuple[str, int]) -> tuple[str, int]:
    """``--target`` as a usable address, or a one-line SetupError before any case runs:
    an unresolvable host, port 0, an address this host cannot send to."""
    host, port = target
    if port == 0:
        raise SetupError(f"--target {host}:{port}: port 0 is not a port a node can listen on")
    try:
        infos = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except (socket.gaierror, UnicodeError) as exc:
        why = exc.strerror if isinstance(exc, socket.gaierror) and exc.strerror else str(exc)
        raise SetupError(f"--target {host}:{port}: cannot resolve host {host!r}: {why}") from None
    addr = (str(infos[0][4][0]), port)
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        try:
            s.connect(addr)  # routes it without sending anything
        except OSError as exc:
            raise SetupError(f"--target {host}:{port}: cannot reach {addr[0]}: {exc.strerror}") from None
    return addr


def reference_command(profile: Profile, role: RoleProfile, options: str) -> str:
    """The reference node of ``role`` as the runner spawns it for its embedded default:
    ``mcp-node --protocol NAME ROLE OPTIONS`` (``python -m mcp_conform.reference_impl``, the
    interpreter the runner runs on), ``options`` a ``--spawn`` template of the role's own."""
    return (f"{shlex.quote(sys.executable)} -m mcp_conform.reference_impl --protocol {profile.name} {role.name} "
            + options)


class _Placeholders(dict[str, str]):
    def __missing__(self, key: str) -> str:  # unknown braces are left alone
        return "{" + key + "}"


def fill_placeholders(command: str, values: dict[str, str]) -> list[str]:
    """Split ``command`` like a shell and replace known ``{placeholders}`` in each word."""
    try:
        words = shlex.split(command)
    except ValueError as exc:
        raise SetupError(f"--spawn: cannot split command: {exc}") from None
    if not words:
        raise SetupError("--spawn: empty command")
    mapping = _Placeholders(values)
    out = []
    for w in words:
        try:
            out.append(w.format_map(mapping))
        except (ValueError, IndexError, KeyError, AttributeError):
            out.append(w)  # braces that are not placeholders stay as they are
    return out


class SpawnedNode:
    """The node process: its own process group, dies with the runner (``harness.procs``),
    its stdout and stderr kept (bounded) as evidence."""

    def __init__(self, argv: list[str]) -> None:
        self.argv = argv
        try:
            self._p = ManagedProcess(argv)
        except OSError as exc:
            raise SpawnFailure(f"--spawn: cannot start {argv[0]!r}: {exc.strerror}",
                               {"command": argv, "exit": None, "stdout": [], "stderr": []}) from None
        self.proc = self._p.proc
        #: called once as the node is stopped, before SIGTERM (its run delay read a last time)
        self.before_stop: Callable[[], None] | None = None

    def alive(self) -> bool:
        return self._p.alive()

    def run_delay(self) -> int | None:
        """Its run delay (ns, D-7): now, or as it was between its exit and its reaping when it
        ended by itself (``harness.procs.ManagedProcess.run_delay``)."""
        return self._p.run_delay()

    @property
    def returncode(self) -> int | None:
        return self._p.returncode

    def output_tail(self, lines: int = 12) -> str:
        out, err = self._p.output(lines)
        return "\n".join(out + err)

    def details(self, lines: int = 12) -> dict[str, Any]:
        """The node's own words for a report: command as run, exit, stdout and stderr tails."""
        out, err = self._p.output(lines)
        rc = self.returncode
        return {"command": list(self.argv), "exit": None if rc is None else describe_exit(rc),
                "stdout": out, "stderr": err}

    def evidence(self) -> list[str]:
        d = self.details()
        ev = [f"node command: {shlex.join(d['command'])}"]
        if d["exit"]:
            ev.append(f"node process {d['exit']}")
        for stream in ("stdout", "stderr"):
            if d[stream]:
                ev.append(f"node {stream} (last lines):\n    " + "\n    ".join(d[stream]))
            else:
                ev.append(f"node {stream}: (nothing)")
        return ev

    @property
    def process(self) -> ManagedProcess:
        """The managed process itself (its output, its sanitizer report: ``harness.procs``)."""
        return self._p

    def stop(self, grace: float = 2.0) -> None:
        hook, self.before_stop = self.before_stop, None
        if hook is not None:  # while the process is still there to be read
            with contextlib.suppress(Exception):
                hook()
        self._p.stop(grace=0.0 if INTERRUPTS.hurry else grace)

    def close(self) -> None:
        self.stop()


_SANITIZER = re.compile(r"(SUMMARY: \w+Sanitizer: .*|ERROR: \w+Sanitizer: .*|runtime error: .*)")


@dataclass(frozen=True)
class Death:
    """How a spawned node ended: exit code or signal, its sanitizer line, its stderr tail."""

    code: int | None
    signal_name: str | None
    sanitizer: str | None
    stderr: tuple[str, ...]
    subject: str = "the node"

    def describe(self) -> str:
        how = f"killed by {self.signal_name}" if self.signal_name else f"exited with status {self.code}"
        return f"{self.subject} process {how}" + (f"; {self.sanitizer}" if self.sanitizer else "")


def death_of(node: SpawnedNode, subject: str = "the node") -> Death:
    """How ``node``, which has ended, ended: the signal (from the exit status, or a shell's
    128 + N), the sanitizer's summary line and the top frames of its report, else its stderr's
    tail."""
    p = node.process
    code = p.returncode
    _, err = p.output(400)
    sig = signal.Signals(-code).name if code is not None and code < 0 else None
    if sig is None and code is not None and code > 128:
        with contextlib.suppress(ValueError):
            sig = signal.Signals(code - 128).name
    san = next((m.group(1) for line in err for m in [_SANITIZER.search(line)] if m and "SUMMARY" in m.group(1)), None)
    san = san or next((m.group(1) for line in err for m in [_SANITIZER.search(line)] if m), None)
    report = p.sanitizer_report()  # its ERROR line and the top frames of the stack
    if report:
        frames = [line for line in report[1:] if line.lstrip().startswith("#")][:5]
        return Death(code, sig, san or report[0].strip(), tuple([report[0], *frames]), subject)
    return Death(code, sig, san, tuple(err[-12:]), subject)


@dataclass
class WithheldCopies:
    """A message's ACK withheld: its copies, then ACKs naming another seq or from another
    source (MCP-RTX-2), then the right ACK — what either role's startup observes of the node's
    first unicast (MCP-RTX-1/2/3, MCP-SEQ-2)."""

    copies: list[Datagram] = field(default_factory=list)  # ACK withheld
    wrong_acks: list[Sent] = field(default_factory=list)
    copy_after_wrong_acks: Datagram | None = None
    wrong_ack_wait: float = 0.0
    right_ack: Sent | None = None
    copies_after_right_ack: list[Datagram] = field(default_factory=list)  # proven: more than one
    crossed_copy: Datagram | None = None  # a lone copy after the right ACK: it may have crossed it
    stop_watch: float = 0.0
    gave_up: str | None = None  # the node exited short of its copies (``harness.drone_giveup``)

    def watch_after_right_ack(self, after: Callable[[], list[Datagram]], gap: float,
                              sleep: Callable[[float], None]) -> None:
        """MCP-RTX-1's "retransmits it until it is ACKed", observed after the right ACK:
        ``after()`` gives the copies that came after it (past the runner's grace), read once
        :attr:`stop_watch` has passed. A copy that came after the right ACK may have crossed
        it, sent before the node read the ACK (its timer fired first; a loaded host kept its
        reader off the CPU past the grace): that node stops, and one copy proves nothing. A
        node that goes on retransmitting sends another a period later, so when one copy came,
        the watch goes on one more period (``gap``, the node's own) and a second copy at least
        half a period after the first proves the rule broken (:attr:`copies_after_right_ack`);
        a lone one is kept as :attr:`crossed_copy`."""
        sleep(self.stop_watch)
        late = after()
        if len(late) == 1:
            sleep(gap)
            self.stop_watch += gap
            late = after()
        proven = [d for d in late[1:] if d.t - late[0].t >= 0.5 * gap]
        self.copies_after_right_ack = [late[0], *proven] if proven else []
        self.crossed_copy = late[0] if late and not proven else None

    def ended_before_wrong_acks(self, before: list[float]) -> str | None:
        """Why the sender's next copy was already overdue when the runner's wrong ACKs went out
        (None: it was not): ``before``, when its copies reached the runner up to them; the last
        came more than ``wrong_ack_wait`` -- the time the RTX-2 case waits for a copy after them
        -- before them. Its retry limit ended its copies first (or a runner held off the CPU sent
        them late): what it does with a wrong ACK is not seen. A sender that stops on any ACK
        retransmits until one comes: its last copy is within a gap of them."""
        if not self.wrong_acks or not before:
            return None
        late = self.wrong_acks[0].t - max(before)
        if late <= self.wrong_ack_wait:
            return None
        return (f"{len(before)} copies, the last {late:.2f} s before them, more than the "
                f"{self.wrong_ack_wait:.2f} s watched after them")

    def limit_or_any_ack(self, before: list[float]) -> bool:
        """Whether the copies stopped right after the wrong ACKs, so that this observation cannot
        tell why: ``before`` as for :meth:`ended_before_wrong_acks`, at least ``MIN_COPIES`` of
        them, none since (the right ACK is sent after the wait). A retry limit of
        ``MIN_COPIES - 1``, the rule's configurable limit (spec/mcp.yaml's ``min_copies``), ends
        them there as a sender that stops on any ACK does (MCP-RTX-2's fault)."""
        return (bool(self.wrong_acks) and self.copy_after_wrong_acks is None and len(before) >= MIN_COPIES
                and self.ended_before_wrong_acks(before) is None)

    def gaps(self) -> list[float]:
        ts = [d.t for d in self.copies]
        return [b - a for a, b in zip(ts, ts[1:], strict=False)]

    def run_delays(self) -> list[int | None]:
        """The node's run delay (ns) at each copy, where known (MCP-RTX-3, ``judge.spacing``)."""
        return [d.run_delay for d in self.copies]

    def period(self) -> float | None:
        """The node's retransmission period as its copies show it (the median gap), or None
        with fewer than two copies."""
        g = sorted(self.gaps())
        return g[len(g) // 2] if g else None


#: How far the node's measured retransmission period may be from --rto before the run says
#: so (a factor either way; the description's jitter and a loaded machine stay well inside).
PERIOD_FACTOR = 2.0


def disagrees(period: float | None, rto: float) -> bool:
    """The node's measured retransmission period is more than ``PERIOD_FACTOR`` off --rto."""
    return period is not None and period > 0 and not rto / PERIOD_FACTOR <= period <= rto * PERIOD_FACTOR


def timing_note(period: float | None, rto: float, copies: int, then: str) -> str | None:
    """Issue 18 item 10: the node's retransmission period, seen at startup, against --rto:
    a sentence when they disagree (``then``: what the tool does about it), else None."""
    if not disagrees(period, rto):
        return None
    return (f"timing: the node retransmits every {period:.2f} s (median of {copies - 1} gap(s) between its "
            f"first message's copies), not every {rto:g} s as --rto says: {then}; "
            f"--rto {period:.2g} says what the node does")


class _HeldRecorder:
    """The recorder's ``impairment`` writer, never cut in half by a signal."""

    def __init__(self, recorder: Any) -> None:
        self.impairment = _held(recorder.impairment)


class SessionBase(NodeBase):
    """What every role's session shares, whatever its protocol and transport: the spawned
    node (its command with the runner's placeholders, its liveness, its death and its
    revival) and the case's begin and end with their marks in the capture. A session adds
    how its node is spawned and reached (``_spawn``) and what it does around a case
    (``before_case``, ``case_started``, ``case_ending``, ``case_ended``). The runner's case
    context for this role, ``make_context(session, case_id, rules)``, is set by the runner
    (``conformance``), which owns the cases and their verify helpers."""

    cfg: RunConfig
    _node: SpawnedNode | None = None
    recorder: Any
    #: who is judged, in the words of a report ("the backend process killed by SIGSEGV")
    subject = "the node"
    #: how many times the spawned node's process was replaced (a death, a hang, a fresh mission)
    restarts: int = 0
    #: the run's clock (``harness.clock``): the host's, or the simulator's virtual time
    clock: Clock = REAL

    def context_factory(self) -> Callable[..., Any]:
        if self.make_context is None:
            raise RuntimeError("begin_case: no case context set (session.make_context)")
        return self.make_context

    @property
    def node(self) -> SpawnedNode | None:
        """The spawned node's process (None: attach mode, or not started yet); as it is
        stopped, :meth:`record_run_delay` runs first."""
        return self._node

    @node.setter
    def node(self, node: SpawnedNode | None) -> None:
        self._node = node
        if node is not None:
            node.before_stop = self.record_run_delay

    def record_run_delay(self) -> None:
        """The spawned node is being stopped: its last run delay to the capture; nothing by
        default (:class:`DatagramSessionBase` records it)."""

    def node_run_delay(self) -> int | None:
        """The spawned node's run delay now, or at its exit when it has ended by itself
        (``SpawnedNode.run_delay``); None in attach mode."""
        node = self.node
        return node.run_delay() if node is not None else None

    # ------------------------------------------------------------------ the spawned node
    @property
    def spawn_command(self) -> str | None:
        """The command the node is spawned with, placeholders unfilled (--spawn, or the role's
        embedded reference node); None: attached."""
        return self.cfg.spawn

    @property
    def spawned(self) -> bool:
        return self.spawn_command is not None

    def _spawn(self) -> None:
        """Start the node's process (``spawn_command`` filled in by :func:`fill_placeholders`,
        run as a :class:`SpawnedNode`), ready for the role's startup."""
        raise NotImplementedError(f"{type(self).__name__} spawns no node")

    def respawn(self, grace: float = 2.0) -> None:
        """Spawn mode: the node's process stopped (SIGTERM, SIGKILL after ``grace`` s) and
        started afresh; a replaced process counts in ``restarts``."""
        if self.node is not None:
            self.node.stop(grace)
            self.restarts += 1
        self.spawn_node()

    def spawn_node(self) -> None:
        """:meth:`_spawn`, where a role's start and :meth:`respawn` start the node; a role that
        must count what the node sends from its first instant marks it here first."""
        self._spawn()

    def revive(self) -> bool:
        """Spawn mode: a node whose process ended started afresh for the next case (the run
        goes on); True when it was."""
        if self.node is None or self.node.alive():
            return False
        self.respawn()
        return True

    def alive(self) -> bool:
        return self.node.alive() if self.node is not None else True

    def death(self, grace: float = 0.0) -> Death | None:
        """How the spawned node ended, if it did within ``grace`` s (a sanitizer takes a
        moment to write its report and exit); None while it runs, or when none was spawned;
        :meth:`revive` starts it afresh."""
        node = self.node
        if node is None:
            return None
        end = self.clock.monotonic() + grace
        while node.alive() and self.clock.monotonic() < end:
            self.clock.sleep(0.005)
        return None if node.alive() else death_of(node, self.subject)

    # ------------------------------------------------------------------ case API
    def begin_case(self, case_id: str, rules: tuple[str, ...]) -> Any:
        """Start a case: the node made ready for it (:meth:`before_case`), the runner's case
        context (``make_context``), the case's start in the capture."""
        self.before_case()
        ctx = self.context_factory()(self, case_id, rules)
        self._case_mark(case_id, "start", ctx.start_ns, rules=rules)
        self.case_started(ctx)
        return ctx

    def end_case(self, ctx: Any, outcome: str) -> None:
        """End a case: what the session does before its end mark (:meth:`case_ending`), the
        mark in the capture, then what it does for the next case (:meth:`case_ended`)."""
        ctx.end_ns = self.clock.time_ns()
        self.case_ending(ctx, outcome)
        self._case_mark(ctx.case_id, "end", ctx.end_ns, outcome=outcome, rules=ctx.rules,
                        evidence=ctx.evidence)
        self.case_ended(ctx, outcome)

    def before_case(self) -> None:
        """Before a case's context: a node lost earlier ends the run's cases (TargetLost)."""
        if self.lost is not None:
            raise TargetLost(self.lost)

    def case_started(self, ctx: Any) -> None:
        """After the case's start mark; nothing by default."""

    def case_ending(self, ctx: Any, outcome: str) -> None:
        """The case's verdict is ``outcome``, before its end mark; nothing by default."""

    def case_ended(self, ctx: Any, outcome: str) -> None:
        """After the case's end mark (a dead node revived for the next case); nothing by default."""

    def _case_mark(self, case_id: str, phase: str, t_ns: int, **kw: Any) -> None:
        """The case's start or end in the capture, never cut off by a signal."""
        if self.recorder is not None:
            with INTERRUPTS.held():
                self.recorder.case_mark(case_id, phase, t_ns, **kw)



class DatagramSessionBase(SessionBase):
    """What the datagram protocol's roles add (``harness.drone_session`` for a drone,
    ``harness.manager_session`` for a Mission Manager): the runner's datagram socket
    (``harness.driver``), the run's timings, the run's observers on it (the capture, the
    trace monitor), ``--impair``'s link and the address placeholders of both ends."""

    driver: TargetDriver | None
    #: the node under test's ID as the capture knows it (:meth:`record_node`)
    recorded_node_id: int | None = None
    #: the run's trace monitor (``judge.run_monitor``), once the role's session built it
    monitor: Any = None
    #: the node under test's address, as the run's monitor and the capture know it (None:
    #: not observed yet, :meth:`observe_run`)
    node_address: tuple[str, int] | None = None
    #: the driver's mark as the spawned node last started (:meth:`spawn_node`); None: not spawned
    spawn_mark: int | None = None

    @property
    def rto(self) -> float:
        return self.cfg.rto

    @property
    def ack_window(self) -> float:
        return self.cfg.ack_window

    def observe_run(self, target: tuple[str, int], node_id: int | None, *, complete: bool,
                    judge: bool = True, also: tuple[Any, ...] = ()) -> Any:
        """The run's observers on the driver, built one way for every role: the capture
        (held against signals, so a record is never cut in half), the run's trace monitor
        (``judge.run_monitor``) and ``also`` (the role's own), added at once: each hears what
        the driver got before too (``TargetDriver.add_observers``); the capture is told whose
        traffic it holds and whether the monitor judges it as complete, so ``mcp-capture check``
        judges it the same. ``judge=False``: no run monitor (the fuzzer's oracles judge); None."""
        driver = self.driver
        assert driver is not None
        driver.run_delay = self.node_run_delay  # spawn mode: the node's lateness (MCP-RTX-3)
        observers, bursts, monitor = [], [], None
        if self.recorder is not None:
            self.recorder.local = driver.listen  # the runner's socket: each datagram's other end
            observers, bursts = [_held(self.recorder.datagram)], [_held(self.recorder.burst)]
        self.node_address = target
        if judge:
            monitor_class = resolve(self.cfg.profile()[0].monitor)  # the protocol's (MCP: judge.run_monitor)
            monitor = monitor_class(rto=self.cfg.rto, ack_window=self.cfg.ack_window,
                                    broadcast_id=self.cfg.broadcast_id, node_id=node_id, node_addr=target,
                                    complete=complete, **({"rto_declared": True} if self.cfg.rto_declared else {}))
            monitor.listen = driver.listen
            observers.append(monitor.observe)
        driver.add_observers([*observers, *also], bursts)
        if judge:
            self.record_node(node_id, complete=complete)
        return monitor

    def spawn_node(self) -> None:
        """:meth:`_spawn` with the driver's mark taken just before (``spawn_mark``): a node may
        send its first datagram before the runner's next line runs (a first spawn also starts
        the reaper, ``harness.procs``, while the node already runs); what it sent from its
        first instant is the startup's to read, not lost before the startup looks."""
        self.spawn_mark = self.driver.mark() if self.driver is not None else None
        self._spawn()

    def record_node(self, node_id: int | None, *, complete: bool | None = None) -> None:
        """Tell the capture whose traffic it holds (the node under test's ID and address, as
        the run's monitor knows them) and how the monitor judges it."""
        if node_id is not None:
            self.recorded_node_id = node_id
        address = self.node_address
        if self.recorder is None or node_id is None or address is None:
            return
        values: dict[str, Any] = {"id": node_id, "address": f"{address[0]}:{address[1]}"}
        if complete is not None:
            values["complete"] = "true" if complete else "false"
        with contextlib.suppress(Exception):
            self.recorder.add_metadata(NODE_METADATA, values)

    def record_run_delay(self) -> None:
        """As the runner stops the spawned node, its run delay (D-7, ``harness.run_delay``)
        read a last time and written to the capture (``traceio.recorder.RUN_DELAY_METADATA``):
        a stall after the node's last datagram -- a manager off the CPU while a retransmission
        fell due, which then read the ACK and closed -- shows nowhere else, and ``mcp-capture
        check`` feeds it to the monitor's veto (``Monitor.run_delay``). The node's ID: as
        :meth:`record_node` named it, a manager's its role's. A node that closed itself and was
        reaped before the stop has the run delay read between its exit and its reaping
        (``harness.procs``); none known, or none readable: nothing is written."""
        node_id = self.recorded_node_id
        if node_id is None:  # the role's own ID where the spec fixes it (MCP's manager: 0)
            node_id = self.cfg.profile()[1].fixed_id
        if node_id is None or (self.recorder is None and self.monitor is None):
            return
        ns = self.node_run_delay()
        if ns is None:
            return
        t_ns = self.clock.time_ns()
        if self.recorder is not None:
            with INTERRUPTS.held(), contextlib.suppress(Exception):
                self.recorder.add_metadata(RUN_DELAY_METADATA, run_delay_metadata(node_id, ns, t_ns))
        if self.monitor is not None:  # the run's own monitor, as mcp-capture check's: one judge
            self.monitor.run_delay(t_ns, node_id, ns)

    def respawn(self, grace: float = 2.0) -> None:
        """Spawn mode: the node replaced (``SessionBase.respawn``), and what the runner's own
        ``--impair`` link still held for later dropped first: copies to or from the old
        process (``ImpairedLink.drop_held``)."""
        link = self.driver.link if self.driver is not None else None
        if link is not None:
            link.drop_held()
        super().respawn(grace)

    # ------------------------------------------------------------------ --impair
    @property
    def trace_complete(self) -> bool:
        """The run's trace holds every datagram the node exchanged (absences are evidence),
        unless ``--impair`` makes the runner's own link lossy (issue 22)."""
        return self.cfg.impair is None

    def impaired_link(self, spec: Any) -> Any:
        """The runner's socket edge through ``spec`` (``harness.impair_link``): each
        decision kept, and recorded in the capture (``/impair``)."""
        from mcp_conform.harness.impair import Impairment
        from mcp_conform.harness.impair_link import ImpairedLink

        recorder = _HeldRecorder(self.recorder) if self.recorder is not None else None
        # a reply later than a quarter of the ACK window may fall outside what a case watches
        return ImpairedLink(Impairment(spec), recorder=recorder,
                            spoil_delay_s=min(0.25 * self.cfg.ack_window, 0.5), clock=self.clock)

    def spoiled_by_impairment(self, since: float, until: float | None = None, *,
                              lookback: bool = True) -> list[str]:
        """What the impaired link did between ``since`` and ``until`` (the run clock's ``monotonic()``)
        that can spoil an observation, for a person; [] on a clean link. ``lookback``: the
        window reaches back over the node's retransmissions of an earlier exchange (2 x --rto)."""
        link = self.driver.link if self.driver is not None else None
        if link is None:
            return []
        start = since - 2 * self.cfg.rto if lookback else since
        return [ev.describe() for ev in link.touched(start, until)]

    def _address_placeholders(self, node_id: int, mavlink: str) -> dict[str, str]:
        """{target_host} {target_port} {listen_host} {listen_port} {broadcast} {id} {mavlink}."""
        assert self.driver is not None
        lhost = self.driver.listen[0] or "127.0.0.1"
        if lhost == "0.0.0.0":
            lhost = "127.0.0.1"
        return {
            "target_host": self.driver.target[0], "target_port": str(self.driver.target[1]),
            "listen_host": lhost, "listen_port": str(self.driver.listen[1]),
            "broadcast": BROADCAST_ADDRESS, "id": str(node_id), "mavlink": mavlink,
        }

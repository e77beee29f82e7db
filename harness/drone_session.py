"""The node under test over a whole run: attach, spawn or the embedded reference node.

A ``Session`` owns the target driver, the simulated vehicle (``--mavlink``), the spawned
process, and the startup phase (docs/design.md "Startup rules"): the vehicle withholds the GPS
fix, then gives it; the runner withholds the ACK of Mission_Ready for a few copies, sends a
wrong-sequence and a wrong-source ACK, then the right one (where the copies stopped at the wrong
ACKs, spawn mode sees it again on a restarted node: ``harness.drone_rtx2``). What it saw is kept
in ``Session.startup`` for the startup-phase cases to judge. Then it starts the mission
(Start_Mission, MCP-BLK-4): commands go only between Mission_Ready and End_Mission (D-6).

A node whose header reads right only byte-swapped (``judge.monitor.byte_order_fault``, MCP-HDR-2)
is diagnosed on its first datagrams: no mission is started, and every case but the ones judged
on the raw bytes (``FRAMING_RULES``) is skipped (``not_judged``): it would misread the rest.

Setup errors (the node never answers, a port is taken, spawn fails) raise ``SetupError``.
A node that dies or goes silent after an input fails that case; in spawn mode it is
restarted for the next case, in attach mode the remaining cases are errors.
"""

from __future__ import annotations

import contextlib
import threading
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import Datagram, Exchange, TargetDriver
from mcp_conform.harness.drone_giveup import POLL_S, gave_up, others_while_waiting, restart_quick
from mcp_conform.harness.drone_rtx2 import needs_second_look, observe_again
from mcp_conform.harness.errors import SetupError, SpawnFailure, TargetLost
from mcp_conform.harness.liveness import Liveness
from mcp_conform.harness.procs import SPAWN_STARTUP_S
from mcp_conform.harness.session_base import (  # noqa: F401  (re-exported: harness.drone_session names them)
    BROADCAST_ADDRESS,
    DRONE_PORT,
    EMBEDDED_ACK_WINDOW,
    EMBEDDED_RTO,
    MANAGER_ID,
    MANAGER_PORT,
    MIN_COPIES,
    DatagramSessionBase,
    SpawnedNode,
    WithheldCopies,
    _held,
    check_target,
    fill_placeholders,
    free_port,
    reference_command,
    timing_note,
)
from mcp_conform.harness.transport import Transport
from mcp_conform.judge.monitor import byte_order_fault
from mcp_conform.judge.run_monitor import RunMonitor, from_node, link_events
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action
from mcp_conform.spec.profiles import pick

_READY = int(Action.MISSION_READY)

#: Rules judged on a datagram's raw bytes (the preamble, the header's length and byte order),
#: not on the values of its header fields: still judged when those cannot be read.
FRAMING_RULES = frozenset({"MCP-HDR-1", "MCP-HDR-2"})

#: The observed startup's parts (a shard of ``mcp-conform --parallel`` may observe some,
#: conformance.schedule.shard_plan), each as in the whole: the fix withheld (MCP-BLK-5); the
#: copies while the ACK is withheld, then the watch after the right ACK (MCP-RTX-1's halves,
#: MCP-RTX-3, MCP-SEQ-2, MCP-BLK-1, MCP-BLK-4's time to arm); the wrong ACKs (MCP-RTX-2).
STARTUP_PARTS = frozenset({"fix", "copies", "wrong"})


def embedded_command() -> str:
    """The reference drone, as the runner spawns it for the embedded default."""
    return reference_command(*pick("mcp", "drone"), "--id {id} --listen {target_host}:{target_port} "
                             "--target {listen_host}:{listen_port} --mavlink {mavlink} --rto " + str(EMBEDDED_RTO))


@dataclass
class Startup(WithheldCopies):
    """What the startup phase observed for its cases: Mission_Ready's copies while its ACK was withheld, and around them."""

    observed: bool = False  # False: no Mission_Ready was seen (attach mode, node already past it)
    reason: str = ""  # why it was not observed
    vehicle: bool = False  # the fix was withheld by our vehicle
    node_connected_to_vehicle: bool = False
    fix_given_at: float | None = None
    ready_before_fix: list[Datagram] = field(default_factory=list)
    others_while_waiting: list[Datagram] = field(default_factory=list)  # non-ACK, non-MR datagrams
    again: Startup | None = None  # MCP-RTX-2 seen again on a restarted node (``harness.drone_rtx2``)


class Session(DatagramSessionBase):
    """One run against one node (see the module docstring)."""

    first_awaited = "its Mission_Ready, or an ACK of a probe"

    def __init__(self, cfg: RunConfig, recorder: Any = None, *, clock: Clock = REAL,
                 transport: Transport | None = None) -> None:
        self.cfg = cfg
        self.recorder = recorder
        #: the run's clock and the driver's far end (``harness.clock``, ``harness.transport``):
        #: the host's and a UDP socket, or the simulator's (``mcp_conform.sim.runner``)
        self.clock, self.transport = clock, transport
        if cfg.embedded:
            cfg.spawn = cfg.spawn or embedded_command()
            cfg.mavlink = True
        self.driver: TargetDriver | None = None
        self.liveness: Liveness | None = None
        self.vehicle: Any = None
        self.mavlink_url = ""  # {mavlink}: how the node reaches the vehicle
        self.node: SpawnedNode | None = None
        self.argv: list[str] = []
        self.target_id: int | None = cfg.target_id
        self.target_desc = ""
        self.startup = Startup()
        self.start_mission: Exchange | None = None
        self.end_mission: Exchange | None = None
        self.ended = False
        self.lost: str | None = None
        self.needs_restart = False
        self.restarts = 0
        self.passthrough_forwarded: bool | None = None  # learnt by the first probe
        self.passthrough_altered = False  # the first probe reached the autopilot altered (MCP-PAY-8)
        self.other_src_accepted: bool | None = None
        self._t0_ns = clock.offset_ns()  # monotonic -> run clock (read so a preemption cannot skew it)
        self.monitor: RunMonitor | None = None  # the trace monitor over the whole run
        #: when the observed startup phase ran (the clock's ``monotonic()``): what spoils it
        self.startup_window: tuple[float, float | None] = (0.0, None)
        #: (rule, why): the startup phase found the node's header unreadable in network order
        self.unreadable: tuple[str, str] | None = None
        self.timing: str | None = None  # the node's retransmission period disagrees with --rto
        #: held while a case learns what the node can do (passthrough): the runner's schedule
        #: may run cases together (conformance.schedule)
        self.capability_lock = threading.RLock()
        self.period: float | None = None  # that period, as measured at startup
        self._startup_mark: int | None = None  # the first startup's first datagram (while it runs)
        self.startup_fix_at: float | None = None  # when this startup gave the vehicle its fix
        self._startup_waited = 0.0  # how long the startup waited for Mission_Ready (s)

    # ------------------------------------------------------------------ properties
    def to_ns(self, t_monotonic: float) -> int:
        return self._t0_ns + int(t_monotonic * 1e9)

    # ------------------------------------------------------------------ start / stop
    def start(self, observe_startup: bool = True, watch: bool = True, measure: bool = False,
              diagnose: bool = False, parts: frozenset[str] | None = None) -> None:
        """Open the driver, start the vehicle and the node, run the startup phase (observed
        for the startup-phase cases unless ``observe_startup`` is False: then it is the quick
        one of a restart, as the fuzzer wants it). ``watch=False``: no background liveness
        watcher and no run monitor (the fuzzer's probe behind each batch is its proof of
        life, and its oracles judge every datagram once). ``measure``: in the quick startup,
        the node's retransmission period is still measured (``period``), its Mission_Ready's
        ACK withheld until a second copy shows it. ``diagnose``: the quick startup leaves the
        node as the observed one does: a header that reads right only byte-swapped is still
        diagnosed (MCP-HDR-2, ``unreadable``), a Mission_Ready the driver could not decode still
        ACKed by its header (a shard of ``mcp-conform --parallel`` that does not hold the
        startup-phase cases: its cases are skipped on that diagnosis, as in a run of one).
        ``parts``: the observed startup's parts to observe (``STARTUP_PARTS``; None: by ``observe_startup``)."""
        cfg = self.cfg
        if self.spawned:
            listen = cfg.listen or ("", 0)
            target = cfg.target or ("127.0.0.1", free_port())
            if self.target_id is None:
                self.target_id = 1
        else:
            if cfg.target is None:
                raise SetupError("no --target and no --spawn")
            listen = cfg.listen or ("", MANAGER_PORT)
            target = check_target(cfg.target)
        self.driver = TargetDriver(target, listen, our_id=MANAGER_ID, clock=self.clock,
                                   transport=self.transport)
        # the startup phase decides when Mission_Ready is ACKed: one that lands before it (an
        # attached node speaks before the runner binds) ACKed here would stop its copies
        # unseen, and the startup would wait for one in vain
        self.driver.auto_ack = lambda d: d.action != _READY
        try:
            self.driver.open()
        except OSError as exc:
            raise SetupError(str(exc)) from None
        self.driver.alive = self.alive
        if cfg.impair is not None:
            self.driver.link = self.impaired_link(cfg.impair)
        if watch:
            self.liveness = Liveness(self.driver, self.rto,
                                     lambda: self.target_id if self.target_id is not None else 1)
            self.liveness.start()
        self.driver.attributor.horizon = max(self.rto, self.ack_window)
        self.driver.attributor.peer_id = self.target_id
        self.driver.attributor.broadcast_id = self.cfg.broadcast_id
        self.monitor = self.observe_run(target, self.target_id, complete=self.trace_complete, judge=watch)
        # runner seq: fixed by the seed, low enough that no case wraps by accident
        self.driver.set_seq(1000 + cfg.seed % 5000)
        self.target_desc = f"{target[0]}:{target[1]}"
        if cfg.mavlink and self.spawned:
            self._start_vehicle()
        self.startup_window = (self.clock.monotonic(), None)
        if self.spawned:
            self.spawn_node()
        parts = (STARTUP_PARTS if observe_startup else frozenset()) if parts is None else parts & STARTUP_PARTS
        self._startup_phase(first=bool(parts), measure=measure, diagnose=diagnose, initial=True, parts=parts)
        self.startup_window = (self.startup_window[0], self.clock.monotonic())
        self._startup_mark = None  # started: later failures are the cases' to explain

    def close(self) -> None:
        if self.liveness is not None:
            self.liveness.close()
        if self.node is not None:
            self.node.close()
            self.node = None
        if self.vehicle is not None:
            with contextlib.suppress(Exception):
                self.vehicle.close()
            self.vehicle = None
        if self.driver is not None:
            self.driver.close()
            self.driver = None
        if self.monitor is not None:  # on the run's clock: the simulator's is not the host's
            self.monitor.finish(self.clock.time_ns())

    def _start_vehicle(self) -> None:
        from mcp_conform.vehicle import start_for_node

        try:
            self.vehicle, self.mavlink_url = start_for_node(
                self.cfg.mavlink_transport, fix_withheld=True, on_frame=self._vehicle_frame,
                on_event=self._vehicle_event)
        except OSError as exc:
            raise SetupError(f"cannot start the simulated vehicle: {exc.strerror}") from None

    def _vehicle_event(self, event: Any) -> None:
        """The vehicle's events: to the run's monitor, and those it judges by (the link, the fix
        coming and going) to the capture too, so ``check`` judges with them."""
        t_ns = self.to_ns(event.t)
        if self.monitor is not None:
            self.monitor.vehicle_event(t_ns, event)
        if self.recorder is not None:
            for ev in link_events(event):
                with contextlib.suppress(Exception):
                    self.recorder.vehicle_event(ev.kind, t_ns, drone=self.target_id, detail=ev.detail)

    def _placeholders(self) -> dict[str, str]:
        return self._address_placeholders(self.target_id if self.target_id is not None else 1,
                                          self.mavlink_url if self.vehicle is not None else "")

    def _spawn(self) -> None:
        assert self.cfg.spawn is not None
        self.argv = fill_placeholders(self.cfg.spawn, self._placeholders())
        self.node = SpawnedNode(self.argv)
        if self.liveness is not None:
            self.liveness.reset(self.node)

    def restart(self) -> None:
        """Spawn mode: a fresh node for the next case (quick startup, nothing judged)."""
        if self.driver is not None:  # its Mission_Ready is the startup's to ACK (as in ``start``)
            self.driver.auto_ack = lambda d: d.action != _READY
        self.respawn()
        self._startup_phase(first=False)

    def respawn(self, grace: float = 2.0) -> None:
        """Spawn mode: the node closed and started again, before its startup phase (which the
        caller runs: ``restart`` the quick one; the fuzzer its own, then ``send_start_mission``)."""
        self.ended = self.needs_restart = False
        super().respawn(grace)

    def send_start_mission(self) -> None:
        """Start_Mission to the node after a startup phase run by the caller."""
        self._start_mission(False)

    def node_evidence(self) -> list[str]:
        """What the process said (command, exit, stdout and stderr tails), for evidence."""
        return self.node.evidence() if self.node is not None else []

    # ------------------------------------------------------------------ startup phase
    def _fail_setup(self, why: str) -> SetupError:
        """A setup error; in spawn mode it quotes the node (its exit, its own words); in the run's
        first startup, what the runner observed meanwhile (``detail``)."""
        node = self.node
        if node is not None and node.alive():  # it may be on its way out: give it a moment to say why
            with contextlib.suppress(Exception):
                node.proc.wait(timeout=0.2)
        from mcp_conform.harness.startup_report import startup_detail
        detail = startup_detail(self)
        if node is None:  # attach mode: what the runner knows fits the error's one line
            return SetupError(why + (f" ({'; '.join(detail)})" if detail else ""))
        details = node.details()
        if details["exit"]:  # "the node exited during startup" -> "the node exited with code 3 ..."
            head, _, rest = why.partition("the node exited")
            why = f"{head}the node {details['exit']}{rest}" if _ else f"{why} (the node {details['exit']})"
        return SpawnFailure(why, details, detail)

    @property
    def fix_hold(self) -> float:
        """How long the fix is withheld after the node connected (MCP-BLK-5's window)."""
        return max(2 * self.ack_window, 0.5)

    @property
    def startup_limit(self) -> float | None:
        """``--startup-timeout`` (never beyond the run's --timeout) when the run gives one: how
        long the first startup waits for the node's Mission_Ready, as the runner printed."""
        limit = self.cfg.extra.get("startup_timeout")
        return None if limit is None else min(float(limit), float(self.cfg.timeout))

    def startup_unanswered(self, why: str | None = None, probed: bool = False) -> SetupError:
        """A startup ended with no Mission_Ready (and no ACK of a probe, when ``probed``);
        ``why``: the caller's words (the --startup-timeout's alarm). A setup error that, in
        the run's first startup, says what the runner observed."""
        limit = self.startup_limit if self._startup_mark is not None and self.spawned else None
        if why is None:
            within = (f"the --startup-timeout of {limit:g} s" if limit is not None
                      else f"{self._startup_waited:.1f} s")
            why = (f"the node sent no Mission_Ready within {within}" if not probed else
                   f"target never answered: no Mission_Ready within {within} and no ACK of a "
                   f"WP_Off probe to ID {self.target_id if self.target_id is not None else 1}")
        return self._fail_setup(why)

    def startup_timed_out(self, timeout: float) -> SetupError:
        """The run's --timeout fell in the startup phase: a setup error, never case errors."""
        if self.spawned:
            return self._fail_setup(f"the node sent no Mission_Ready within the run's --timeout of {timeout:g} s")
        return self._fail_setup(f"target never answered within the run's --timeout of {timeout:g} s "
                                "(no Mission_Ready, no ACK of a probe)")

    def _startup_phase(self, first: bool, measure: bool = False, diagnose: bool = False,
                       initial: bool = False, parts: frozenset[str] = STARTUP_PARTS) -> None:
        """``initial``: the run's first startup (``start``), bounded by ``startup_limit``, explained
        when the node never announces (``startup_unanswered``); ``first``: its ``parts`` observed."""
        drv = self.driver
        assert drv is not None
        st = Startup(vehicle=self.vehicle is not None)
        mark = self.spawn_mark if self.spawned and self.spawn_mark is not None else drv.mark()  # from its start
        self._startup_mark = mark if initial else None
        self.startup_fix_at = None
        parts = parts if first else frozenset()
        withheld = bool(parts & {"copies", "wrong"})  # the parts that withhold Mission_Ready's ACK
        withhold = withheld or measure
        drv.auto_ack = lambda d: not (withhold and d.action == _READY)
        acking = drv.mark()  # the driver ACKs an unwithheld Mission_Ready from here, none before
        ready_limit = max(SPAWN_STARTUP_S, 4 * self.rto + 5.0)
        # the first startup waits --startup-timeout from the node's start (else the runner's limits)
        limit = self.startup_limit if initial else None
        deadline = None if limit is None else self.startup_window[0] + limit

        def left(default: float) -> float:
            return default if deadline is None else max(deadline - self.clock.monotonic(), 0.0)

        def is_ready(d: Datagram) -> bool:
            return d.action == _READY

        def ready_or_unreadable(d: Datagram) -> bool:
            return is_ready(d) or ((first or diagnose) and self._byte_order(d) is not None)

        if self.vehicle is not None and "fix" in parts:
            v = self.vehicle
            st.node_connected_to_vehicle = v.wait_for(lambda: v.connected or not self.alive(),
                                                      timeout=min(ready_limit, left(ready_limit))
                                                      ) and bool(v.connected)
            if not self.alive():
                raise self._fail_setup("the node exited during startup")
            if st.node_connected_to_vehicle:
                # hold the fix while a node that ignores it would already speak (MCP-BLK-5)
                hold = self.fix_hold
                drv.wait_for(is_ready, hold, mark)
            st.ready_before_fix = [d for d in drv.received(mark) if is_ready(d)]
            st.fix_given_at = self.startup_fix_at = self.clock.monotonic()
            v.give_fix()
        elif self.vehicle is not None:
            self.vehicle.give_fix()
        # spawn mode: the first startup waits --startup-timeout from the node's start; attach
        # mode: a node past its startup answers a probe instead
        wait = left(ready_limit) if self.spawned else 2.5 * self.rto + 1.0
        first_ready = drv.wait_for(ready_or_unreadable, wait, mark)
        self._startup_waited = wait
        if first_ready is None:
            withhold = False
            self.startup = st
            if not self.alive():
                raise self._fail_setup("the node exited before sending Mission_Ready")
            if self.spawned and (first or initial):
                raise self.startup_unanswered()
            probe = self._probe_alive()
            if not probe.acked:
                raise self.startup_unanswered(probed=True)
            st.reason = "no Mission_Ready was seen: the node was already past its startup phase"
            if first:
                self.startup = st
            self._start_mission(first)
            return
        if self.target_id is None and first_ready.header is not None:
            self.target_id = first_ready.header[1]
            if self.monitor is not None:
                self.monitor.node_id = self.target_id
            drv.attributor.peer_id = self.target_id
            self.record_node(self.target_id, complete=self.trace_complete)
        swapped = self._byte_order(first_ready) if first or diagnose else None
        if swapped is not None:
            # nothing the runner would read of this node's datagrams (its ACKs, seqs, IDs) is
            # what it wrote: no mission, the cases that read them are skipped (not_judged)
            self.unreadable = ("MCP-HDR-2", f"the node's header is not in network byte order: {swapped}")
            withhold = False
            st.reason = f"MCP-HDR-2: {self.unreadable[1]}"
            self.startup = st
            return
        if withheld:
            self._observe_retransmissions(st, first_ready, parts)
            if st.gave_up is not None:  # MCP-RTX-1 observed broken: cases on a restarted node
                restart_quick(self, st)
            elif needs_second_look(self, st):  # a retry limit or MCP-RTX-2's fault: a restart tells
                observe_again(self, st)
        elif measure:
            self._measure_period(first_ready)
        elif first_ready.header is not None and (first_ready.index < acking or (first or diagnose) and first_ready.msg is None):
            # the driver ACKs only what it decodes, from ``acking`` on: one that came before (sent as the node
            # started) or that it could not decode (a bad preamble) is ACKed as the observed startup ACKs it
            drv.send_ack(first_ready.header[2], dst=self.target_id if self.target_id is not None
                         else first_ready.header[1])
        withhold = False
        if first:
            st.observed = True  # (the fix's part alone: the first Mission_Ready ACKed at once)
            self.startup = st
        self._start_mission(first)

    def _byte_order(self, d: Datagram) -> str | None:
        """MCP-HDR-2: why ``d``, from the node's address, reads right only byte-swapped."""
        drv = self.driver
        if (d.header is None or not d.preamble_ok or self.target_id is None or drv is None
                or not from_node(d.addr, drv.target)):
            return None
        return byte_order_fault(self.target_id, d.header[1], d.header[3])

    def not_judged(self, rules: tuple[str, ...]) -> str | None:
        """Why a case verifying ``rules`` cannot be judged against this node, or None: its header
        cannot be read (``unreadable``) and the case reads more than raw bytes."""
        if self.unreadable is None or set(rules) <= FRAMING_RULES:
            return None
        rule, why = self.unreadable
        return (f"{rules[0]}: not judged: {why} ({rule}); every field this case would read of "
                "the node's datagrams is misread")

    def _measure_period(self, first_ready: Datagram) -> None:
        """The node's retransmission period from its first two Mission_Ready copies (the ACK
        withheld until the second, up to the description's timeout), then the ACK."""
        drv = self.driver
        assert drv is not None
        wait = max(self.rto, float(SPEC.params["timeout_s"])) * 1.5 + 1.0
        second = drv.wait_for(lambda d: d.action == _READY, wait - (self.clock.monotonic() - first_ready.t),
                              first_ready.index + 1)
        last = second or first_ready
        if second is not None:
            self.period = second.t - first_ready.t
        if last.header is not None:
            drv.send_ack(last.header[2], dst=last.header[1])

    def _observe_retransmissions(self, st: Startup, first_ready: Datagram,
                                 parts: frozenset[str] = STARTUP_PARTS) -> None:
        """Withhold the ACK (MCP-RTX-1/3, SEQ-2), then wrong ACKs (RTX-2), then the right one
        and the watch (RTX-1); the wrong ACKs' part alone: two copies (the node's period), no watch."""
        drv = self.driver
        assert drv is not None
        st.observed = True
        # ACKs go to the node's configured ID (its Mission_Ready's src when none was given)
        ready_src = self.target_id if self.target_id is not None else (
            first_ready.header[1] if first_ready.header else 1)
        # copies are awaited at --rto's pace, or at the node's own once two show it: a node
        # slower than --rto says (the description's 5 s against --rto 0.3) is judged by what it
        # does, not failed for copies that were not due yet (issue 18 item 10); a second copy
        # is awaited up to the description's timeout
        slowest = max(self.rto, float(SPEC.params["timeout_s"]))
        i = first_ready.index
        wanted = MIN_COPIES if "copies" in parts else 2
        seen = None  # when the node was last seen running (a lower bound of its exit)
        while True:
            now = self.clock.monotonic()
            seen = now if self.alive() else seen
            copies = [d for d in drv.received(i) if d.action == _READY]
            if len(copies) >= 2:
                deadline = first_ready.t + MIN_COPIES * max(self.rto, copies[1].t - copies[0].t) * 1.5 + 1.0
            else:
                deadline = first_ready.t + max(MIN_COPIES * self.rto, slowest) * 1.5 + 1.0
            if len(copies) >= wanted or now >= deadline or seen != now:
                break
            drv.wait_for(lambda d: d.action == _READY, POLL_S, drv.mark())
        st.copies = [d for d in drv.received(i) if d.action == _READY]
        self.period = st.period()
        if "copies" in parts:
            self.timing = timing_note(st.period(), self.rto, len(st.copies),
                                      "the node is judged by its copies' own spacing")
            st.gave_up = gave_up(self, st, seen, None if seen == now else now)  # gone: no wrong ACKs, no watch
        gaps = st.gaps()
        gap = sorted(gaps)[len(gaps) // 2] if gaps else self.rto
        if "wrong" in parts and st.gave_up is None:
            self._send_wrong_acks(st, i, ready_src, gap)
        latest = [d for d in drv.received(i) if d.action == _READY][-1]  # (an MR: its header was read)
        rseq = latest.header[2] if latest.header else 0
        st.right_ack = drv.send_ack(rseq, dst=ready_src)
        if "copies" in parts and st.gave_up is None:
            st.stop_watch = max(self.ack_window, 1.5 * gap)
            grace = 0.05
            right = st.right_ack
            st.watch_after_right_ack(lambda: [d for d in drv.received(i) if d.action == _READY
                                              and d.t > right.t + grace], gap, self.clock.sleep)
        st.others_while_waiting = others_while_waiting(self, i, drv.mark_before(st.right_ack))  # MCP-BLK-1

    def _send_wrong_acks(self, st: Startup, i: int, ready_src: int, gap: float) -> None:
        """MCP-RTX-2: an ACK with the wrong seq and one with the right seq from the wrong
        source, then a copy awaited (2.5 of the node's periods)."""
        drv = self.driver
        assert drv is not None
        last = st.copies[-1]
        seq = last.header[2] if last.header else 0
        wrong_src = (ready_src + 0x100) & 0xFFFF or 0x7777
        if wrong_src in (MANAGER_ID, self.cfg.broadcast_id, ready_src):
            wrong_src = 0x7777
        st.wrong_acks = [drv.send_ack((seq + 0x8000) & 0xFFFF, dst=ready_src),
                         drv.send_ack(seq, dst=ready_src, src=wrong_src)]
        after = drv.mark()
        st.wrong_ack_wait = max(2.5 * gap, 0.3) + 0.2
        st.copy_after_wrong_acks = drv.wait_for(lambda d: d.action == _READY, st.wrong_ack_wait, after)

    def _start_mission(self, first: bool) -> None:
        drv = self.driver
        assert drv is not None
        if not self.alive():  # gone before it is sent (its copies given up): not "after Start_Mission"
            raise self._fail_setup("the node exited before Start_Mission was sent" + drv.last_heard(self.spawn_mark or 0))
        sent = drv.send(Action.START_MISSION, None, self.target_id)
        ex = drv.exchange(sent, rto=self.rto, copies=int(SPEC.params["max_ack_copies"]), tail=self.ack_window)
        if first:
            self.start_mission = ex  # judged by MCP-BLK-4; restarts do not replace it
        if not ex.acked and not self.alive():
            raise self._fail_setup("the node exited after Start_Mission was sent")
        if self.liveness is not None:
            self.liveness.enable()  # it receives from now on: watch it

    def _probe_alive(self) -> Exchange:
        drv = self.driver
        assert drv is not None
        sent = drv.send(Action.WP_OFF, None, self.target_id if self.target_id is not None else 1)
        return drv.exchange(sent, rto=self.rto, copies=int(SPEC.params["max_ack_copies"]))

    # ------------------------------------------------------------------ per case
    def before_case(self) -> None:
        """Make sure a live, started node is there (restart in spawn mode)."""
        self._note_loss()
        super().before_case()  # a node lost earlier: TargetLost
        if self.spawned and (self.needs_restart or self.ended or not self.alive()):
            self.restart()
        elif self.ended:
            raise TargetLost("the node's mission has ended (End_Mission was sent)")
        assert self.driver is not None
        self.driver.quiet(gap=0.05, limit=min(1.0, self.ack_window))

    def after_case(self, node_silent: bool) -> None:
        died = self.node is not None and not self.node.alive()
        if self.spawned and (died or node_silent):
            self.needs_restart = True
        elif not self.spawned and node_silent and self.lost is None:
            self.lost = "the node went silent after an earlier case's input"
        self._note_loss()
        if self.ended and self.liveness is not None:
            self.liveness.enabled = False  # after End_Mission a node may stop receiving

    def _note_loss(self) -> None:
        """A loss the watcher declared: attach mode ends the run's cases, spawn restarts."""
        lost = self.liveness.lost if self.liveness is not None else None
        if lost is None:
            return
        if self.spawned:
            self.needs_restart = True
        elif self.lost is None:
            self.lost = f"the node was lost during an earlier case ({lost.reason})"

    def declare_not_live(self, why: str) -> None:
        """A case found the node not live (no answer to a proof-of-life probe)."""
        if self.spawned:
            self.needs_restart = True
        elif self.lost is None:
            self.lost = why

    def _vehicle_frame(self, t: float, direction: str, conn: int, raw: bytes) -> None:
        """The vehicle's frame tap: both directions of the autopilot link into the capture
        (/mavlink; "rx" the vehicle received it from the node, "tx" it sent it)."""
        if self.recorder is not None:
            with contextlib.suppress(Exception):
                self.recorder.mavlink(direction, raw, self.to_ns(t), drone=self.target_id)
        if self.monitor is not None:  # and to the trace monitor
            self.monitor.vehicle_frame(self.to_ns(t), direction, raw)

    def flush_vehicle_frames(self) -> None:
        """Kept for callers (a no-op): the vehicle's frames reach the capture as they pass (its tap)."""

    # ------------------------------------------------------------------ case API
    def case_ending(self, ctx: Any, outcome: str) -> None:
        """Before the case's end mark: a node the case left unfit is restarted before the next
        one (spawn mode), a silent one lost (attach mode)."""
        if ctx.restart_if_failed and outcome in ("failed", "warned", "error") and self.spawned:
            self.needs_restart = True
        self.after_case(ctx.node_silent)

"""The Mission Manager under test over a whole run (``--role manager``): attach, spawn, or
the embedded reference manager.

The runner listens where drones listen (default: all addresses, port 7890, so the manager's
IP broadcasts reach it) and plays every drone of ``--drones`` from that one socket
(:mod:`harness.drone_players`). It hands the manager a QGC WPL 110 waypoint file of
its own (``{waypoints}``; varied from the seed: several items, non-trivial coordinates,
altitudes, commands and frames) unless ``--waypoints FILE`` names one, and for challenge 3
an obstacles file (``{obstacles}``).

A manager runs one mission and is done, so every scenario that needs a fresh mission
starts a fresh manager (spawn mode and the embedded default). The main scenario runs at
start; a manager that sends nothing at all in it never answered (a setup error, exit 2),
while one that goes on with the mission without ACKing the drones' Mission_Ready is judged
on what it did (MCP-ACK-1 fails). The other scenario a run's cases judge (``overlap``, set
by the runner: the silent drone's) runs beside the main one, on a manager instance of its
own (``harness.manager_side``: its own ports and drones' socket, its traffic handed to the
capture and the monitor as its own session when its case asks for it); with ``overlap``
empty (``--serial``), or a spawn command that cannot give a second instance ports of its
own, it runs when the first case that needs it does. In attach mode the manager is already
running and only its one mission can be observed: the other scenarios are SKIPPED.

Each scenario's mission is a session of its own, of the run's trace monitor
(``judge.run_monitor.SessionMonitors``) and of the capture (``McapRecorder.begin_segment``,
with the node's record and the mission the manager was handed), judged as a complete trace:
the runner plays every drone, so its socket is party to every exchange. ``mcp-capture check``
judges the capture's sessions the same way.

The run's clock and the drones' socket's far end are the host's by default (``harness.clock``,
``harness.transport``); ``sim.manager_runner`` runs the same session on virtual time against a
manager model (``_spawn``, ``new_side``, ``backlog`` overridden). Before a scenario's session
begins, what the previous scenario's manager sent is read (the socket's backlog, then a quiet
gap), so a loaded receiver never tells the next session of it.
"""

from __future__ import annotations

import contextlib
import random
import struct
import tempfile
from pathlib import Path
from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import TargetDriver
from mcp_conform.harness.drone_players import DronePlayers, Mission
from mcp_conform.harness.errors import Inconclusive, SetupError
from mcp_conform.harness.interrupts import INTERRUPTS
from mcp_conform.harness.manager_side import SideScenario, side_by_side_why_not
from mcp_conform.harness.mission_script import MissionScript
from mcp_conform.harness.procs import SPAWN_STARTUP_S
from mcp_conform.harness.session_base import (
    EMBEDDED_RTO,
    MANAGER_ID,
    DatagramSessionBase,
    SpawnedNode,
    fill_placeholders,
    free_port,
    reference_command,
)
from mcp_conform.harness.transport import Transport
from mcp_conform.judge.run_monitor import MISSION_METADATA, SessionMonitors, mission_metadata
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import MissionItem
from mcp_conform.spec.profiles import pick
from mcp_conform.traceio.recorder import NODE_METADATA, RUN_DELAY_METADATA, run_delay_metadata

DRONE_PORT = int(SPEC.protocol["ports"]["drone"])
MANAGER_PORT = int(SPEC.protocol["ports"]["manager"])
#: The embedded reference manager's retry limit: enough for the copies the main scenario
#: withholds, few enough that the silent drone's scenario ends quickly.
EMBEDDED_RETRIES = 12

# MAV_CMDs and MAV_FRAMEs the generated missions draw from (all defined by MAVLink)
_COMMANDS = (16, 17, 19, 21, 22, 178, 82)  # WAYPOINT, LOITER_UNLIM, LOITER_TIME, LAND, TAKEOFF, DO_CHANGE_SPEED, SPLINE
_FRAMES = (0, 3, 10)  # GLOBAL, GLOBAL_RELATIVE_ALT, GLOBAL_TERRAIN_ALT


def embedded_command() -> str:
    """The reference manager, as the runner spawns it for the embedded default."""
    return reference_command(*pick("mcp", "manager"), "--challenge {challenge} --drones {drones} "
                             "--waypoints {waypoints} --obstacles {obstacles} --listen {target_host}:{target_port} "
                             f"--target {{listen_host}}:{{listen_port}} --rto {EMBEDDED_RTO} --retries {EMBEDDED_RETRIES}")


def _f32(x: float) -> float:
    return float(struct.unpack("<f", struct.pack("<f", x))[0])


def make_mission_items(seed: int, count: int | None = None) -> tuple[Any, ...]:
    """Waypoints varied by ``seed``: 3-6 items somewhere on Earth, varied commands, frames,
    altitudes and parameters (each value exact in float32 after 6 decimals)."""
    rnd = random.Random(seed)
    n = count if count is not None else rnd.randint(3, 6)
    lat0, lon0 = rnd.uniform(-70, 70), rnd.uniform(-170, 170)
    items = []
    for i in range(n):
        cmd = rnd.choice(_COMMANDS)
        params = [round(rnd.uniform(0, 30), 2) if rnd.random() < 0.6 else 0.0 for _ in range(4)]
        items.append(MissionItem(
            param1=params[0], param2=params[1], param3=params[2], param4=params[3],
            x=round(lat0 + rnd.uniform(-0.02, 0.02), 6), y=round(lon0 + rnd.uniform(-0.02, 0.02), 6),
            z=round(rnd.uniform(5, 120), 2), seq=i, command=cmd, target_system=0, target_component=0,
            frame=rnd.choice(_FRAMES), current=1 if i == 0 else 0, autocontinue=1))
    return tuple(items)


class ManagerSession(DatagramSessionBase):
    """One run against one Mission Manager (see the module docstring)."""

    first_awaited = "an ACK of the drones' Mission_Ready"

    def __init__(self, cfg: RunConfig, recorder: Any = None, *, clock: Clock = REAL,
                 transport: Transport | None = None) -> None:
        self.cfg = cfg
        self.recorder = recorder
        #: the run's clock and the drones' socket's far end (``harness.clock``,
        #: ``harness.transport``): the host's by default, the simulator's in ``sim.manager_runner``
        self.clock, self.transport = clock, transport
        if cfg.embedded:
            cfg.spawn = cfg.spawn or embedded_command()
        self.driver: TargetDriver | None = None
        self.players: DronePlayers | None = None
        self.node: SpawnedNode | None = None
        self.vehicle = None
        self.argv: list[str] = []
        self.target_id = MANAGER_ID
        self.target_desc = ""
        self.missions: dict[str, Mission] = {}
        self.unavailable: dict[str, str] = {}
        self.lost: str | None = None
        self.ended = False  # a manager's mission ends within a scenario, never between cases
        self.restarts = 0
        self._tmp = tempfile.TemporaryDirectory(prefix="mcp-conform-manager-")
        self.waypoints_path = ""
        self.obstacles_path = ""
        self.waypoints: tuple[Any, ...] | None = None
        self.obstacles: tuple[Any, ...] | None = None
        self.monitor: SessionMonitors | None = None  # the trace monitor, one session per mission
        #: scenarios to run beside the main one, each on a manager instance of its own (set by
        #: the runner from the cases it will run; empty: one after another, ``--serial``)
        self.overlap: set[str] = set()
        self.side: dict[str, SideScenario] = {}  # running beside the main one

    # ------------------------------------------------------------------ facts
    @property
    def startup(self) -> Any:
        return None

    @property
    def ready_limit(self) -> float:
        """How long the first Mission_Ready of a scenario is retransmitted awaiting the
        manager's ACK (a fresh manager may still be starting)."""
        return max(SPAWN_STARTUP_S, 4 * self.rto + 5.0) if self.spawned else 2.5 * self.rto + 1.0

    @property
    def startup_note(self) -> tuple[str, str]:  # type: ignore[override]  # NodeBase's default; the runner only reads it
        """What the start of the run does, for the terminal's header: (line, status)."""
        cfg = self.cfg
        who = "starts the manager" if self.spawned else "attaches to the running manager"
        first = cfg.drones[0]
        line = (f"startup: the runner {who} and plays drones {', '.join(map(str, cfg.drones))}: drone {first} "
                f"announces Mission_Ready, retransmitted every {self.rto:g} s (--rto) until the manager ACKs it "
                f"(up to {self.ready_limit:g} s), then the others; the main mission is watched to its End_Mission")
        if "silent" in self.overlap:
            why = self.side_why_not()
            line += ("; the silent drone's scenario runs beside it, on a second manager instance with ports of "
                     "its own" if why is None else f"; the silent drone's scenario runs after it ({why})")
        return line, "startup: the drones' Mission_Ready and the main mission"

    # ------------------------------------------------------------------ start / stop
    def start(self) -> None:
        """Open the drones' socket and run the main scenario (a setup error when the manager
        sends nothing at all)."""
        self.open()
        self._start_side()
        self.mission("main")
        if "main" not in self.missions:
            raise SetupError(self.unavailable.get("main", "the manager never answered"))

    def open(self) -> None:
        """The drones' socket, the mission files and the drone players (nothing spawned)."""
        cfg = self.cfg
        if self.spawned:
            listen = cfg.listen or ("", 0)
            target = cfg.target or ("127.0.0.1", free_port())
        else:
            if cfg.target is None:
                raise SetupError("no --target and no --spawn")
            listen = cfg.listen or ("", DRONE_PORT)
            target = cfg.target
        self._mission_files()
        self.driver = TargetDriver(target, listen, our_id=MANAGER_ID, clock=self.clock, transport=self.transport)
        self.driver.auto_ack = lambda d: False  # the drone players answer (DronePlayers)
        try:
            self.driver.open()
        except OSError as exc:
            raise SetupError(str(exc)) from None
        self.driver.alive = self.alive
        # the capture; the trace monitor judges the manager's traffic (the drones are the
        # runner's), one mission at a time: each scenario starts a fresh manager, and its
        # mission is a session of the capture of its own, complete (the runner plays every
        # drone: its socket is party to every exchange of the mission), judged so offline too;
        # both hear what came before they were added (an attached manager already speaks)
        self.monitor = SessionMonitors(rto=self.cfg.rto, ack_window=self.cfg.ack_window,
                                       broadcast_id=self.cfg.broadcast_id, node_id=MANAGER_ID,
                                       node_addr=target, complete=self.trace_complete,
                                       challenge=cfg.challenge, waypoints=self._handed_items(),
                                       rto_declared=cfg.rto_declared)
        self.monitor.listen = self.driver.listen
        self.observe_run(target, MANAGER_ID, complete=self.trace_complete, judge=False,
                         also=(self.monitor.observe,))
        self.players = DronePlayers(self.driver, cfg.drones, 1000 + cfg.seed % 5000)
        self.driver.on_datagram = self.players.on_datagram
        self.target_desc = f"{target[0]}:{target[1]}"

    def _handed_items(self) -> tuple[Any, ...] | None:
        """What the manager was handed to send (MCP-FLOW-4/5/6): the obstacles for challenge
        3, else the waypoints (None: unknown, attach mode without --waypoints)."""
        return self.obstacles if self.cfg.challenge == 3 else self.waypoints

    def _mission_files(self) -> None:
        from mcp_conform.spec.mission import WaypointFileError, load_waypoints, save_waypoints

        tmp = Path(self._tmp.name)
        cfg = self.cfg
        if cfg.waypoints:
            self.waypoints_path = cfg.waypoints
        else:
            self.waypoints_path = str(tmp / "mission.waypoints")
            save_waypoints(self.waypoints_path, make_mission_items(cfg.seed))
        self.obstacles_path = str(tmp / "obstacles.waypoints")
        save_waypoints(self.obstacles_path, make_mission_items(cfg.seed + 1))
        try:
            self.waypoints = load_waypoints(self.waypoints_path)
            obstacles = load_waypoints(self.obstacles_path)
        except WaypointFileError as exc:
            raise SetupError(f"--waypoints: {exc}") from None
        spawn = cfg.spawn or ""
        if "{obstacles}" in spawn:
            self.obstacles = obstacles
        elif "{waypoints}" in spawn or (not self.spawned and cfg.waypoints):
            self.obstacles = self.waypoints  # one file handed over: its items are the obstacles
        if not self.spawned and not cfg.waypoints:
            self.waypoints = None  # attach mode without --waypoints: the mission is unknown

    def close(self) -> None:
        for side in self.side.values():
            side.close()
        self.side.clear()
        if self.node is not None:
            self.node.close()
            self.node = None
        if self.driver is not None:
            self.driver.close()
            self.driver = None
        if self.monitor is not None:
            self.monitor.finish()
        with contextlib.suppress(OSError):
            self._tmp.cleanup()

    def _placeholders(self) -> dict[str, str]:
        return {**self._address_placeholders(MANAGER_ID, ""),
                "drones": ",".join(map(str, self.cfg.drones)), "challenge": str(self.cfg.challenge),
                "waypoints": self.waypoints_path, "obstacles": self.obstacles_path}

    def _spawn(self) -> None:
        assert self.cfg.spawn is not None
        self.argv = fill_placeholders(self.cfg.spawn, self._placeholders())
        self.node = SpawnedNode(self.argv)

    def node_evidence(self) -> list[str]:
        if self.node is None:
            return []
        ev = []
        if not self.node.alive():
            ev.append(f"manager process exited with code {self.node.returncode}")
        tail = self.node.output_tail()
        if tail:
            ev.append("manager output (last lines):\n    " + tail.replace("\n", "\n    "))
        return ev

    # ------------------------------------------------------------------ scenarios
    def mission(self, kind: str) -> Mission:
        """The record of scenario ``kind`` (``main`` or ``silent``), run on first use (or
        already running beside the main one: then awaited)."""
        if kind in self.missions:
            return self.missions[kind]
        if kind in self.unavailable:
            raise Inconclusive(self.unavailable[kind])
        side = self.side.pop(kind, None)
        if side is not None:
            return self._side_mission(side)
        if self.missions and not self.spawned:
            why = (f"the {kind} scenario needs a fresh mission, and in attach mode the manager runs "
                   "one mission only (use --spawn to let the runner restart it)")
            self.unavailable[kind] = why
            raise Inconclusive(why)
        if kind == "silent" and len(self.cfg.drones) < 2:
            why = "a silent drone's effect on the others needs at least two drones (--drones)"
            self.unavailable[kind] = why
            raise Inconclusive(why)
        assert self.driver is not None and self.players is not None
        m = Mission(kind, self.cfg.drones, self.cfg.challenge, self.waypoints, self.obstacles)
        script = MissionScript(self.driver, self.players, m, rto=self.rto, ack_window=self.ack_window,
                               broadcast_id=self.cfg.broadcast_id, seed=self.cfg.seed, alive=self.alive,
                               ready_limit=self.ready_limit, backlog=self.backlog())
        # what the stopped manager of the scenario before sent is read, and told, before this
        # scenario's session begins (a loaded receiver read a last Start_Mission of the main
        # mission into the silent drone's session: a false MCP-BLK-2 there)
        script.drain()
        self.driver.quiet(gap=0.05, limit=min(1.0, self.ack_window))
        self._begin_session(kind)
        if self.spawned:
            self.respawn()
        self.players.reset(m)
        if kind == "main":
            self.players.withhold_first_start = True
        self.driver.quiet(gap=0.05, limit=min(1.0, self.ack_window))
        ok = script.run_main() if kind == "main" else script.run_silent()
        if self.node is not None:
            m.exit_code = self.node.returncode
            m.output = self.node.output_tail(40)
            self.node.stop()
            if m.exit_code is None:
                m.notes.append("the manager was still running at the end of the scenario (stopped)")
        return self._settle(m, ok, self.clock.monotonic() - m.t0)

    def _settle(self, m: Mission, ok: bool, elapsed: float) -> Mission:
        """The scenario's record kept, or why the manager never answered in it."""
        kind = m.kind
        if not ok:
            first = next(iter(m.ready.values()), None)
            unacked = (f" (drone {first.first.src}'s Mission_Ready, seq {first.seq}: {len(first.copies)} copies, "
                       "no ACK)" if first is not None else "")
            why = (f"the manager never answered: nothing from it in {elapsed:.1f} s{unacked}"
                   + (f"; manager process exited with code {m.exit_code}" if m.exit_code is not None else ""))
            self.unavailable[kind] = why
            raise Inconclusive(why) if kind != "main" else SetupError(why)
        if kind == "main":
            from mcp_conform.harness.manager_monitor import monitor_mission

            assert self.driver is not None
            m.monitor, _, m.monitor_trace = monitor_mission(
                m, self.driver.sent(), self.driver.listen, rto=self.rto, ack_window=self.ack_window,
                broadcast_id=self.cfg.broadcast_id)
        self.missions[kind] = m
        return m

    # ------------------------------------------------------------------ side by side (issue 23)
    def _start_side(self) -> None:
        """Start each scenario of ``self.overlap`` on a manager instance of its own, beside
        the main mission (``harness.manager_side``); where it cannot, it runs after it."""
        for kind in sorted(self.overlap):
            if kind != "silent" or kind in self.side:
                continue
            if self.side_why_not() is not None:
                continue  # it runs after the main one (the header says why)
            side = self.new_side(kind)
            try:
                side.start()
            except OSError:
                side.close()
                continue  # no socket of its own: it runs after the main one
            self.side[kind] = side

    def backlog(self) -> Any:
        """What tells whether the drones' socket holds unread datagrams (None: the kernel's
        receive queue, ``harness.mission_script``)."""
        return None

    def side_why_not(self) -> str | None:
        """Why the silent scenario cannot run beside the main one (None: it can)."""
        return side_by_side_why_not(self.cfg.spawn, self.cfg.drones)

    def new_side(self, kind: str) -> SideScenario:
        """Scenario ``kind`` on a manager instance of its own (not started yet): a second
        process of the ``--spawn`` command on ports of its own."""
        listen = self.cfg.listen[0] if self.cfg.listen else ""
        target_host = self.cfg.target[0] if self.cfg.target else "127.0.0.1"
        return SideScenario(kind, spawn=self.cfg.spawn or "", placeholders=self._placeholders(),
                            listen_host=listen, target_host=target_host, drones=self.cfg.drones,
                            challenge=self.cfg.challenge, waypoints=self.waypoints, obstacles=self.obstacles,
                            seq_base=1000 + self.cfg.seed % 5000, rto=self.rto, ack_window=self.ack_window,
                            broadcast_id=self.cfg.broadcast_id, seed=self.cfg.seed,
                            ready_limit=self.ready_limit, clock=self.clock)

    def _side_mission(self, side: SideScenario) -> Mission:
        """The scenario that ran beside the main one: awaited, then its traffic written to the
        capture and fed to the run's monitor as its own session, with its instance's address."""
        try:
            m = side.join()
        finally:
            self._begin_session(side.kind, address=side.target, held=True)
            if self.monitor is not None and self.monitor.current is not None:
                self.monitor.current.listen = side.listen  # this instance's drones' socket
                self.monitor.current.node_addr = side.target
            observers: list[Any] = [self.monitor.observe_held] if self.monitor is not None else []
            rec = self.recorder
            if rec is not None:
                def record(direction: str, data: bytes, addr: Any, t_ns: int, run_delay: int | None = None) -> None:
                    with INTERRUPTS.held():
                        rec.datagram(direction, data, addr, t_ns, run_delay=run_delay, local=side.listen)
                observers.insert(0, record)
            monitor = self.monitor

            def stopped(t_ns: int, run_delay_ns: int) -> None:
                """The instance's stop, told to its session as the main instance's is
                (``record_run_delay``): the run delay read at that stop, to the capture
                (``RUN_DELAY_METADATA``) and the run's monitor; the session ends there, not at
                the run's later case marks (a false MCP-RTX-1 "none for 2.5 s" of the copies
                the stop cut short)."""
                if rec is not None:
                    with INTERRUPTS.held(), contextlib.suppress(Exception):
                        rec.add_metadata(RUN_DELAY_METADATA, run_delay_metadata(MANAGER_ID, run_delay_ns, t_ns))
                if monitor is not None:
                    monitor.run_delay(t_ns, MANAGER_ID, run_delay_ns)
            # the main driver's datagrams (its manager may still send) wait until the held
            # traffic is told: the capture and the monitor get one order (one judge); and the
            # instance's stop, where its session ends (judge.run_monitor.session_end)
            if self.driver is not None:
                with self.driver.notify_lock:
                    side.replay(observers, stopped)
            else:
                side.replay(observers, stopped)
            side.close()
        return self._settle(m, side.ok, side.elapsed)

    def _begin_session(self, kind: str, address: tuple[str, int] | None = None, held: bool = False) -> None:
        """Scenario ``kind``'s mission is a session of the capture and of the run's monitor
        of its own (``McapRecorder.begin_segment``, :class:`SessionMonitors`), named by the
        scenario, with the node under test's record (complete: the runner plays every drone);
        ``address``: where that scenario's manager received (default: the main one's);
        ``held``: it ran beside on sockets of its own, its traffic told now (the driver's
        datagrams stamped from now on stay the main scenario's, as those stamped before now
        and told late do: ``SessionMonitors``)."""
        if self.monitor is not None:
            self.monitor.begin(kind, self.clock.time_ns(), held=held)
        address = address or self.node_address
        if self.recorder is not None and address is not None:  # the capture (McapRecorder, or the runner's tee)
            with contextlib.suppress(Exception):
                complete = "true" if self.trace_complete else "false"
                self.recorder.begin_segment(kind, [(NODE_METADATA, {"id": MANAGER_ID, "address": f"{address[0]}:{address[1]}",
                                              "complete": complete}),
                             (MISSION_METADATA, mission_metadata(self.cfg.challenge, self._handed_items()))])

    # ------------------------------------------------------------------ case API
    def case_started(self, ctx: Any) -> None:
        """The case's bounds on the run's monitor too (its violations are told by case)."""
        if self.monitor is not None:
            self.monitor.mark(ctx.start_ns)

    def case_ending(self, ctx: Any, outcome: str) -> None:
        if self.monitor is not None:
            self.monitor.mark(ctx.end_ns)

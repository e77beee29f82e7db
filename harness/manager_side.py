"""A scenario on a manager instance of its own, run beside the main mission
(``--role manager``, spawn mode and the embedded default; issue 23).

The silent drone's scenario (:meth:`harness.drone_players.MissionScript.run_silent`)
mostly waits: the manager retransmits to a drone that never answers until it gives up or
the watch ends. Rather than after the main mission, it runs at the same time on a second
manager process with ports of its own — its own receive port (``{target_port}``) and its
own drones' socket (``{listen_port}``, a second :class:`~harness.driver.TargetDriver` with
its own :class:`~harness.drone_players.DronePlayers`) — so every datagram it sends
reaches its own scenario's socket and no other: which instance a datagram belongs to is
given by the socket it arrived on, exactly, whatever the manager's source ports or its
destination host (the broadcast address included).

The scenario's traffic is held as observed (kernel receive times, the node's run delay),
and so is the instance's stop (its run delay read as it is stopped, as the main instance's is:
``DatagramSessionBase.record_run_delay``); when its case asks for the scenario
(``ManagerSession.mission``), they are written to the capture and fed to the run's trace
monitor as the scenario's own session, with that instance's address, the session ending at
that stop (``judge.run_monitor.session_end``: not at the run's later case marks): the same
session, the same records and the same verdicts as when it ran after the main mission
(``--serial``, or a spawn command without ``{target_port}`` and ``{listen_port}``, where two
instances would share ports).

The scenario runs on the session's clock (``harness.clock``: a thread it starts, its waits);
``transport``, ``target``, ``spawn_node`` and ``backlog`` put its drones' socket, its manager's
address, its manager and the socket's unread datagrams elsewhere than a UDP socket, a free port,
a process and the kernel's receive queue (the simulator's:
``sim.manager_runner``, a manager model on a link of its own).
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.driver import TargetDriver
from mcp_conform.harness.drone_players import MANAGER_ID, DronePlayers, Mission
from mcp_conform.harness.mission_script import MissionScript
from mcp_conform.harness.run_delay import run_delay_ns
from mcp_conform.harness.session_base import SpawnedNode, fill_placeholders, free_port
from mcp_conform.harness.transport import Transport

__all__ = ["SideScenario", "side_by_side_why_not"]

#: the placeholders a spawn command needs for a second instance on ports of its own
NEEDED = ("{target_port}", "{listen_port}")


def _process_run_delay(node: Any) -> int | None:
    """A spawned manager's run delay now (D-7, ``harness.run_delay``)."""
    return run_delay_ns(node.proc.pid)


def side_by_side_why_not(spawn: str | None, drones: tuple[int, ...]) -> str | None:
    """Why the silent scenario cannot run beside the main one (None: it can)."""
    if spawn is None:
        return "attach mode: the manager runs one mission only"
    if len(drones) < 2:
        return "a silent drone's effect on the others needs at least two drones"
    missing = [p for p in NEEDED if p not in spawn]
    if missing:
        return (f"the --spawn command has no {' and no '.join(missing)}: a second instance would share the "
                "first one's ports")
    return None


class SideScenario:
    """Scenario ``kind`` (``silent``) on a manager instance of its own, in a thread (see the
    module docstring). ``start`` opens its socket and spawns its manager; ``join`` returns
    the record and whether the manager answered; ``replay`` hands the held traffic on."""

    def __init__(self, kind: str, *, spawn: str, placeholders: dict[str, str], listen_host: str,
                 target_host: str, drones: tuple[int, ...], challenge: int, waypoints: Any, obstacles: Any,
                 seq_base: int, rto: float, ack_window: float, broadcast_id: int, seed: int,
                 ready_limit: float, clock: Clock = REAL, transport: Transport | None = None,
                 target: tuple[str, int] | None = None,
                 spawn_node: Callable[[list[str]], Any] = SpawnedNode,
                 run_delay_of: Callable[[Any], int | None] = _process_run_delay,
                 backlog: Callable[[], bool] | None = None) -> None:
        self.kind = kind
        self.clock = clock
        self._spawn = spawn
        self._placeholders = placeholders
        self.mission = Mission(kind, drones, challenge, waypoints, obstacles)
        self._script_kw = dict(rto=rto, ack_window=ack_window, broadcast_id=broadcast_id, seed=seed,
                               ready_limit=ready_limit, backlog=backlog)
        target = target or (target_host, free_port(target_host or "127.0.0.1"))
        self.driver = TargetDriver(target, (listen_host, 0), our_id=MANAGER_ID, clock=clock, transport=transport)
        self.players = DronePlayers(self.driver, drones, seq_base)
        self._spawn_node = spawn_node
        self._run_delay_of = run_delay_of
        self.node: Any = None  # a SpawnedNode (or what ``spawn_node`` made)
        self.ok = False
        self.error: BaseException | None = None
        self.elapsed = 0.0  # from the scenario's start to the end of its watch
        #: (direction, data, peer, t_ns, run delay) as observed; ("stop", b"", None, t_ns, run
        #: delay): the instance stopped (:meth:`_hold_stop`)
        self._held: list[tuple[str, bytes, Any, int, int | None]] = []
        self._lock = threading.Lock()
        self._stop = clock.event()
        self._thread: Any = None

    @property
    def target(self) -> tuple[str, int]:
        """Where this instance receives (its ``{target_host}:{target_port}``)."""
        return self.driver.target

    @property
    def listen(self) -> tuple[str, int]:
        return self.driver.listen

    def alive(self) -> bool:
        return not self._stop.is_set() and self.node is not None and self.node.alive()

    def _run_delay(self) -> int | None:
        return self._run_delay_of(self.node) if self.node is not None else None

    def _hold(self, direction: str, data: bytes, addr: Any, t_ns: int, run_delay: int | None = None) -> None:
        with self._lock:
            self._held.append((direction, bytes(data), addr, t_ns, run_delay))

    def _hold_stop(self) -> None:
        """The instance is being stopped (its ``before_stop``): its run delay read a last time
        and held with the time of the stop (none readable: nothing, as for the main instance)."""
        ns = self._run_delay()
        if ns is not None:
            self._hold("stop", b"", None, self.clock.time_ns(), ns)

    # ------------------------------------------------------------------ running
    def start(self) -> None:
        """Open the scenario's socket, spawn its manager, run the scenario in a thread
        (OSError: the socket could not be opened; nothing is left running)."""
        drv = self.driver
        drv.auto_ack = lambda d: False  # the drone players answer
        drv.alive = self.alive
        drv.run_delay = self._run_delay
        drv.add_observer(self._hold)
        drv.on_datagram = self.players.on_datagram
        drv.open()
        host = drv.listen[0] or "127.0.0.1"
        values = {**self._placeholders, "target_host": drv.target[0], "target_port": str(drv.target[1]),
                  "listen_host": "127.0.0.1" if host == "0.0.0.0" else host, "listen_port": str(drv.listen[1])}
        self.players.reset(self.mission)
        self.node = self._spawn_node(fill_placeholders(self._spawn, values))
        self.node.before_stop = self._hold_stop
        self._thread = self.clock.start_thread(self._run, f"mcp-conform-{self.kind}")

    def _run(self) -> None:
        m = self.mission
        t0 = self.clock.monotonic()
        try:
            script = MissionScript(self.driver, self.players, m, alive=self.alive, **self._script_kw)  # type: ignore[arg-type]
            self.ok = script.run_silent()
        except BaseException as exc:  # noqa: BLE001 - handed to the case that asks (join)
            self.error = exc
        finally:
            self.elapsed = self.clock.monotonic() - t0
            node = self.node
            if node is not None:
                m.exit_code = node.returncode
                m.output = node.output_tail(40)
                node.stop()
                if m.exit_code is None:
                    m.notes.append("the manager was still running at the end of the scenario (stopped)")

    def join(self) -> Mission:
        """The scenario's record once it is over (its own waits bound it: the startup limit,
        the copies, the watch's cap); a signal reaches the waiting thread between joins."""
        t = self._thread
        while t is not None and t.is_alive():
            t.join(0.05)
        if self.error is not None:
            raise self.error
        return self.mission

    def replay(self, observers: list[Callable[..., None]],
               stopped: Callable[[int, int], None] | None = None) -> None:
        """Hand the held traffic, in the order observed, to ``observers`` (each called as
        the driver calls its observers: direction, data, peer, t_ns[, run_delay=]), and the
        instance's stop to ``stopped`` (t_ns, run delay ns)."""
        with self._lock:
            held, self._held = self._held, []
        for direction, data, addr, t_ns, rd in held:
            if direction == "stop":
                if stopped is not None and rd is not None:
                    try:
                        stopped(t_ns, rd)
                    except Exception:  # noqa: BLE001 - a broken recorder must not stop the run
                        pass
                continue
            for obs in observers:
                try:
                    if rd is None:
                        obs(direction, data, addr, t_ns)
                    else:
                        obs(direction, data, addr, t_ns, run_delay=rd)
                except Exception:  # noqa: BLE001 - a broken recorder must not stop the run
                    pass

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        if self.node is not None:
            self.node.close()
        self.driver.close()

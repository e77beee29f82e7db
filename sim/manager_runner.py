"""The runner's own manager-role cases against a manager model, in one process on virtual time
(issue 38, item 2; the drone role's is :mod:`sim.runner`): the conformance suite as
``mcp-conform --role manager`` runs it (``conformance.cli.pytest_args``, the ``conformance``
plugin, its report), its session :class:`harness.manager_session.ManagerSession` itself, with
the run's clock a :class:`harness.clock.VirtualClock` and its drones' socket's far end a
:class:`sim.transport.SimTransport` to a :class:`sim.models.ManagerModel` -- the reference
manager (``reference_impl.manager``'s steps over ``reference_impl.endpoint``, at the embedded
manager's retry limit) or a manager fault of :mod:`sim.manager_faults` -- through the runner's seeded
link. Every wait of the runner's drones (``harness.mission_script``) and every timer of the
model are events on the clock: a suite at the description's 5 s timings costs the wall time of
its computation, and a seed gives the same run.

Each scenario's fresh manager is a fresh model (spawn mode: ``ManagerSession.respawn``); the
silent drone's scenario runs beside the main one (the default schedule) on a model of its own
behind a link of its own (``harness.manager_side.SideScenario`` with the simulated transport),
or after it (``serial``). :func:`run_manager_cases` returns the JSON report's verdicts
(:class:`ManagerSimRun`). Not simulated: attach mode (one running manager), ``--parallel``.

A stall of :class:`sim.stalls.StallingClock` holds a thread before it runs; a host also takes the
CPU from a thread in the middle of its step. ``preempt`` does that at the two points of the
drone players' answers where it changes what the runner records (:class:`Preemption`): right
after an ACK the runner sent has left, before the sender records it; and after the receiver
thread has logged a datagram and woken its waiters, before the drone players answer it.
"""

from __future__ import annotations

import json
import random
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import read_header
from mcp_conform.harness.impair import ImpairSpec, parse_impairment
from mcp_conform.harness.manager_session import EMBEDDED_RETRIES, MANAGER_PORT, ManagerSession
from mcp_conform.harness.manager_side import SideScenario
from mcp_conform.sim.faults import Fault, fault_endpoint
from mcp_conform.sim.manager_faults import MANAGER_FAULTS
from mcp_conform.sim.models import ManagerModel
from mcp_conform.sim.runner import STEP_S, SimRun, _SimPlugin
from mcp_conform.sim.stalls import StallingClock
from mcp_conform.sim.suite import run_suite, suite_args
from mcp_conform.sim.transport import SimNode, SimTransport
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action
from mcp_conform.spec.profiles import pick

__all__ = ["ManagerSimRun", "Preemption", "SimManagerSession", "manager_factory", "run_manager_cases"]

DRONE_PORT = int(SPEC.protocol["ports"]["drone"])
#: where the main scenario's manager model receives, and the drones' socket listens
MANAGER_ADDR = ("127.0.0.1", MANAGER_PORT)
DRONES_ADDR = ("127.0.0.1", DRONE_PORT)
#: the side scenario's: an instance with ports of its own (``harness.manager_side``)
SIDE_MANAGER_ADDR = ("127.0.0.1", MANAGER_PORT + 10000)
SIDE_DRONES_ADDR = ("127.0.0.1", DRONE_PORT + 10000)

#: A manager model for ``(drones, challenge, items handed, now)``: a fresh one per scenario.
ManagerFactory = Callable[[tuple[int, ...], int, tuple[Any, ...], float], ManagerModel]


def manager_factory(fault: str | None = None, *, rto: float = 0.2, seed: int = 0,
                    retries: int = EMBEDDED_RETRIES) -> ManagerFactory:
    """The reference manager (``fault`` None) or the manager fault ``fault`` of
    :data:`sim.manager_faults.MANAGER_FAULTS`, its endpoint at ``rto`` with ``retries`` retries
    (the embedded manager's: enough for the copies the main scenario withholds)."""
    endpoint, cls = None, ManagerModel
    if fault is not None:
        f = MANAGER_FAULTS.get(fault)
        if f is None:
            raise ValueError(f"{fault}: not a manager fault (known: {', '.join(sorted(MANAGER_FAULTS))})")
        cls = f.model
        if f.endpoint is not None:
            endpoint = fault_endpoint(Fault(f.name, "manager", f.rule, f.endpoint, f.retries), retries)
    spawns = random.Random(seed)

    def make(drones: tuple[int, ...], challenge: int, items: tuple[Any, ...], now: float) -> ManagerModel:
        return cls(drones, challenge, items, rto, retries, random.Random(spawns.getrandbits(64)), endpoint=endpoint)

    return make


class Preemption:
    """A runner thread taken off the CPU mid-step, seeded: with probability ``p`` it waits up to
    ``max_s`` virtual seconds (uniform) where :meth:`point` is called. It holds no lock there
    (the driver's condition is released before a datagram leaves and before the drone players
    answer), so the other threads run meanwhile, as on a loaded host: the case thread's ACK left
    but is not yet recorded in the mission while the receiver thread answers a copy of the same
    command (the drone players ACK it again once the case thread has released it)."""

    def __init__(self, clock: VirtualClock, seed: int, p: float, max_s: float) -> None:
        self.clock, self.p, self.max_s = clock, p, max_s
        self._rng = random.Random(seed)
        self.count = 0

    def point(self) -> None:
        if self._rng.random() < self.p:
            self.count += 1
            self.clock.sleep(self._rng.uniform(0.0, self.max_s))


class PreemptedTransport(SimTransport):
    """The runner's simulated socket whose sender may be preempted right after an ACK leaves
    (``Preemption``): the kernel took the datagram, the thread has not yet recorded it."""

    preemption: Preemption | None = None

    def sendto(self, data: bytes, addr: tuple[str, int]) -> int:
        n = super().sendto(data, addr)
        hdr = read_header(data) if self.preemption is not None else None
        if hdr is not None and hdr[3] == _ACK:
            self.preemption.point()  # type: ignore[union-attr]  # hdr is None without one
        return n


_ACK = int(Action.ACK)


def _unread(transport: SimTransport) -> Callable[[], bool]:
    """Whether the transport holds datagrams due at the runner's socket that its receiver
    thread has not read (a stalled thread: ``sim.stalls``), as the kernel's receive queue."""
    def unread() -> bool:
        box = getattr(transport, "_inbox", None)  # SimTransport has no public reading of it yet
        return bool(box is not None and box.queue)
    return unread


class SimManagerSession(ManagerSession):
    """The manager session with each scenario's manager a model on the simulated link."""

    def __init__(self, cfg: RunConfig, recorder: Any = None, *, clock: VirtualClock, transport: SimTransport,
                 side_transport: Callable[[], SimTransport], make_model: ManagerFactory, name: str) -> None:
        if cfg.target is None:  # the model receives where a manager does (a spawn would pick a free port)
            cfg.target = MANAGER_ADDR
        super().__init__(cfg, recorder, clock=clock, transport=transport)
        self.sim_transport = transport
        self.side_transport = side_transport
        self.make_model = make_model
        self.model_name = name
        self.models: list[ManagerModel] = []
        self.preemption: Preemption | None = getattr(transport, "preemption", None)

    def open(self) -> None:
        super().open()
        assert self.driver is not None and self.driver.on_datagram is not None
        preemption, answer = self.preemption, self.driver.on_datagram
        if preemption is not None:  # the receiver thread preempted before the drone players answer

            def answer_late(d: Any) -> None:
                preemption.point()
                answer(d)
            self.driver.on_datagram = answer_late

    def _model_node(self, transport: SimTransport, addr: tuple[str, int]) -> SimNode:
        items = self._handed_items()
        assert items is not None, "the spawn command names {waypoints} and {obstacles}"
        model = self.make_model(self.cfg.drones, self.cfg.challenge, items, self.clock.monotonic())
        model.addr = addr  # the manager receives where the drones send
        self.models.append(model)
        transport.attach(model)  # type: ignore[arg-type]  # typed for a drone, reads what any NodeModel has
        return SimNode(model, self.model_name, transport)  # type: ignore[arg-type]  # a manager's model

    def _spawn(self) -> None:
        assert self.driver is not None
        self.node = self._model_node(self.sim_transport, self.driver.target)  # type: ignore[assignment]

    def node_run_delay(self) -> int | None:
        return 0  # a model never waits for a CPU (stalls are the clock's)

    def backlog(self) -> Callable[[], bool]:
        return _unread(self.sim_transport)

    def side_why_not(self) -> str | None:
        if len(self.cfg.drones) < 2:
            return "a silent drone's effect on the others needs at least two drones"
        return None  # a model of its own on a link of its own: always possible

    def new_side(self, kind: str) -> SideScenario:
        tr = self.side_transport()
        return SideScenario(kind, spawn=self.cfg.spawn or "", placeholders=self._placeholders(),
                            listen_host=SIDE_DRONES_ADDR[0], target_host=SIDE_MANAGER_ADDR[0],
                            drones=self.cfg.drones, challenge=self.cfg.challenge, waypoints=self.waypoints,
                            obstacles=self.obstacles, seq_base=1000 + self.cfg.seed % 5000, rto=self.rto,
                            ack_window=self.ack_window, broadcast_id=self.cfg.broadcast_id, seed=self.cfg.seed,
                            ready_limit=self.ready_limit, clock=self.clock, transport=tr, target=SIDE_MANAGER_ADDR,
                            spawn_node=lambda argv: self._model_node(tr, SIDE_MANAGER_ADDR),
                            run_delay_of=lambda node: 0, backlog=_unread(tr))


@dataclass
class ManagerSimRun(SimRun):
    """A run's report and costs (:class:`sim.runner.SimRun`), its manager models (each
    scenario's, in the order spawned: what each did), and the session's mission records (what
    the cases judged: ``harness.drone_players.Mission`` by scenario) and preemptions made."""

    managers: list[ManagerModel] = field(default_factory=list)
    missions: dict[str, Any] = field(default_factory=dict)
    preemptions: int = 0


def _SimManagerPlugin(make: Callable[[RunConfig, Any], SimManagerSession]) -> Any:  # noqa: N802
    """Makes the run's session the simulated manager session (``sim.runner``'s plugin, for the
    manager role)."""
    return _SimPlugin(make, role="manager")


def run_manager_cases(model: str | None | ManagerFactory = None, *, seed: int = 0, rto: float = 0.2,
                      ack_window: float = 0.25, node_rto: float | None = None, retries: int = EMBEDDED_RETRIES,
                      link: str | ImpairSpec | None = None, challenge: int = 1, drones: str = "1,2,3",
                      select: Sequence[str] = (), exclude: Sequence[str] = (), extra: Sequence[str] = (),
                      serial: bool = False, stalls: tuple[float, float] | None = None,
                      preempt: tuple[float, float] | None = None) -> ManagerSimRun:
    """The manager-role cases (``serial``: ``--serial``; else the default, the silent drone's
    scenario beside the main one) against ``model`` -- None: the reference manager; a name of
    :data:`sim.manager_faults.MANAGER_FAULTS`; or a factory -- at ``--rto rto --ack-window ack_window`` (the
    manager's own timeout ``node_rto``, default ``rto``, and retry limit ``retries``),
    ``--challenge challenge --drones drones``; ``link`` the runner's link both ways, for each
    scenario's manager (``harness.impair`` spec); ``seed`` the run's, the models' and the links';
    ``stalls`` ``(p, max_s)``: the runner's own threads stalled (:class:`sim.stalls.StallingClock`);
    ``preempt`` ``(p, max_s)``: the main scenario's runner threads preempted mid-step (:class:`Preemption`)."""
    from mcp_conform.conformance import cli

    if model is None or isinstance(model, str):
        name = model or "reference-manager"
        factory = manager_factory(model, rto=rto if node_rto is None else node_rto, seed=seed, retries=retries)
    else:
        name, factory = getattr(model, "__name__", "model"), model
    spec = parse_impairment(link) if isinstance(link, str) else link
    clock = (VirtualClock(step=STEP_S) if stalls is None
             else StallingClock(seed, stalls[0], stalls[1], step=STEP_S))
    transport = PreemptedTransport(clock, spec, spec, link_seed=seed, listen=DRONES_ADDR)
    if preempt is not None:
        transport.preemption = Preemption(clock, seed + 104729, *preempt)
    sides = iter(range(1, 1000))

    def side_transport() -> SimTransport:
        return SimTransport(clock, spec, spec, link_seed=seed + 7919 * next(sides), listen=SIDE_DRONES_ADDR)

    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "report.json"
        # the files the session hands a manager named, as a spawn command names them: the model
        # is handed their items (the obstacles for challenge 3, else the waypoints)
        argv = ["--spawn", f"sim:{name} {{waypoints}} {{obstacles}}", "--rto", str(rto), "--ack-window", str(ack_window),
                "--challenge", str(challenge), "--drones", drones, *(["--serial"] if serial else []),
                "--seed", str(seed), "--json", str(path), "--timeout", "86400", *extra]
        argv += [f"--select={s}" for s in select] + [f"--exclude={s}" for s in exclude]
        ns = cli.build_parser().parse_args([*argv, "--quiet"])
        ns.protocol, ns.role = (p.name for p in pick("mcp", "manager"))
        args = suite_args(ns)
        plugin = _SimManagerPlugin(lambda cfg, rec: SimManagerSession(
            cfg, rec, clock=clock, transport=transport, side_transport=side_transport, make_model=factory,
            name=name))
        start = clock.monotonic()
        rc = run_suite(clock, args, plugin)
        report = json.loads(path.read_text()) if path.exists() else {}
    managers = list(plugin.session.models) if plugin.session is not None else []
    missions = dict(plugin.session.missions) if plugin.session is not None else {}
    made = transport.preemption.count if transport.preemption is not None else 0
    return ManagerSimRun(report, rc, clock.monotonic() - start, clock.switches, len(managers), managers,
                         missions, made)

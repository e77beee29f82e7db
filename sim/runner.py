"""The runner's own drone cases against a node model, in one process on virtual time (issue 38,
item 2): the conformance suite as ``mcp-conform`` runs it (``conformance.cli.pytest_args``,
the ``conformance`` pytest plugin, its report), only the session's clock is a
:class:`harness.clock.VirtualClock` and its driver's far end a :class:`sim.transport.SimTransport`
to a model of :mod:`sim.models` (the reference drone over ``reference_impl.endpoint``, or a
fault of :mod:`sim.faults`) through the runner's seeded link. Every wait of the runner and
every timer of the model are events on the clock: a run at the description's 5 s timings
costs the wall time of its computation, not of its waits, and a seed gives the same run.

:func:`run_cases` runs the suite (``--serial``, or the default schedule with its batch) and
returns the JSON report's verdicts (:class:`SimRun`). ``mavlink=True`` is the run with
``--mavlink`` (``mavlink="udpout"``: ``--mavlink udpout``): the session's vehicle is
``vehicle.SimVehicle`` on the same clock (:mod:`sim.vehicle`, over TCP or UDP), and each node
model talks MAVLink to it through its autopilot client (:mod:`sim.autopilot`), so the cases
observed on the autopilot link (MCP-DUP-*, MCP-BLK-4/5/7, MCP-PAY-8, MCP-SEQ-3) are judged. Not
simulated yet: ``--parallel`` (node instances in processes of their own: ``conformance.parallel``).
"""

from __future__ import annotations

import json
import random
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import pytest

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.drone_session import DRONE_PORT, Session
from mcp_conform.harness.impair import ImpairSpec, parse_impairment
from mcp_conform.sim.faults import FAULTS, fault_endpoint
from mcp_conform.sim.models import DroneModel
from mcp_conform.sim.stalls import StallingClock
from mcp_conform.sim.suite import run_suite, silence, suite_args
from mcp_conform.sim.transport import SimNode, SimTransport
from mcp_conform.sim.vehicle import SimVehicleNet, start_vehicle
from mcp_conform.spec import SPEC
from mcp_conform.spec.profiles import pick

__all__ = ["SimRun", "SimSession", "drone_factory", "run_cases"]

DRONE_ADDR = ("127.0.0.1", DRONE_PORT)
#: virtual seconds a handoff between the runner's threads takes (``VirtualClock.step``)
STEP_S = 1e-6

#: A node model for a spawn at virtual time ``now`` (a fresh one at each restart).
ModelFactory = Callable[[float], DroneModel]


def drone_factory(fault: str | None = None, *, rto: float = 0.2, seed: int = 0, ready_after: float = 0.05,
                  linger: float | None = None, retries: int | None = None, exits_on_give_up: bool = True
                  ) -> ModelFactory:
    """The reference drone (``fault`` None) or the drone fault ``fault`` of :data:`sim.faults.FAULTS`,
    its endpoint at ``rto``, its GPS fix ``ready_after`` s after it starts; ``retries``: its retry
    limit (None: the spec's, or the fault's own). ``retries=2`` is correct otherwise: the rule's
    configurable limit (spec/mcp.yaml's ``min_copies``); its Mission_Ready given up, it exits as
    ``drone.py`` does, or (``exits_on_give_up=False``) goes on as the C drone does."""
    retries = int(SPEC.params["retries"]) if retries is None else retries
    endpoint = None
    if fault is not None:
        f = FAULTS[fault]
        if f.role != "drone":
            raise ValueError(f"{fault}: a {f.role} fault, not a drone's")
        endpoint = fault_endpoint(f, retries)
    spawns = random.Random(seed)

    def make(now: float) -> DroneModel:
        model = DroneModel(1, rto, retries, random.Random(spawns.getrandbits(64)), ready_at=now + ready_after,
                           linger=linger, endpoint=endpoint)
        model.exits_on_give_up = exits_on_give_up
        return model

    return make


class SimSession(Session):
    """The drone session with its node a model on the simulated link (spawn mode: a restart is
    a fresh model)."""

    def __init__(self, cfg: RunConfig, recorder: Any = None, *, clock: VirtualClock, transport: SimTransport,
                 make_model: ModelFactory, name: str) -> None:
        if cfg.target is None:  # the model listens on the drone's port (a spawn would pick a free one)
            cfg.target = (DRONE_ADDR[0], DRONE_PORT)
        super().__init__(cfg, recorder, clock=clock, transport=transport)
        self.sim_transport = transport
        self.make_model = make_model
        self.model_name = name
        self.models: list[DroneModel] = []

    def _start_vehicle(self) -> None:
        """The real session's vehicle (``fix_withheld``, its taps to the monitor and capture),
        on the session's clock and the simulated link (:mod:`sim.vehicle`)."""
        net = self.sim_transport.vehicle_net = SimVehicleNet(self.clock)  # type: ignore[arg-type]
        self.vehicle, self.mavlink_url = start_vehicle(
            self.clock, net, self.cfg.mavlink_transport, fix_withheld=True,  # type: ignore[arg-type]
            on_frame=self._vehicle_frame, on_event=self._vehicle_event)

    def _spawn(self) -> None:
        assert self.driver is not None
        model = self.make_model(self.clock.monotonic())
        model.addr = self.driver.target  # the node listens where the runner sends
        if self.vehicle is not None:  # each spawn's client on a port of its own
            model.use_autopilot(("127.0.0.1", 41000 + len(self.models)))
        self.models.append(model)
        self.sim_transport.attach(model)
        self.node = SimNode(model, self.model_name, self.sim_transport)  # type: ignore[assignment]  # a process's reading
        if self.liveness is not None:
            self.liveness.reset(self.node)

    def node_run_delay(self) -> int | None:
        return 0  # a model never waits for a CPU (stalls are the link's and the world's)

    def observe_run(self, target: tuple[str, int], node_id: int | None, **kw: Any) -> Any:
        """Attach mode (``--target``): the node model starts as the runner's socket opens (one
        that runs already: its first copies are not seen), and is never replaced."""
        monitor = super().observe_run(target, node_id, **kw)
        if not self.spawned and not self.models:
            model = self.make_model(self.clock.monotonic())
            model.addr = target
            self.models.append(model)
            self.sim_transport.attach(model)
        return monitor


class _SimPlugin:
    """Makes the run's session the simulated one (``pytest_mcp_make_session``, first)."""

    def __init__(self, make: Callable[[RunConfig, Any], Any], role: str = "drone") -> None:
        self.make = make
        self.role = role  # the role whose cases the simulated session runs
        self.session: Any = None

    @pytest.hookimpl(trylast=True)
    def pytest_configure(self, config: pytest.Config) -> None:
        silence(config)  # a simulated run's stdout is /dev/null (sim.suite)

    @pytest.hookimpl(tryfirst=True)
    def pytest_mcp_make_session(self, cfg: RunConfig, recorder: Any, config: pytest.Config) -> Any:
        from mcp_conform.conformance._run_state import state_of
        from mcp_conform.spec.profiles import resolve

        role = cfg.profile()[1]
        if role.name != self.role:
            raise pytest.UsageError(f"this simulated session runs the {self.role} role's cases only")
        context = resolve(role.context)
        session = self.make(cfg, recorder)
        session.make_context = context
        state = state_of(config)
        context.prepare_session(session, config, state.items if state is not None else [])
        self.session = session
        return session


@dataclass
class SimRun:
    """One run's report (the JSON ``mcp-conform --json`` writes) and its costs."""

    report: dict[str, Any]
    rc: int
    virtual_s: float  # the run's length on the virtual clock (wall and CPU: bench/bench_sim_runner.py)
    switches: int  # the clock's thread switches
    models: int  # node models spawned (1 + restarts)

    @property
    def rules(self) -> dict[str, str]:
        return dict(self.report.get("rules", {}))

    def rules_with(self, *outcomes: str) -> dict[str, str]:
        return {r: o for r, o in self.rules.items() if o in outcomes}

    def cases(self) -> dict[str, str]:
        return {c["id"]: c["outcome"] for c in self.report.get("cases", [])}

    def explain(self) -> str:
        lines = [f"exit {self.rc}; error={self.report.get('error')!r}; {self.virtual_s:.1f} virtual s"]
        for c in self.report.get("cases", []):
            if c["outcome"] in ("failed", "warned", "error"):
                lines.append(f"{c['outcome']}: {c['id']} {c['rules']}: {c.get('reason') or ''} "
                             f"expected={c.get('expected')!r} actual={c.get('actual')!r}")
        for f in self.report.get("failures", []):
            if f.get("source") == "monitor":
                lines.append(f"monitor {f['outcome']}: {f['rule']}")
        return "\n".join(lines)


def run_cases(model: str | None | ModelFactory = None, *, seed: int = 0, rto: float = 0.2,
              ack_window: float = 0.25, node_rto: float | None = None, link: str | ImpairSpec | None = None,
              select: Sequence[str] = (), exclude: Sequence[str] = (), extra: Sequence[str] = (),
              serial: bool = True, stalls: tuple[float, float] | None = None, mavlink: bool | str = False,
              attach: bool = False) -> SimRun:
    """The drone cases (``--serial``; ``serial=False``: the default schedule, its batch's cases
    in threads of their own on the virtual clock) against ``model`` -- None: the reference drone; a name of
    :data:`sim.faults.FAULTS`; or a factory -- at ``--rto rto --ack-window ack_window`` (the node's
    own timeout ``node_rto``, default ``rto``), ``link`` the runner's link both ways
    (``harness.impair`` spec), ``seed`` the run's and the link's; ``stalls`` ``(p, max_s)``: the
    runner's own threads stalled (:class:`sim.stalls.StallingClock`, by ``seed``); ``mavlink``:
    the run's vehicle (``--mavlink``: True its TCP, or a transport of
    :data:`sim.vehicle.SIM_TRANSPORTS`; module docstring); ``attach``: ``--target`` (attach mode,
    no vehicle: the node is never restarted) instead of ``--spawn``."""
    from mcp_conform.conformance import cli

    if model is None or isinstance(model, str):
        name = model or "reference-drone"
        factory = drone_factory(model, rto=rto if node_rto is None else node_rto, seed=seed)
    else:
        name, factory = getattr(model, "__name__", "model"), model
    spec = parse_impairment(link) if isinstance(link, str) else link
    clock = (VirtualClock(step=STEP_S) if stalls is None
             else StallingClock(seed, stalls[0], stalls[1], step=STEP_S))
    transport = SimTransport(clock, spec, spec, link_seed=seed)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "report.json"
        node = ["--target", f"{DRONE_ADDR[0]}:{DRONE_PORT}"] if attach else ["--spawn", f"sim:{name}"]
        argv = [*node, "--rto", str(rto), "--ack-window", str(ack_window),
                *(["--serial"] if serial else []), *(["--mavlink", "tcp" if mavlink is True else str(mavlink)] if mavlink else []), "--seed", str(seed), "--json", str(path), "--timeout", "86400", *extra]
        argv += [f"--select={s}" for s in select] + [f"--exclude={s}" for s in exclude]
        ns = cli.build_parser().parse_args([*argv, "--quiet"])
        ns.protocol, ns.role = (p.name for p in pick("mcp", "drone"))
        args = suite_args(ns)
        plugin = _SimPlugin(lambda cfg, rec: SimSession(cfg, rec, clock=clock, transport=transport,
                                                        make_model=factory, name=name))
        start = clock.monotonic()
        rc = run_suite(clock, args, plugin)
        report = json.loads(path.read_text()) if path.exists() else {}
    models = len(plugin.session.models) if plugin.session is not None else 0
    return SimRun(report, rc, clock.monotonic() - start, clock.switches, models)

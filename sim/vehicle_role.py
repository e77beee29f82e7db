"""The MAVLink vehicle role in the simulator (issue 38, items 2 and 4): ``mcp-conform --protocol
mavlink`` (role ``vehicle``: the runner a ground station, an autopilot judged) as it runs --
``conformance.cli``'s pytest arguments, the ``conformance`` plugin, its report -- with its
session :class:`harness.mavlink_session.MavlinkSession` itself on a
:class:`harness.clock.VirtualClock`, and its link's far end ``vehicle.SimVehicle`` (our
reference vehicle, the one ``mcp-vehicle`` serves) on the same clock and a simulated net
(:mod:`sim.vehicle`), or that vehicle behind one of the faults of :mod:`sim.vehicle_faults`.
Every wait of the runner's cases, its heartbeat and its reader, and every timer of the
vehicle, is an event on the clock: the suite's ~45 s of protocol timers cost the wall time of
its computation, and a seed gives the same run.

The runner's link (``harness.mavlink_session.Link``, through its net seam) is seeded each way
(``harness.impair``'s :class:`Impairment`, as :mod:`sim.link` decides): over TCP (the default;
the vehicle listens and the runner connects, SITL's 5760) the link is a stream -- its bytes
come in order and whole, so a copy the impairment loses is one TCP sends again
(``TCP_RTO_MIN_S`` later, Linux's least retransmission timeout), its duplicates are discarded
and a delay never lets a chunk pass the one before; over UDP (``udpout``: the vehicle listens
and answers the runner's socket) each datagram is carried as decided, so a spec with loss,
duplication or reordering spoils what the suite reads as loopback (MAV-HB-11's sequence
numbers: the rules allow only delays there). ``stalls``: the runner's and the vehicle's threads
left off the CPU (:class:`sim.stalls.StallingClock`). ``udpin`` (the vehicle sends first, SITL's
``--out``) is not simulated (:mod:`sim.vehicle`).

:func:`run_vehicle_cases` returns the JSON report's verdicts (:class:`sim.runner.SimRun`).
"""

from __future__ import annotations

import json
import tempfile
from collections import deque
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.impair import Impairment, ImpairSpec, parse_impairment
from mcp_conform.harness.mavlink_session import MavlinkSession
from mcp_conform.sim.link import check_spec
from mcp_conform.sim.runner import STEP_S, SimRun, _SimPlugin
from mcp_conform.sim.stalls import StallingClock
from mcp_conform.sim.suite import run_suite, suite_args
from mcp_conform.sim.vehicle import VEHICLE_ADDR, VEHICLE_TCP, SimVehicleNet, start_vehicle
from mcp_conform.sim.vehicle_faults import VEHICLE_SYSID, FaultProxy
from mcp_conform.spec.profiles import pick

__all__ = ["RUNNER_ADDR", "SimLinks", "SimVehicleSession", "run_vehicle_cases"]

Address = tuple[str, int]
#: the runner's end of the link (its ephemeral port)
RUNNER_ADDR: Address = ("127.0.0.1", 45760)
#: the session's transports the simulated vehicle serves, and how it serves each (sim.vehicle)
SERVES = {"tcp": "tcp", "udpout": "udpout"}
#: a lost TCP segment comes again after Linux's least retransmission timeout (TCP_RTO_MIN)
TCP_RTO_MIN_S = 0.2


class _Lane:
    """One direction of the runner's link: each chunk's delivery time by the seeded
    impairment (``harness.impair``), on the virtual clock (module docstring: a stream's come in
    order and whole)."""

    def __init__(self, clock: VirtualClock, impairment: Impairment, name: str, stream: bool, latency: float) -> None:
        self.clock, self.impairment, self.name = clock, impairment, name
        self.stream, self.latency = stream, latency
        self._last = 0.0  # a stream's last delivery time

    def carry(self, data: bytes, deliver: Callable[[bytes], None]) -> None:
        now = self.clock.now + self.latency
        if not self.impairment.spec.active:
            delays = [0.0]
        else:
            decision = self.impairment.decide(self.name, data, now)
            delays = [d.delay_s for d in decision.deliveries]
            if self.stream:  # TCP: sent again when lost, one copy, in order
                delays = delays[:1] or [TCP_RTO_MIN_S + self.impairment.spec.delay_hi_s]
        for delay in delays:
            t = now + delay
            if self.stream:
                t = self._last = max(t, self._last)
            self.clock.call_at(t, lambda: deliver(data))


class RunnerEnd:
    """What the runner's end of a simulated link is in either MAVLink role (``harness.
    mavlink_session``'s ``HostLinks.open`` end: ``ready``, ``read``, ``sock``; its subclass
    adds ``send`` and ``close``): the chunks that came, queued on the clock, read in order;
    ``peer``: where a datagram comes from (over UDP; over TCP none)."""

    def __init__(self, clock: VirtualClock, transport: str, peer: Address) -> None:
        self.clock, self.transport, self.peer = clock, transport, peer
        self.sock = self
        self._cond = clock.condition()
        self._queue: deque[bytes] = deque()
        self.closed = False

    def ready(self, timeout: float) -> bool:
        with self._cond:
            if not self._queue and not self.closed:
                self._cond.wait(timeout)
            if self.closed:
                raise ValueError("closed")
            return bool(self._queue)

    def read(self) -> tuple[bytes, Any]:
        with self._cond:
            if not self._queue:
                raise BlockingIOError
            data = self._queue.popleft()
        return data, (None if self.transport == "tcp" else self.peer)

    def _arrive(self, data: bytes) -> None:
        with self._cond:
            if not self.closed:
                self._queue.append(data)
                self._cond.notify_all()


class _SimEnd(RunnerEnd):
    """The runner's end of the link on the simulated net (``harness.mavlink_session``'s
    ``HostLinks.open`` end: ``send``, ``ready``, ``read``, ``close``, ``sock``)."""

    def __init__(self, links: SimLinks, transport: str, address: Address) -> None:
        vnet = links.vnet
        if vnet is None or (transport == "tcp" and (vnet.listener is None or vnet.listener.closed)):
            raise ConnectionRefusedError(111, "Connection refused")
        super().__init__(links.clock, transport, address)
        self.links, self.address, self.vnet = links, address, vnet
        clock = links.clock
        self.proxy = FaultProxy(links.fault) if links.fault is not None else None
        stream = transport == "tcp"
        self.down = _Lane(clock, links.impairment, "runner:down", stream, vnet.latency)
        self.up = _Lane(clock, links.impairment, "runner:up", stream, vnet.latency)
        vnet.attach(RUNNER_ADDR, self._from_vehicle)

    def getsockname(self) -> Address:
        return RUNNER_ADDR

    # -- the runner's side ----------------------------------------------------------------
    def send(self, data: bytes, peer: Address) -> None:
        if self.closed:
            raise BrokenPipeError(32, "Broken pipe")
        self.down.carry(data, self._to_vehicle)

    def close(self) -> None:
        with self._cond:
            if self.closed:
                return
            self.closed = True
            self._cond.notify_all()
        self.vnet.detach(RUNNER_ADDR)

    # -- the link's far end (clock callbacks: they never block) ----------------------------
    def _to_vehicle(self, data: bytes) -> None:
        if self.closed:
            return
        if self.proxy is not None:
            data, answer = self.proxy.down(data)
            if answer:
                self.up.carry(answer, self._arrive)
        if data:
            self.vnet.from_node(data, RUNNER_ADDR)

    def _from_vehicle(self, data: bytes) -> None:
        if self.proxy is not None:
            data = self.proxy.up(data)
        if data:
            self.up.carry(data, self._arrive)


class SimLinks:
    """Where the session's link opens its end (``harness.mavlink_session.Link``'s ``net``):
    on the simulated vehicle's net ``vnet`` (set once the vehicle is started), through
    ``fault`` (a name of :data:`sim.vehicle_faults.FAULTS`; None: straight to the vehicle)
    and the seeded ``impairment`` (module docstring)."""

    def __init__(self, clock: VirtualClock, impairment: Impairment, fault: str | None = None) -> None:
        self.clock, self.impairment, self.fault = clock, impairment, fault
        self.vnet: SimVehicleNet | None = None

    def open(self, transport: str, address: Address, sock: Any = None) -> _SimEnd:
        if transport not in SERVES:
            raise OSError(f"{transport}: the simulated vehicle serves {' or '.join(SERVES)}")
        return _SimEnd(self, transport, address)


class SimVehicleNode:
    """The vehicle as the session's spawned process (``harness.session_base.SpawnedNode``'s
    reading: ``alive``, ``returncode``, ``details``, ``evidence``, ``stop``)."""

    def __init__(self, vehicle: Any, name: str) -> None:
        self.vehicle, self.name = vehicle, name
        self.argv = [f"sim:{name}"]
        self.before_stop: Callable[[], None] | None = None
        self.stopped = False
        self.pid = None

    def alive(self) -> bool:
        return not self.stopped

    @property
    def returncode(self) -> int | None:
        return 0 if self.stopped else None

    def run_delay(self) -> int | None:
        return None

    def output_tail(self, lines: int = 12) -> str:
        return ""

    def details(self, lines: int = 12) -> dict[str, Any]:
        return {"command": list(self.argv), "exit": "exited with code 0" if self.stopped else None,
                "stdout": [], "stderr": []}

    def evidence(self) -> list[str]:
        return [f"vehicle model: {self.name}"]

    def stop(self, grace: float = 2.0) -> None:
        hook, self.before_stop = self.before_stop, None
        if hook is not None:
            hook()
        if not self.stopped:
            self.stopped = True
            self.vehicle.close()

    close = stop


class SimVehicleSession(MavlinkSession):
    """The vehicle-role session with its vehicle ``SimVehicle`` on the run's virtual clock and
    its link's far end the simulated net (spawn mode: the vehicle started with the run)."""

    def __init__(self, cfg: RunConfig, recorder: Any = None, *, clock: VirtualClock, links: SimLinks,
                 name: str) -> None:
        super().__init__(cfg, recorder, clock=clock, net=links)
        if self.transport not in SERVES:
            raise pytest.UsageError(f"the simulated vehicle serves {' or '.join(SERVES)}, not {self.transport}")
        self.links, self.model_name = links, name

    def _spawn(self) -> None:
        vnet = self.links.vnet = SimVehicleNet(self.clock)  # type: ignore[arg-type]  # a VirtualClock
        vehicle, _ = start_vehicle(self.clock, vnet, SERVES[self.transport], sysid=VEHICLE_SYSID)  # type: ignore[arg-type]
        self.address = VEHICLE_TCP if self.transport == "tcp" else VEHICLE_ADDR
        self.node = SimVehicleNode(vehicle, self.model_name)  # type: ignore[assignment]  # a process's reading
        self._open()


def run_vehicle_cases(fault: str | None = None, *, seed: int = 0, transport: str = "tcp",
                      link: str | ImpairSpec | None = None, stalls: tuple[float, float] | None = None,
                      select: Sequence[str] = (), exclude: Sequence[str] = (), extra: Sequence[str] = ()) -> SimRun:
    """The vehicle-role suite against the reference vehicle (``fault`` None) or the vehicle
    behind ``fault`` (:data:`sim.vehicle_faults.FAULTS`), over ``transport`` (``tcp`` or
    ``udpout``, ``--mavlink``), ``link`` the runner's link both ways (``harness.impair`` spec,
    seeded by ``seed``), ``stalls`` ``(p, max_s)``: the threads stalled
    (:class:`sim.stalls.StallingClock`, by ``seed``)."""
    from mcp_conform.conformance import cli

    name = fault or "reference-vehicle"
    spec = check_spec(parse_impairment(link) if isinstance(link, str) else (link or ImpairSpec()))
    clock = (VirtualClock(step=STEP_S) if stalls is None
             else StallingClock(seed, stalls[0], stalls[1], spare=("vehicle-",), step=STEP_S))
    links = SimLinks(clock, Impairment(replace(spec, seed=seed)), fault)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "report.json"
        argv = ["--spawn", f"sim:{name}", "--mavlink", "udp" if transport == "udpin" else transport,
                "--seed", str(seed), "--json", str(path), "--timeout", "86400", *extra]
        argv += [f"--select={s}" for s in select] + [f"--exclude={s}" for s in exclude]
        ns = cli.build_parser().parse_args([*argv, "--quiet"])
        ns.protocol, ns.role = (p.name for p in pick("mavlink", "vehicle"))
        args = suite_args(ns)
        plugin = _SimPlugin(lambda cfg, rec: SimVehicleSession(cfg, rec, clock=clock, links=links, name=name),
                            role="vehicle")
        start = clock.monotonic()
        rc = run_suite(clock, args, plugin)
        report = json.loads(path.read_text()) if path.exists() else {}
    return SimRun(report, rc, clock.monotonic() - start, clock.switches, 1 if plugin.session is not None else 0)

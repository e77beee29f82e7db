"""The MAVLink gcs role in the simulator (issue 38, items 2 and 4): ``mcp-conform --protocol
mavlink --role gcs`` (the runner the vehicle, a ground station judged) as it runs --
``conformance.cli``'s pytest arguments, the ``conformance`` plugin, its report -- with its
session :class:`harness.mavlink_gcs_session.MavlinkGcsSession` itself (its runner's vehicle,
its cases, its trace monitor) on a :class:`harness.clock.VirtualClock`, and each run's ground
station the reference GCS or one of its faults run on the same clock (:mod:`sim.gcs`: the
reference's own code, its connection and clock the simulator's) in place of a process. The
suite's protocol timers (a ground station spawned for each behaviour, ~70 s a suite on real
timers) cost the wall time of their computation, and a seed gives the same run.

The link between them (``harness.mavlink_session.Link``'s ``net``: :class:`GcsLinks`) is seeded
each way (``harness.impair``, as :mod:`sim.vehicle_role`'s ``_Lane`` carries it): over TCP (the
default; the runner listens, the ground station connects) a stream, its bytes late and in order,
a lost chunk sent again ``TCP_RTO_MIN_S`` later; over UDP (``udpout``: the ground station sends
first and the runner answers its port; ``udp``/``udpin``: the runner sends to the port the
ground station listens on, which sends nothing until it heard the runner) each datagram as
decided -- the cases read a UDP link as loopback (MAV-HB-11's sequence numbers), so only delays
are for it. ``stalls``: the runner's threads (its vehicle's ticker, its reader, its cases) left
off the CPU (:class:`sim.stalls.StallingClock`); the ground station's are spared (its lateness
is its own).

:func:`run_gcs_cases` returns the JSON report's verdicts (:class:`sim.runner.SimRun`).
"""

from __future__ import annotations

import json
import tempfile
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import pytest

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.impair import Impairment, ImpairSpec, parse_impairment
from mcp_conform.harness.mavlink_gcs_session import MavlinkGcsSession
from mcp_conform.harness.session_base import Death
from mcp_conform.sim.gcs import GcsProcess, SimMavConn, gcs_class
from mcp_conform.sim.link import check_spec
from mcp_conform.sim.runner import STEP_S, SimRun, _SimPlugin
from mcp_conform.sim.stalls import StallingClock
from mcp_conform.sim.suite import run_suite, suite_args
from mcp_conform.sim.vehicle_role import RunnerEnd, _Lane
from mcp_conform.spec.profiles import pick

__all__ = ["GCS_ADDR", "RUNNER_ADDR", "GcsLinks", "SimGcsSession", "run_gcs_cases"]

Address = tuple[str, int]
#: where the runner listens (TCP: SITL's 5760; UDP, ``udpout``: 14550), and the ground station's end
RUNNER_ADDR: Address = ("127.0.0.1", 5760)
RUNNER_UDP: Address = ("127.0.0.1", 14550)
GCS_ADDR: Address = ("127.0.0.1", 14551)
#: the session's ``--mavlink`` schemes the simulator carries (all of them)
SCHEMES = ("tcp", "udp", "udpin", "udpout")
#: virtual seconds a byte takes on loopback, each way
LATENCY_S = 50e-6


class _RunnerEnd(RunnerEnd):
    """The runner's end of one run's link (``HostLinks.open``'s: ``send``, ``ready``,
    ``read``, ``close``, ``sock``), to :attr:`conn`, the ground station's connection."""

    def __init__(self, links: GcsLinks, transport: str, address: Address) -> None:
        clock = links.clock
        super().__init__(clock, transport, GCS_ADDR)
        self.links = links
        links.runs += 1
        stream = transport == "tcp"
        run = links.runs
        self.down = _Lane(clock, links.impairment, f"run{run}:down", stream, LATENCY_S)
        self.up = _Lane(clock, links.impairment, f"run{run}:up", stream, LATENCY_S)
        self.conn: SimMavConn | None = None
        self.address = RUNNER_UDP if transport == "udpin" else RUNNER_ADDR

    def getsockname(self) -> Address:
        return self.address

    def connect(self, conn: SimMavConn) -> None:
        self.conn = conn

    # -- the runner's side ----------------------------------------------------------------
    def send(self, data: bytes, peer: Address) -> None:
        if self.closed:
            raise BrokenPipeError(32, "Broken pipe")
        conn = self.conn
        if conn is not None:
            self.down.carry(data, conn.arrive)

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()
        conn = self.conn
        if conn is not None and self.transport == "tcp":  # the connection's end, read by the ground station
            self.clock.call_later(LATENCY_S, conn.close)

    # -- the ground station's side (clock callbacks and its sends: they never block) --------
    def from_gcs(self, data: bytes) -> None:
        self.up.carry(data, self._arrive)

    def gcs_closed(self) -> None:
        """The ground station closed its end: over TCP the runner reads the end (b"")."""
        if self.transport == "tcp":
            self.up.carry(b"", self._arrive)


class GcsLinks:
    """Where the session's links open their end (``harness.mavlink_session.Link``'s ``net``):
    each run's a fresh :class:`_RunnerEnd` (:attr:`end`), through the seeded ``impairment``."""

    def __init__(self, clock: VirtualClock, impairment: Impairment) -> None:
        self.clock, self.impairment = clock, impairment
        self.runs = 0
        self.end: _RunnerEnd | None = None

    def open(self, transport: str, address: Address, sock: Any = None) -> _RunnerEnd:
        self.end = _RunnerEnd(self, transport, address)
        return self.end


class SimGcsSession(MavlinkGcsSession):
    """The gcs-role session with each run's ground station a model (:class:`sim.gcs.GcsProcess`)
    on the run's virtual clock, its link the simulated one (spawn mode, ``--spawn sim:NAME``)."""

    def __init__(self, cfg: RunConfig, recorder: Any = None, *, clock: VirtualClock, links: GcsLinks,
                 fault: str | None, name: str) -> None:
        super().__init__(cfg, recorder, clock=clock, net=links)
        if self.scheme not in SCHEMES:
            raise pytest.UsageError(f"the simulated link carries {' or '.join(SCHEMES)}, not {self.scheme}")
        gcs_class(fault)  # an unknown fault: its one line before the run
        self.links, self.fault, self.model_name = links, fault, name
        self.processes: list[GcsProcess] = []

    def _spawn(self) -> None:
        """As the real session's: the runner's end first (over UDP it is open before the
        ground station starts), then the ground station on it with ``{mavlink}``."""
        host = RUNNER_ADDR[0]
        if self.scheme == "tcp":
            self._open("tcp", GCS_ADDR, sock="accepted")
            self.url = f"tcp:{host}:{RUNNER_ADDR[1]}"
        elif self.scheme == "udpout":
            self._open("udpin", (host, 0))
            self.url = f"udpout:{host}:{RUNNER_UDP[1]}"
        else:
            self._open("udpout", GCS_ADDR)
            self.url = f"{self.scheme}:{host}:{GCS_ADDR[1]}"
        end = self.links.end
        assert end is not None
        cls = gcs_class(self.fault)
        conn = SimMavConn(self.clock, end.from_gcs, mavlink2_first=cls.mavlink2_first,  # type: ignore[arg-type]
                          listens=self.scheme != "udpout" and self.scheme != "tcp", on_close=end.gcs_closed)
        end.connect(conn)
        proc = GcsProcess(self.clock, conn, self.url, self.fault, self.model_name)  # type: ignore[arg-type]
        self.processes.append(proc)
        self.node = proc  # type: ignore[assignment]  # a process's reading

    def death(self, grace: float = 0.0) -> Death | None:
        """How the ground station ended, when it ended badly (as the real session's: its exit
        code 0 is its work done; a stop by the runner is none)."""
        node = self.node
        if node is None or node.alive() or node.returncode in (0, -15):
            return None
        return Death(node.returncode, None, None, tuple(node.details(20)["stderr"]), self.subject)


def run_gcs_cases(fault: str | None = None, *, seed: int = 0, transport: str = "tcp",
                  link: str | ImpairSpec | None = None, stalls: tuple[float, float] | None = None,
                  select: Sequence[str] = (), exclude: Sequence[str] = (), extra: Sequence[str] = ()) -> SimRun:
    """The gcs-role suite against the reference GCS (``fault`` None) or the ground station with
    ``fault`` (:data:`sim.gcs_faults.FAULTS`), over ``transport`` (``--mavlink``: tcp, udp,
    udpin, udpout), ``link`` the link both ways (``harness.impair`` spec, seeded by ``seed``),
    ``stalls`` ``(p, max_s)``: the runner's threads stalled (:class:`sim.stalls.StallingClock`,
    by ``seed``). ``models`` of the result: the ground stations run (one per behaviour)."""
    from mcp_conform.conformance import cli

    name = fault or "reference-gcs"
    spec = check_spec(parse_impairment(link) if isinstance(link, str) else (link or ImpairSpec()))
    clock = (VirtualClock(step=STEP_S) if stalls is None
             else StallingClock(seed, stalls[0], stalls[1], spare=("gcs-",), step=STEP_S))
    links = GcsLinks(clock, Impairment(replace(spec, seed=seed)))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "report.json"
        argv = ["--spawn", f"sim:{name} {{mavlink}}", "--mavlink", transport, "--seed", str(seed),
                "--json", str(path), "--timeout", "86400", *extra]
        argv += [f"--select={s}" for s in select] + [f"--exclude={s}" for s in exclude]
        ns = cli.build_parser().parse_args([*argv, "--quiet"])
        ns.protocol, ns.role = (p.name for p in pick("mavlink", "gcs"))
        args = suite_args(ns)
        plugin = _SimPlugin(lambda cfg, rec: SimGcsSession(cfg, rec, clock=clock, links=links, fault=fault, name=name),
                            role="gcs")
        start = clock.monotonic()
        rc = run_suite(clock, args, plugin)
        report = json.loads(path.read_text()) if path.exists() else {}
    runs = len(plugin.session.processes) if plugin.session is not None else 0
    return SimRun(report, rc, clock.monotonic() - start, clock.switches, runs)

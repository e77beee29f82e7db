"""The runner's session with a ground station (``--protocol mavlink --role gcs``): the runner
is the vehicle (``harness.mavlink_gcs_vehicle``: the simulated ArduCopter with a run's
``Behaviour``), driven in-process on the runner's :class:`~harness.mavlink_session.Link`, and
the ground station (a GCS, an SDK, a drone application) connects to it.

A ground station does its work once (a mission, a parameter, a command), so every behaviour
gets its own run: :meth:`MavlinkGcsSession.run` starts the ground station afresh (``--spawn
CMD`` with ``{mavlink}``, the URL it reaches the runner's vehicle by; without ``--spawn``, the
reference GCS, ``mcp-node --protocol mavlink gcs {mavlink}``) against a fresh vehicle with
that behaviour, and keeps the run while the cases ask for the same behaviour. ``--mavlink
tcp|udp|udpin|udpout`` is how the ground station connects, as ``vehicle.links`` names it:
tcp (default, the runner listens as SITL's port 5760 does), udp/udpin (the runner sends to
the ground station's port, as SITL's ``--out``), udpout (the runner listens on UDP and
answers the sender). Every frame goes to the capture's ``/mavlink`` channel from the
autopilot's side, which is now the runner's (``tx``: the runner sent it).

``clock`` and ``net`` are the run's clock (``harness.clock``) and where its links open
(``harness.mavlink_session.HostLinks``): the host's by default; the simulator's virtual ones
in ``mcp_conform.sim.gcs_role`` (issue 38), whose session spawns a ground-station model in
place of a process (:meth:`MavlinkGcsSession._spawn`).
"""

from __future__ import annotations

import contextlib
import socket
from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.errors import SetupError, SpawnFailure
from mcp_conform.harness.mavlink_gcs_vehicle import ARDUPILOT, Behaviour, RunnerVehicle
from mcp_conform.harness.mavlink_session import HOST_LINKS, Link, Received
from mcp_conform.harness.procs import SPAWN_STARTUP_S
from mcp_conform.harness.session_base import (
    Death,
    SpawnedNode,
    fill_placeholders,
    free_port,
    reference_command,
)
from mcp_conform.harness.stream_session import StreamSessionBase
from mcp_conform.judge.mavlink_monitor import MavlinkMonitor
from mcp_conform.spec import MAVLINK
from mcp_conform.spec.mavlink import MavlinkSpec

__all__ = ["MavlinkGcsSession"]

TICK_S = 0.02


class MavlinkGcsSession(StreamSessionBase):
    """The ground station under test, run afresh for each behaviour of the runner's vehicle."""

    subject = "the ground station"
    _template: str  # always a command: the ground station is spawned for every run
    startup_note = ("startup: the runner is the vehicle (system 1, an ArduCopter) and starts the ground station "
                    "against it", "startup: waiting for the ground station's first frame")

    def __init__(self, cfg: RunConfig, recorder: Any = None, spec: MavlinkSpec = MAVLINK, *,
                 clock: Clock = REAL, net: Any = HOST_LINKS) -> None:
        self.cfg, self.recorder, self.spec = cfg, recorder, spec
        self.clock, self.net = clock, net
        self.params = spec.params
        self.scheme = cfg.mavlink_transport if cfg.mavlink else "tcp"
        profile, role = cfg.profile()
        self._template = cfg.spawn or reference_command(profile, role, "{mavlink}")
        self.link: Link | None = None
        self.vehicle: RunnerVehicle | None = None
        self.behaviour: Behaviour | None = None
        self.url = ""
        #: when the current run's link opened, and when the ground station's first frame came
        self.run_started = 0.0
        self.first_frame: float | None = None
        #: the run's trace monitor, fed by each run's link, the ground station's rules judged
        #: on it (the report's monitor section; each run a session of its own)
        self.monitor: Any = MavlinkMonitor(spec, roles=("gcs",), complete=True)
        self.runs = 0
        self._stop = clock.event()
        self._ticker: Any = None
        self._listener: socket.socket | None = None

    # -- life -----------------------------------------------------------------------------
    def start(self, **_: Any) -> None:
        if self.cfg.target is not None:
            raise SetupError("--role gcs: attach mode is not supported: the runner starts the ground station "
                             "for each behaviour of its vehicle (--spawn 'CMD ... {mavlink}')")
        self.run(ARDUPILOT)
        how = " (spawned)" if self.cfg.spawn else " (embedded reference GCS)"
        self.target_desc = f"{self.url}{how}"

    def run(self, behaviour: Behaviour, *, fresh: bool = False) -> float:
        """The ground station's run against a vehicle that behaves so: the current one when it
        has this behaviour (unless ``fresh``), else the ground station started afresh; when
        the run's link opened (the run clock's ``monotonic()``)."""
        if not fresh and behaviour == self.behaviour and self.link is not None:
            return self.run_started
        self._end_run()
        self.behaviour, self.vehicle = behaviour, RunnerVehicle(behaviour, self.clock.monotonic())
        self.first_frame = None
        self.runs += 1
        segment = f"gcs-run-{self.runs}"  # each run a session of the capture and the monitor
        self.monitor.begin_segment(segment)  # (its parties start anew: judge.mavlink_monitor)
        if self.recorder is not None:
            with contextlib.suppress(Exception):  # a recorder without sessions records them as one
                self.recorder.begin_segment(segment)
        self._spawn()
        wait = float(self.cfg.extra.get("startup_timeout", SPAWN_STARTUP_S))
        link = self.link
        assert link is not None
        if not link.wait_for(lambda: self.first_frame is not None or not self.alive_process(), wait):
            if not self.alive_process():
                raise SpawnFailure(f"the ground station {self.node_exit()} before it sent a frame to "
                                   f"{self.url}", self.node.details(20) if self.node else {})
            raise SetupError(f"{self.url}: no frame from the ground station within {wait:g} s")
        return self.run_started

    def _spawn(self) -> None:
        """A fresh link in the GCS's transport, then the ground station with ``{mavlink}``;
        TCP: its connection accepted (within --startup-timeout)."""
        host = "127.0.0.1"
        if self.scheme == "tcp":
            lst = self._listener = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
            lst.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            lst.bind((host, 0))
            lst.listen(1)
            self.url = f"tcp:{host}:{lst.getsockname()[1]}"
        elif self.scheme == "udpout":  # the ground station sends first: the runner binds and answers
            self._open("udpin", (host, 0))
            assert self.link is not None
            self.url = f"udpout:{host}:{self.link.sock.getsockname()[1]}"
        else:  # udp / udpin: the ground station listens, the runner sends to it
            port = free_port(host)
            self._open("udpout", (host, port))
            self.url = f"{self.scheme}:{host}:{port}"
        self.node = SpawnedNode(fill_placeholders(self._template, {"mavlink": self.url}))
        if self.scheme == "tcp":
            assert self._listener is not None
            conn = self.accept_from_node(self._listener, float(self.cfg.extra.get("startup_timeout", SPAWN_STARTUP_S)),
                                         self.url)
            self._open("tcp", conn.getpeername(), conn)

    def _open(self, transport: str, address: tuple[str, int], sock: Any = None) -> None:
        assert self.vehicle is not None
        self.link = Link(transport, address, self.recorder, ids=self.vehicle.ids, sent_as="tx", got_as="rx",
                         sock=sock, on_frames=self._answer, monitor=self.monitor, clock=self.clock, net=self.net)
        self.run_started = self.clock.monotonic()
        self._stop.clear()
        self._ticker = self.clock.start_thread(self._tick, "mavlink-vehicle")

    def _answer(self, frames: list[Received]) -> None:
        """On the link's reader thread: the vehicle's answers to what the ground station sent."""
        vehicle, link = self.vehicle, self.link
        if vehicle is None or link is None:
            return
        for r in frames:
            if r.bad:
                continue
            if self.first_frame is None:
                self.first_frame = r.t
            with vehicle.lock:
                replies = vehicle.answer(r.msg, self.clock.monotonic())
            for m in replies:
                link.send(m)

    def _tick(self) -> None:
        """The vehicle's telemetry, HEARTBEAT and held answers, until the run ends or --timeout."""
        vehicle, link = self.vehicle, self.link
        end = self.clock.monotonic() + self.cfg.timeout
        while vehicle is not None and link is not None and not self._stop.is_set() and self.clock.monotonic() < end:
            with vehicle.lock:
                out = vehicle.tick(self.clock.monotonic())
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

    # -- the ground station's process ---------------------------------------------------
    def alive_process(self) -> bool:
        return self.node is None or self.node.alive()

    def alive(self) -> bool:
        """A ground station that did its work and exited is not lost: each case starts the run it needs."""
        return True

    def death(self, grace: float = 0.0) -> Death | None:
        """How the ground station ended, when it ended badly (an exit status 0 is its work done)."""
        found = super().death(grace)
        return found if found is not None and (found.code != 0 or found.signal_name) else None

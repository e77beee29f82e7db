"""The runner's session with a ground station (``--protocol mavlink --role gcs``): the runner
is the vehicle (``vehicle.behaviour``: the simulated ArduCopter with a run's
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

The runs, the link, the answers and the ticks are the shared core's
(``harness.link_session.PlayedNodeSession``); this role declares its vehicle, its placeholder
and its monitor. ``clock`` and ``net`` are the run's clock (``harness.clock``) and where its
links open (``harness.link.HostLinks``): the host's by default; the simulator's virtual ones
in ``mcp_conform.sim.gcs_role`` (issue 38), whose session spawns a ground-station model in
place of a process (:meth:`MavlinkGcsSession._spawn`).
"""

from __future__ import annotations

from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.link_session import PlayedNodeSession
from mcp_conform.harness.mavlink_session import HOST_LINKS, Link
from mcp_conform.judge.mavlink_monitor import MavlinkMonitor
from mcp_conform.spec import MAVLINK
from mcp_conform.spec.mavlink import MavlinkSpec
from mcp_conform.vehicle.behaviour import ARDUPILOT, Behaviour, RunnerVehicle

__all__ = ["MavlinkGcsSession"]


class MavlinkGcsSession(PlayedNodeSession):
    """The ground station under test, run afresh for each behaviour of the runner's vehicle
    (attach mode refused), first against ArduPilot's."""

    subject = "the ground station"
    startup_note = ("startup: the runner is the vehicle (system 1, an ArduCopter) and starts the ground station "
                    "against it", "startup: waiting for the ground station's first frame")
    placeholder, tick_thread, segment = "mavlink", "mavlink-vehicle", "gcs-run"
    first_behaviour, played, reference = ARDUPILOT, "vehicle", "GCS"
    link_class = Link
    link: Link | None
    model: RunnerVehicle | None  # the runner's vehicle
    behaviour: Behaviour | None

    def __init__(self, cfg: RunConfig, recorder: Any = None, spec: MavlinkSpec = MAVLINK, *,
                 clock: Clock = REAL, net: Any = HOST_LINKS) -> None:
        super().__init__(cfg, recorder, spec, MavlinkMonitor(spec, roles=("gcs",), complete=True),
                         scheme=cfg.mavlink_transport if cfg.mavlink else "tcp", clock=clock, net=net)

    def make_model(self, behaviour: Behaviour, now: float) -> RunnerVehicle:
        return RunnerVehicle(behaviour, now)

    @property
    def vehicle(self) -> RunnerVehicle | None:
        """The runner's vehicle: the played node (``model``), as the cases read it."""
        return self.model

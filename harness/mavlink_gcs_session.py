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
answers the sender). ``--mavlink1``: the runner's vehicle speaks MAVLink 1 on every link
from the start (:class:`Mavlink1Link`), as ``mcp-vehicle --mavlink1`` and ArduPilot on a port
whose SERIALn_PROTOCOL is 1 do, for a ground station built on MAVLink 1 headers (seed 001's C
programs), whose parser drops MAVLink 2 frames. Every frame goes to the capture's ``/mavlink`` channel from the
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
from mcp_conform.harness.mavlink_session import GCS_COMPID, GCS_SYSID, HOST_LINKS, Link
from mcp_conform.judge.mavlink_monitor import MavlinkMonitor
from mcp_conform.spec import MAVLINK
from mcp_conform.spec.mavlink import MavlinkSpec
from mcp_conform.vehicle.behaviour import ARDUPILOT, Behaviour, RunnerVehicle
from mcp_conform.vehicle.codec import Encoder

__all__ = ["Mavlink1Link", "MavlinkGcsSession"]


class Mavlink1Link(Link):
    """The runner's vehicle's link in MAVLink 1 (``--mavlink1``): each message packed by its
    v1.0 definition, extension fields dropped, by the reference vehicle's own encoder
    (``vehicle.codec.Encoder``, ``mcp-vehicle --mavlink1``); a message MAVLink 1 cannot carry
    (an id above 255) is not sent and takes no sequence number, as ArduPilot on a MAVLink 1
    port. What the ground station sends is read as it comes, MAVLink 1 or 2 (MAV-HB-10)."""

    def __init__(self, transport: str, address: tuple[str, int], recorder: Any = None, *,
                 ids: tuple[int, int] = (GCS_SYSID, GCS_COMPID), **kw: Any) -> None:
        self.v1 = Encoder(ids[0], ids[1], version=1)
        super().__init__(transport, address, recorder, ids=ids, **kw)

    def pack(self, msg: Any) -> tuple[bytes, str]:
        data = self.v1.encode(msg)
        if data:
            self.skip_seq()  # the link's count in step with the frames sent (``next_seq``)
        return data, msg.get_type()

    def send(self, msg: Any) -> float:
        """Pack ``msg`` in MAVLink 1 and send it, unless MAVLink 1 cannot carry it; its send time."""
        with self._send_lock:
            data, name = self.pack(msg)
            return self._send_locked(data, name) if data else self.clock.monotonic()


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
        if cfg.mavlink1:
            self.link_class = Mavlink1Link
            self.startup_note = (f"{self.startup_note[0]}, speaking MAVLink 1 (--mavlink1)", self.startup_note[1])

    def make_model(self, behaviour: Behaviour, now: float) -> RunnerVehicle:
        return RunnerVehicle(behaviour, now)

    @property
    def vehicle(self) -> RunnerVehicle | None:
        """The runner's vehicle: the played node (``model``), as the cases read it."""
        return self.model

"""The runner's session with a MAVLink autopilot (``--protocol mavlink``, role ``vehicle``):
the runner is its ground station, on one link over the whole run, the way a ground station
reaches ArduPilot SITL.

The link is named as pymavlink names it (``mavutil.mavlink_connection``): ``--target
tcp:HOST:PORT`` connects (SITL's 5760; a bare ``HOST:PORT`` is TCP too), ``udp:HOST:PORT``
(``udpin``) listens there for a vehicle that sends to it (SITL's ``--out``), ``udpout:HOST:PORT``
sends to a vehicle that listens and answers each sender. ``--spawn CMD`` starts the vehicle
with ``{target_host}`` ``{target_port}`` filled in, its transport ``--mavlink tcp|udp|udpout``
(default tcp); with neither, the reference vehicle (``mcp-vehicle``) is spawned (embedded).

Frames are packed and parsed by pymavlink's dialect (``spec.MAVLINK.dialect``, ardupilotmega),
MAVLink 2 out; the runner is system 255, component MAV_COMP_ID_MISSIONPLANNER, and sends its
own HEARTBEAT every ``heartbeat_period_s`` (a ground station must, MAV-HB-2). A reader thread
keeps every frame the vehicle sent (:class:`Received`: arrival time, the message or
pymavlink's ``MAVLink_bad_data``, the raw bytes); every frame both ways goes to the capture's
``/mavlink`` channel, from the autopilot's side (``rx``: the vehicle received it from the
runner, ``tx``: the vehicle sent it). The vehicle's identity is taken from its first
HEARTBEAT (MAV-HB-1: the start fails in one line when none comes).

The link and the session are the shared cores' (``harness.link.Link``,
``harness.link_session.LinkSessionBase``), MAVLink their declared parameter: its framing
(:class:`MavlinkFraming`), its encoder (:class:`Link`), its first sign and its beat.
"""

from __future__ import annotations

import shlex
import sys
from dataclasses import dataclass
from functools import cached_property
from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.link import HOST_LINKS, HostLinks
from mcp_conform.harness.link import Link as LinkCore
from mcp_conform.harness.link_session import LinkSessionBase, parse_address
from mcp_conform.judge.mavlink_monitor import MavlinkMonitor
from mcp_conform.spec import MAVLINK
from mcp_conform.spec.mavlink import MavlinkSpec
from mcp_conform.traceio.mavlink import robust_parser, version_of

__all__ = ["HOST_LINKS", "HostLinks", "Link", "MavlinkSession", "Received", "parse_address"]

DIALECT: Any = MAVLINK.dialect
GCS_SYSID = 255
GCS_COMPID = int(DIALECT.MAV_COMP_ID_MISSIONPLANNER)
#: how the spawned reference vehicle (``mcp-vehicle``) serves each transport
_VEHICLE_LINK = {"tcp": "--listen {target_host}:{target_port}",
                 "udpout": "--no-tcp --udp-in {target_host}:{target_port}",
                 "udpin": "--no-tcp --udp-out {target_host}:{target_port}"}


@dataclass(frozen=True)
class Received:
    """One frame the vehicle sent: when it arrived (the run clock's ``monotonic()``), pymavlink's message
    (``MAVLink_bad_data`` for bytes that are no good frame) and its raw bytes."""

    t: float
    msg: Any
    raw: bytes

    @cached_property  # read many times a frame (the cases' scans, the monitor)
    def name(self) -> str:
        return str(self.msg.get_type())

    @cached_property
    def bad(self) -> bool:
        return self.name == "BAD_DATA"

    @property
    def version(self) -> int:
        return version_of(self.raw)

    def describe(self) -> str:
        if self.bad:
            return f"bad data ({self.msg.reason}): {self.raw[:32].hex(' ')}"
        fields = {k: v for k, v in self.msg.to_dict().items() if k != "mavpackettype"}
        return (f"{self.name} v{self.version} from {self.msg.get_srcSystem()}/{self.msg.get_srcComponent()} "
                f"seq {self.msg.get_seq()}: {fields}")


class MavlinkFraming:
    """MAVLink as the link's protocol (``harness.link.Framing``): pymavlink's parser, robust
    (bad bytes kept as BAD_DATA, never raised: ``traceio.mavlink.robust_parser``, the trace
    reader's), and the capture's ``/mavlink`` channel."""

    thread = "mavlink-link"

    def __init__(self) -> None:
        self.parser = robust_parser()

    def deframe(self, data: bytes, t: float) -> list[Received]:
        return [Received(t, m, bytes(m.get_msgbuf())) for m in self.parser.parse_buffer(data) or []]

    def record(self, recorder: Any, direction: str, raw: bytes, t_ns: int, name: str | None) -> None:
        recorder.mavlink(direction, raw, t_ns, msg_type=name)


class Link(LinkCore):
    """The runner's one MAVLink link to the node under test, shared by both roles: the core's
    (``harness.link.Link``: its transports, ``sent_as``/``got_as`` always from the autopilot's
    side, ``sock``, ``on_frames``, ``monitor``, ``clock``, ``net``) with MAVLink's framing; ``ids``
    are the runner's own system and component (a ground station's by default), its frames
    packed as MAVLink 2 with its next sequence number."""

    def __init__(self, transport: str, address: tuple[str, int], recorder: Any = None, *,
                 ids: tuple[int, int] = (GCS_SYSID, GCS_COMPID), **kw: Any) -> None:
        self.encoder = DIALECT.MAVLink(None, srcSystem=ids[0], srcComponent=ids[1])
        super().__init__(MavlinkFraming(), transport, address, recorder, **kw)

    def pack(self, msg: Any) -> tuple[bytes, str]:
        data = bytes(msg.pack(self.encoder))
        self.skip_seq()  # as pymavlink's MAVLink.send counts
        return data, msg.get_type()

    def next_seq(self) -> int:
        """The sequence number the next frame packed takes (a raw frame built by hand uses it
        and :meth:`skip_seq` then)."""
        return int(self.encoder.seq)

    def skip_seq(self) -> None:
        self.encoder.seq = (self.encoder.seq + 1) % 256


def embedded_command(transport: str) -> str:
    """The reference vehicle (``mcp-vehicle``) as the embedded default, on ``transport``."""
    return f"{shlex.quote(sys.executable)} -m mcp_conform.vehicle -q {_VEHICLE_LINK[transport]}"


class MavlinkSession(LinkSessionBase):
    """The vehicle under test over the whole run, and the runner's link to it
    (``harness.link_session.LinkSessionBase``: its first HEARTBEAT awaited, MAV-HB-1)."""

    subject = "the vehicle"
    startup_note = ("startup: the runner joins the vehicle's link as a ground station (system 255) "
                    "and waits for its first HEARTBEAT", "startup: waiting for the vehicle's HEARTBEAT")
    first_sign, first_rule, beat_thread = "HEARTBEAT", "MAV-HB-1", "mavlink-heartbeat"
    link_class = Link
    link: Link | None

    def __init__(self, cfg: RunConfig, recorder: Any = None, spec: MavlinkSpec = MAVLINK, *,
                 clock: Clock = REAL, net: Any = HOST_LINKS) -> None:
        super().__init__(cfg, recorder, spec, MavlinkMonitor(spec, roles=("vehicle",), complete=True),
                         scheme=cfg.mavlink_transport if cfg.mavlink else "tcp", embedded=embedded_command,
                         clock=clock, net=net)
        #: the vehicle's system and component IDs (its first HEARTBEAT's)
        self.vehicle: tuple[int, int] = (0, 0)

    def identified(self, first: Any) -> None:
        self.vehicle = (first.msg.get_srcSystem(), first.msg.get_srcComponent())

    def beat_message(self, link: Any) -> Any:
        """A ground station's HEARTBEAT (MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID): MAV-HB-2."""
        return link.encoder.heartbeat_encode(DIALECT.MAV_TYPE_GCS, DIALECT.MAV_AUTOPILOT_INVALID, 0, 0,
                                             DIALECT.MAV_STATE_ACTIVE)

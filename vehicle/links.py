"""A simulated vehicle for a node that reaches its autopilot by a pymavlink URL of a transport.

``start_for_node(transport)`` serves the vehicle the way the node expects to find it and
returns the URL to give the node (the runner's ``{mavlink}``):

=========  =============================================  ==============================
transport  the vehicle                                    the node's URL
=========  =============================================  ==============================
tcp        listens on TCP, as SITL's port 5760             ``tcp:127.0.0.1:PORT``
udp        sends to a free port from one UDP socket and   ``udp:127.0.0.1:PORT`` (pymavlink:
           answers the sender, as SITL's ``--out``        listen on PORT)
udpin      the same                                       ``udpin:127.0.0.1:PORT``
udpout     listens on UDP and answers each sender         ``udpout:127.0.0.1:PORT``
=========  =============================================  ==============================

Over UDP the vehicle knows the node once the node sends a frame (a HEARTBEAT, as companion
computers send at 1 Hz), so ``SimVehicle.connected`` says the node is on the link.
"""

from __future__ import annotations

from typing import Any

from .ports import free_port
from .server import SimVehicle

TRANSPORTS = ("tcp", "udp", "udpin", "udpout")


def start_for_node(transport: str = "tcp", **settings: Any) -> tuple[SimVehicle, str]:
    """A started ``SimVehicle(**settings)`` and the URL the node connects with.

    Raises ``ValueError`` for an unknown transport and ``OSError`` if a socket cannot open.
    """
    if transport not in TRANSPORTS:
        raise ValueError(f"transport must be one of {', '.join(TRANSPORTS)}: {transport!r}")
    vehicle = SimVehicle(**settings)
    if transport == "tcp":
        vehicle.start("127.0.0.1", 0)
        return vehicle, vehicle.url
    if transport == "udpout":
        vehicle.start(port=None, udp_in=("127.0.0.1", 0))
        return vehicle, vehicle.udp_in_url
    port = free_port()  # below the ephemeral range: no other bind(0) takes it first
    vehicle.start(port=None, udp_out=[("127.0.0.1", port)])
    return vehicle, f"{transport}:127.0.0.1:{port}"

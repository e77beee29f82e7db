"""The runner's vehicle in the simulator (issue 38): ``vehicle.SimVehicle`` itself -- the
simulated ArduCopter a real ``--mavlink`` run starts (``harness.drone_session``'s
``_start_vehicle``) -- on the session's :class:`harness.clock.VirtualClock` and on a simulated
UDP link to the node model's autopilot client (:class:`sim.autopilot.AutopilotClient`), through
the vehicle's seam (``vehicle.seam``: a clock and a net).

The vehicle listens as it does for a node given ``udpout:HOST:PORT`` (``vehicle.links``): it
learns each peer from the peer's first frame (the client's HEARTBEAT) and answers it. A
datagram each way takes ``latency`` virtual seconds; the autopilot link is not impaired (a
real run's is the host's loopback too). A restarted node is a new peer (its client has a port
of its own), as a restarted process's ephemeral port is.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.vehicle import SimVehicle

__all__ = ["VEHICLE_ADDR", "SimUdpEndpoint", "SimVehicleNet", "start_vehicle"]

Address = tuple[str, int]
#: where the vehicle listens (the node's ``{mavlink}`` is ``udpout:`` this)
VEHICLE_ADDR: Address = ("127.0.0.1", 14550)


class SimUdpEndpoint:
    """The vehicle's listening socket on the simulated link (``vehicle.udp.UdpEndpoint``'s
    reading: ``receive`` blocks on the virtual clock)."""

    mode = "in"

    def __init__(self, net: SimVehicleNet, addr: Address) -> None:
        self.net, self.addr = net, addr
        self.destinations: list[Address] = []
        self.sock = self  # ``sock.getsockname()``
        self._cond = net.clock.condition()
        self._queue: deque[tuple[bytes, Address]] = deque()
        self.closed = False

    @property
    def port(self) -> int:
        return self.addr[1]

    def getsockname(self) -> Address:
        return self.addr

    def put(self, data: bytes, src: Address) -> None:
        with self._cond:
            if not self.closed:
                self._queue.append((data, src))
                self._cond.notify_all()

    def receive(self, timeout: float) -> tuple[bytes, Address] | None:
        with self._cond:
            if not self._queue and not self.closed:
                self._cond.wait(timeout)
            return self._queue.popleft() if self._queue else None

    def sendto(self, data: bytes, addr: Address) -> None:
        self.net.to_node(data, (str(addr[0]), int(addr[1])))

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._queue.clear()
            self._cond.notify_all()


class SimVehicleNet:
    """The vehicle's net (``vehicle.seam``) on the virtual clock: its one listening socket, and
    the node models' clients attached by address (:meth:`attach`)."""

    def __init__(self, clock: VirtualClock, latency: float = 50e-6) -> None:
        self.clock, self.latency = clock, latency
        self.endpoint: SimUdpEndpoint | None = None
        self._nodes: dict[Address, Callable[[bytes], None]] = {}

    def open_out(self, destinations: list[Address]) -> Any:
        raise OSError("the simulated vehicle listens (udp_in) only")

    def open_in(self, host: str, port: int) -> SimUdpEndpoint:
        self.endpoint = SimUdpEndpoint(self, (host, port or VEHICLE_ADDR[1]))
        return self.endpoint

    def attach(self, addr: Address, deliver: Callable[[bytes], None]) -> None:
        """A node's client at ``addr``: what the vehicle sends there reaches ``deliver``."""
        self._nodes[addr] = deliver

    def detach(self, addr: Address) -> None:
        self._nodes.pop(addr, None)

    def from_node(self, data: bytes, src: Address) -> None:
        ep = self.endpoint
        if ep is not None:
            self.clock.call_later(self.latency, lambda: ep.put(data, src))

    def to_node(self, data: bytes, addr: Address) -> None:
        def arrive() -> None:
            deliver = self._nodes.get(addr)
            if deliver is not None:
                deliver(data)

        self.clock.call_later(self.latency, arrive)


def start_vehicle(clock: VirtualClock, net: SimVehicleNet, **settings: Any) -> tuple[SimVehicle, str]:
    """A started vehicle on ``clock`` and ``net`` (``SimVehicle(**settings)``) and the node's URL."""
    vehicle = SimVehicle(clock=clock, net=net, **settings)
    vehicle.start(port=None, udp_in=VEHICLE_ADDR)
    return vehicle, vehicle.udp_in_url

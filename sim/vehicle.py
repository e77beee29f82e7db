"""The runner's vehicle in the simulator (issue 38): ``vehicle.SimVehicle`` itself -- the
simulated ArduCopter a real ``--mavlink`` run starts (``harness.drone_session``'s
``_start_vehicle``) -- on the session's :class:`harness.clock.VirtualClock` and on a simulated
UDP link to the node model's autopilot client (:class:`sim.autopilot.AutopilotClient`), through
the vehicle's seam (``vehicle.seam``: a clock and a net).

The vehicle listens as a real run's does (``vehicle.links``): on TCP (``tcp``, the runner's
default: each node connects; its end is the connection's end, the vehicle's ``disconnect``) or
on UDP (``udpout``: it learns each peer from the peer's first frame, the client's HEARTBEAT,
and answers it). ``udp``/``udpin`` (the vehicle sends first, to a port the node listens on) are
not simulated. Bytes take ``latency`` virtual seconds each way; the autopilot link is not
impaired (a real run's is the host's loopback too). A restarted node is a new peer (its
client has a port of its own), as a restarted process's ephemeral port is.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.vehicle import SimVehicle

__all__ = ["SIM_TRANSPORTS", "VEHICLE_ADDR", "VEHICLE_TCP", "SimListener", "SimStream", "SimUdpEndpoint", "SimVehicleNet",
           "start_vehicle"]

Address = tuple[str, int]
#: where the vehicle listens on UDP (the node's ``{mavlink}`` is ``udpout:`` this), and on TCP
VEHICLE_ADDR: Address = ("127.0.0.1", 14550)
VEHICLE_TCP: Address = ("127.0.0.1", 5760)
SIM_TRANSPORTS = ("tcp", "udpout")


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


class SimStream:
    """The vehicle's end of a node's TCP connection: bytes in order, then its end."""

    def __init__(self, net: SimVehicleNet, peer: Address) -> None:
        self.net, self.peer = net, peer
        self._cond = net.clock.condition()
        self._buf = bytearray()
        self.ended = False  # the node's end closed
        self.closed = False  # the vehicle's end closed

    def put(self, data: bytes) -> None:
        with self._cond:
            self._buf += data
            self._cond.notify_all()

    def end(self) -> None:
        with self._cond:
            self.ended = True
            self._cond.notify_all()

    def recv(self, timeout: float) -> bytes | None:
        with self._cond:
            if not self._buf and not self.ended and not self.closed:
                self._cond.wait(timeout)
            if self.closed:
                raise OSError("closed")
            if self._buf:
                data, self._buf = bytes(self._buf), bytearray()
                return data
            return b"" if self.ended else None

    def sendall(self, data: bytes) -> None:
        if self.closed or self.ended:
            raise BrokenPipeError("the node's end is closed")
        self.net.to_node(data, self.peer)

    def settimeout(self, _t: float | None) -> None:
        pass

    def setsockopt(self, *_args: Any) -> None:
        pass

    def shutdown(self, _how: int) -> None:
        self.close()

    def close(self) -> None:
        with self._cond:
            self.closed = True
            self._cond.notify_all()


class SimListener:
    """The vehicle's TCP listener: connections not accepted yet."""

    def __init__(self, net: SimVehicleNet, addr: Address) -> None:
        self.addr = addr
        self.cond = net.clock.condition()
        self.pending: deque[tuple[SimStream, Address]] = deque()
        self.closed = False

    def getsockname(self) -> Address:
        return self.addr

    def close(self) -> None:
        with self.cond:
            self.closed = True
            self.cond.notify_all()


class SimVehicleNet:
    """The vehicle's net (``vehicle.seam``) on the virtual clock: its one listening socket, and
    the node models' clients attached by address (:meth:`attach`)."""

    def __init__(self, clock: VirtualClock, latency: float = 50e-6) -> None:
        self.clock, self.latency = clock, latency
        self.endpoint: SimUdpEndpoint | None = None
        self.listener: SimListener | None = None
        self._nodes: dict[Address, Callable[[bytes], None]] = {}
        self._streams: dict[Address, SimStream] = {}

    def open_out(self, destinations: list[Address]) -> Any:
        raise OSError("the simulated vehicle listens (udp_in) only")

    def open_in(self, host: str, port: int) -> SimUdpEndpoint:
        self.endpoint = SimUdpEndpoint(self, (host, port or VEHICLE_ADDR[1]))
        return self.endpoint

    def listen(self, host: str, port: int) -> SimListener:
        self.listener = SimListener(self, (host, port or VEHICLE_TCP[1]))
        return self.listener

    def accept(self, listener: SimListener, timeout: float) -> tuple[SimStream, Address] | None:
        with listener.cond:
            if not listener.pending and not listener.closed:
                listener.cond.wait(timeout)
            if listener.closed:
                raise OSError("listener closed")
            return listener.pending.popleft() if listener.pending else None

    def recv(self, conn: SimStream, timeout: float) -> bytes | None:
        return conn.recv(timeout)

    def attach(self, addr: Address, deliver: Callable[[bytes], None]) -> None:
        """A node's client at ``addr``: what the vehicle sends there reaches ``deliver``; with a
        TCP listener, the client connects to it."""
        self._nodes[addr] = deliver
        listener = self.listener
        if listener is not None:
            stream = self._streams[addr] = SimStream(self, addr)

            def arrive() -> None:
                with listener.cond:
                    if not listener.closed:
                        listener.pending.append((stream, addr))
                        listener.cond.notify_all()

            self.clock.call_later(self.latency, arrive)

    def detach(self, addr: Address) -> None:
        """The node's end closes (its process ended): over TCP the vehicle reads the end."""
        self._nodes.pop(addr, None)
        stream = self._streams.pop(addr, None)
        if stream is not None:
            self.clock.call_later(self.latency, stream.end)

    def from_node(self, data: bytes, src: Address) -> None:
        stream = self._streams.get(src)
        if stream is not None:
            self.clock.call_later(self.latency, lambda: stream.put(data))
            return
        ep = self.endpoint
        if ep is not None:
            self.clock.call_later(self.latency, lambda: ep.put(data, src))

    def to_node(self, data: bytes, addr: Address) -> None:
        def arrive() -> None:
            deliver = self._nodes.get(addr)
            if deliver is not None:
                deliver(data)

        self.clock.call_later(self.latency, arrive)


def start_vehicle(clock: VirtualClock, net: SimVehicleNet, transport: str = "tcp",
                  **settings: Any) -> tuple[SimVehicle, str]:
    """A started vehicle on ``clock`` and ``net`` (``SimVehicle(**settings)``) serving
    ``transport`` (:data:`SIM_TRANSPORTS`), and the node's URL."""
    if transport not in SIM_TRANSPORTS:
        raise ValueError(f"the simulated vehicle serves {' or '.join(SIM_TRANSPORTS)}, not {transport!r}")
    vehicle = SimVehicle(clock=clock, net=net, **settings)
    if transport == "tcp":
        vehicle.start(*VEHICLE_TCP)
        return vehicle, vehicle.url
    vehicle.start(port=None, udp_in=VEHICLE_ADDR)
    return vehicle, vehicle.udp_in_url

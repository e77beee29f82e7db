"""The vehicle's UDP sockets, as ArduPilot SITL and MAVProxy serve MAVLink over UDP.

* ``--udp-out HOST:PORT`` (repeatable): one socket, bound to an ephemeral port, sends the
  telemetry to every destination (like SITL/MAVProxy ``--out udp:127.0.0.1:14550``) and
  answers whoever writes to it, from the same socket; a peer reaches it with pymavlink's
  ``udpin:HOST:PORT`` (or ``udp:``, the same) on the destination address.
* ``--udp-in HOST:PORT``: a socket bound to HOST:PORT; every address that sends to it is a
  peer that gets the answers and, from then on, the telemetry; a peer reaches it with
  ``udpout:HOST:PORT``.

Each peer address is one link (its own parser, sequence numbers and MAVLink version).
The socket is read by one thread of ``SimVehicle``; this module only opens and reads.
"""

from __future__ import annotations

import contextlib
import select
import socket
from dataclasses import dataclass, field

Address = tuple[str, int]


def parse_hostport(text: str) -> Address:
    """``"127.0.0.1:14550"`` -> ("127.0.0.1", 14550); ValueError naming what is wrong."""
    host, sep, port = text.rpartition(":")
    if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"expected HOST:PORT with a port 0..65535: {text!r}")
    return host, int(port)


@dataclass
class UdpEndpoint:
    """One UDP socket: ``mode`` "out" (destinations) or "in" (listening)."""

    mode: str
    sock: socket.socket
    destinations: list[Address] = field(default_factory=list)

    @classmethod
    def open_out(cls, destinations: list[Address], bind_host: str = "0.0.0.0") -> UdpEndpoint:
        """A socket on an ephemeral port that will send to ``destinations``."""
        resolved = [(socket.gethostbyname(h), p) for h, p in destinations]
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.bind((bind_host, 0))
        except OSError:
            sock.close()
            raise
        return cls("out", sock, resolved)

    @classmethod
    def open_in(cls, host: str, port: int) -> UdpEndpoint:
        """A socket bound to ``host:port`` (0 picks a port)."""
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
        except OSError:
            sock.close()
            raise
        return cls("in", sock)

    @property
    def port(self) -> int:
        return int(self.sock.getsockname()[1])

    def receive(self, timeout: float) -> tuple[bytes, Address] | None:
        """One datagram within ``timeout`` s, or None (also on a socket error)."""
        try:
            readable, _, _ = select.select([self.sock], [], [], timeout)
            if not readable:
                return None
            data, addr = self.sock.recvfrom(65535)
        except (OSError, ValueError):
            return None
        if addr is None:  # shut down by close(): no datagram
            return None
        return data, (str(addr[0]), int(addr[1]))

    def sendto(self, data: bytes, addr: Address) -> None:
        """Send one datagram; a refused or unreachable peer is not an error for UDP."""
        with contextlib.suppress(ConnectionRefusedError):
            self.sock.sendto(data, addr)

    def close(self) -> None:
        """Close the socket, a thread blocked in :meth:`receive` woken first (Linux: a UDP
        socket's shutdown wakes its readers, though it says ENOTCONN)."""
        with contextlib.suppress(OSError):
            self.sock.shutdown(socket.SHUT_RDWR)
        with contextlib.suppress(OSError):
            self.sock.close()

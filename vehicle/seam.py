"""What ``SimVehicle`` reads the time from, starts its threads with and opens its UDP sockets
through: one seam, so that a simulator can run the vehicle on its own clock and link (the
runner's simulator, ``mcp_conform.sim.vehicle``; issue 38). The vehicle imports nothing of the
runner's: both are duck-typed here, and the defaults are the host's clock and sockets, so a
vehicle built without them behaves exactly as before the seam.

A clock has ``monotonic()`` (seconds), ``sleep(s)``, ``condition(lock)`` and ``event()`` (objects
with ``threading.Condition``'s and ``threading.Event``'s methods, whose waits block on that
clock) and ``start_thread(target, name)`` (a daemon thread; its handle has ``join(timeout)`` and
``ident``). A net (:class:`HostNet`'s methods) opens the vehicle's UDP endpoints
(``open_out(destinations)``, ``open_in(host, port)``: what ``vehicle.udp.UdpEndpoint``'s class
methods return, ``mode``, ``destinations``, ``port``, ``sock.getsockname()``,
``receive(timeout)``, ``sendto(data, addr)``, ``close()``) and its TCP listener
(``listen(host, port)``: ``getsockname()``, ``close()``), accepts a connection
(``accept(listener, timeout)``: ``(conn, peer)`` or None) and reads one (``recv(conn,
timeout)``: bytes, b"" at its end, None when nothing came); a connection has ``sendall``,
``settimeout``, ``setsockopt``, ``shutdown`` and ``close``, as a socket.
"""

from __future__ import annotations

import select
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from .udp import UdpEndpoint

__all__ = ["HOST_NET", "REAL_CLOCK", "RealClock"]


class RealClock:
    """The host's clock and threads: ``time.monotonic``, ``threading``."""

    def monotonic(self) -> float:
        return time.monotonic()

    def sleep(self, seconds: float) -> None:
        time.sleep(seconds)

    def condition(self, lock: Any = None) -> threading.Condition:
        return threading.Condition(lock)

    def event(self) -> threading.Event:
        return threading.Event()

    def start_thread(self, target: Callable[[], None], name: str) -> threading.Thread:
        thread = threading.Thread(target=target, name=name, daemon=True)
        thread.start()
        return thread


class HostNet:
    """The host's sockets: UDP by ``vehicle.udp``, TCP by ``socket`` and ``select``."""

    open_out = staticmethod(UdpEndpoint.open_out)
    open_in = staticmethod(UdpEndpoint.open_in)

    @staticmethod
    def listen(host: str, port: int) -> socket.socket:
        sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        try:
            sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            sock.bind((host, port))
            sock.listen(8)
        except OSError:
            sock.close()
            raise
        return sock

    @staticmethod
    def accept(listener: socket.socket, timeout: float) -> tuple[socket.socket, Any] | None:
        readable, _, _ = select.select([listener], [], [], timeout)
        return listener.accept() if readable else None

    @staticmethod
    def recv(sock: socket.socket, timeout: float) -> bytes | None:
        readable, _, _ = select.select([sock], [], [], timeout)
        return sock.recv(65536) if readable else None


#: The defaults of every vehicle: the host's clock and sockets.
REAL_CLOCK = RealClock()
HOST_NET = HostNet()

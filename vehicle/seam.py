"""What ``SimVehicle`` reads the time from, starts its threads with and opens its UDP sockets
through: one seam, so that a simulator can run the vehicle on its own clock and link (the
runner's simulator, ``mcp_conform.sim.vehicle``; issue 38). The vehicle imports nothing of the
runner's: both are duck-typed here, and the defaults are the host's clock and sockets, so a
vehicle built without them behaves exactly as before the seam.

A clock has ``monotonic()`` (seconds), ``sleep(s)``, ``condition(lock)`` and ``event()`` (objects
with ``threading.Condition``'s and ``threading.Event``'s methods, whose waits block on that
clock) and ``start_thread(target, name)`` (a daemon thread; its handle has ``join(timeout)`` and
``ident``). A net has ``open_out(destinations)`` and ``open_in(host, port)``, returning what
``vehicle.udp.UdpEndpoint``'s class methods return: ``mode``, ``destinations``, ``port``,
``sock.getsockname()``, ``receive(timeout)``, ``sendto(data, addr)``, ``close()``. TCP stays on
the host's sockets: a vehicle on another net serves UDP only.
"""

from __future__ import annotations

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


#: The defaults of every vehicle: the host's clock, and UDP sockets of the host.
REAL_CLOCK = RealClock()
HOST_NET = UdpEndpoint

"""A faulty vehicle for the real smoke runs: our reference vehicle (``mcp-vehicle``) behind a
TCP proxy that changes one thing, so that ``mcp-conform --protocol mavlink`` must fail exactly
the rule of that one thing. The faults are ``mcp_conform.sim.vehicle_faults``' (each one's
rewrite and rule are listed there): the same pure rewrites the simulator runs the whole matrix
with (tests/sim/test_mavlink_vehicle_sim.py); here they run on real sockets, a thread each way
(tests/mavlink/vehicle_proxy.py), one lock over both.

    python tests/mavlink/faulty_vehicle.py --listen HOST:PORT --fault NAME [--duration S]
"""

from __future__ import annotations

import contextlib
import socket
import sys
import threading

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2]))  # run as a script
from mcp_conform.sim.vehicle_faults import FAULTS, VEHICLE_SYSID, FaultProxy  # noqa: E402
from tests.mavlink.vehicle_proxy import serve  # noqa: E402


class Proxy:
    """One runner connection through the fault: its rewrites, and the lock over both directions
    (the runner's socket is written from both pumps)."""

    def __init__(self, client: socket.socket, fault: str) -> None:
        self.client, self.fault = client, FaultProxy(fault)
        self.lock = threading.Lock()


def pump(src: socket.socket, dst: socket.socket, proxy: Proxy, vehicle_side: bool, stop: threading.Event) -> None:
    while not stop.is_set():
        try:
            data = src.recv(65536)
        except OSError:
            break
        if not data:
            break
        try:
            with proxy.lock:
                if vehicle_side:
                    proxy.client.sendall(proxy.fault.up(data))
                    continue
                to_vehicle, answer = proxy.fault.down(data)
                if answer:
                    proxy.client.sendall(answer)
            dst.sendall(to_vehicle)
        except OSError:
            break
    stop.set()
    for s in (src, dst):
        with contextlib.suppress(OSError):
            s.shutdown(socket.SHUT_RDWR)


def main() -> int:
    return serve(None, FAULTS, pump, lambda client, vehicle, fault: Proxy(client, fault), ("--sysid", str(VEHICLE_SYSID)))


if __name__ == "__main__":
    sys.exit(main())

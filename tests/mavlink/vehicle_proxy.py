"""A TCP proxy in front of our vehicle (``mcp-vehicle``), the scaffold of the tests' faulty and
fragile vehicles (tests/mavlink/faulty_vehicle.py, tests/fuzz/fragile_vehicle.py): it starts the
vehicle on a port of its own, accepts the runner on ``--listen``, connects each client to the
vehicle and runs a ``pump`` each way, ``(src, dst, state, vehicle_side, stop)``, over a state made
per connection by ``make_state(client, vehicle)``, until ``--duration`` is up or the vehicle ends.
Nagle's algorithm is off on both legs: a frame goes on as it came."""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

from mcp_conform.vehicle.ports import free_port

Pump = Callable[[socket.socket, socket.socket, Any, bool, threading.Event], None]


def serve(argv: Sequence[str] | None, faults: Sequence[str], pump: Pump,
          make_state: Callable[[socket.socket, subprocess.Popen[bytes], str], Any],
          vehicle_args: Sequence[str] = ()) -> int:
    """The proxy's main: ``--listen HOST:PORT --fault NAME --duration S``."""
    p = argparse.ArgumentParser()
    p.add_argument("--listen", required=True)
    p.add_argument("--fault", choices=faults, default="none")
    p.add_argument("--duration", type=float, default=600.0)
    ns = p.parse_args(argv)
    host, port = ns.listen.rsplit(":", 1)
    vport = free_port(kind=socket.SOCK_STREAM)
    vehicle = subprocess.Popen([sys.executable, "-m", "mcp_conform.vehicle", "-q", "--listen", f"127.0.0.1:{vport}",
                                *vehicle_args, "--duration", str(ns.duration)])
    server = socket.create_server((host, int(port)))
    server.settimeout(0.5)
    end = time.monotonic() + ns.duration
    try:
        while time.monotonic() < end and vehicle.poll() is None:
            try:
                client, _ = server.accept()
            except TimeoutError:
                continue
            upstream = None
            while upstream is None and time.monotonic() < end:
                try:
                    upstream = socket.create_connection(("127.0.0.1", vport), timeout=1.0)
                except OSError:
                    time.sleep(0.05)
            if upstream is None:
                break
            upstream.settimeout(None)
            for s in (client, upstream):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            stop = threading.Event()
            state = make_state(client, vehicle, ns.fault)
            threads = [threading.Thread(target=pump, args=(upstream, client, state, True, stop), daemon=True),
                       threading.Thread(target=pump, args=(client, upstream, state, False, stop), daemon=True)]
            for t in threads:
                t.start()
            while not stop.wait(0.5) and time.monotonic() < end:
                pass
    finally:
        vehicle.terminate()
        vehicle.wait(5)
    return 0

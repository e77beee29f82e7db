"""A TCP proxy in front of our vehicle (``mcp-vehicle``), the scaffold of the tests' faulty and
fragile vehicles (tests/mavlink/faulty_vehicle.py, tests/fuzz/fragile_vehicle.py): it starts the
vehicle on a port of its own, accepts the runner on ``--listen``, connects each client to the
vehicle and runs a ``pump`` each way, ``(src, dst, state, vehicle_side, stop)``, over a state made
per connection by ``make_state(client, vehicle)``, until ``--duration`` is up or the vehicle ends.
Nagle's algorithm is off on both legs: a frame goes on as it came.

The vehicle is ``mcp-vehicle``'s own main (``vehicle.cli.main``) in a child the proxy forks
(:class:`ForkedVehicle`) before it opens a socket or starts a thread: a process of its own, as
``python -m mcp_conform.vehicle`` would be, which starts with the vehicle's modules the proxy
imported already instead of importing them again in a second interpreter (about 0.2 CPU s of
each start; the fuzz tests start these proxies about sixty times)."""

from __future__ import annotations

import argparse
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Callable, Sequence
from typing import Any

from mcp_conform.vehicle.ports import free_port

Pump = Callable[[socket.socket, socket.socket, Any, bool, threading.Event], None]


class ForkedVehicle:
    """``mcp-vehicle ARGS`` in a forked child of this (single-threaded) process, seen as
    ``subprocess.Popen`` sees its child: ``pid``, ``poll``, ``wait``, ``terminate``, ``kill``,
    ``returncode`` (a signal as its negative number)."""

    def __init__(self, args: Sequence[str]) -> None:
        from mcp_conform.vehicle import cli

        assert threading.active_count() == 1, "fork before any thread starts"
        self.args, self.returncode = list(args), None
        self.pid = os.fork()
        if self.pid == 0:  # the vehicle: its main's exit status, as the command's
            code = 1
            try:
                code = cli.main(self.args)
            except SystemExit as exc:  # argparse's usage errors
                code = exc.code if isinstance(exc.code, int) else 1
            except BaseException:  # as the interpreter ends on one: its traceback, exit 1
                traceback.print_exc()
            finally:
                for stream in (sys.stdout, sys.stderr):
                    stream.flush()
                os._exit(code)

    def poll(self) -> int | None:
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self, timeout: float | None = None) -> int:
        end = None if timeout is None else time.monotonic() + timeout
        while self.poll() is None:
            if end is not None and time.monotonic() >= end:
                raise subprocess.TimeoutExpired(["mcp-vehicle", *self.args], timeout or 0.0)
            time.sleep(0.01)
        assert self.returncode is not None
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, sig)

    def terminate(self) -> None:
        self.send_signal(signal.SIGTERM)

    def kill(self) -> None:
        self.send_signal(signal.SIGKILL)


def serve(argv: Sequence[str] | None, faults: Sequence[str], pump: Pump,
          make_state: Callable[[socket.socket, ForkedVehicle, str], Any],
          vehicle_args: Sequence[str] = ()) -> int:
    """The proxy's main: ``--listen HOST:PORT --fault NAME --duration S``."""
    p = argparse.ArgumentParser()
    p.add_argument("--listen", required=True)
    p.add_argument("--fault", choices=faults, default="none")
    p.add_argument("--duration", type=float, default=600.0)
    ns = p.parse_args(argv)
    host, port = ns.listen.rsplit(":", 1)
    vport = free_port(kind=socket.SOCK_STREAM)
    vehicle = ForkedVehicle(["-q", "--listen", f"127.0.0.1:{vport}", *vehicle_args, "--duration", str(ns.duration)])
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

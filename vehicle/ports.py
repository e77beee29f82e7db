"""Ports for another process to bind: a spawned node's MCP socket, a tool's ``--live``
server, the UDP port a node's autopilot link listens on (``vehicle.links``).

A port from bind(0), closed and handed on, can be handed out again by the kernel to the next
bind(0) anywhere on the host before its new owner binds it; one chosen below the kernel's
ephemeral range can be taken only by an explicit bind.

Two processes on one host may pick the same free port before either's node binds it; nodes
that set SO_REUSEADDR then both bind it, and the kernel gives every unicast datagram to the
one bound last until it closes: the other node goes deaf, for seconds, and is judged so (a
soak's correct manager "did not ACK" a Mission_Ready copy while another test's node held its
port). So each port handed out is also reserved host-wide for ``RESERVE_S`` seconds: a file
in a per-user directory of the temporary directory, claimed under a lock; no process using
this module hands it out again meanwhile.
"""

from __future__ import annotations

import collections
import contextlib
import os
import random
import socket
import tempfile
import threading
import time
from pathlib import Path

try:
    import fcntl
except ImportError:  # no POSIX locks (Windows): the pick's bind check and _RECENT still hold
    fcntl = None  # type: ignore[assignment]

_PICK = random.SystemRandom()
#: the ports this process handed out last: a port is free until its new owner binds it, so
#: two calls before either owner starts (a drone's port and its manager's) could get the same
#: one (a CI run: the drone and the manager on one port, the mission never ended)
_RECENT: collections.deque[int] = collections.deque(maxlen=256)
_LOCK = threading.Lock()
#: seconds a port handed out stays reserved for its new owner, host-wide
RESERVE_S = 120.0
#: well-known ports in the pick's range that other software binds by default (MAVLink's
#: ground station and offboard ports, PX4 SITL's): never handed out
_WELL_KNOWN = (range(14500, 14600), range(18570, 18580))


def ephemeral_low() -> int:
    """The lowest port the kernel hands out by itself (Linux's ip_local_port_range)."""
    try:
        with open("/proc/sys/net/ipv4/ip_local_port_range", encoding="ascii") as f:
            return int(f.read().split()[0])
    except (OSError, ValueError, IndexError):
        return 0


def free_port(host: str = "127.0.0.1", kind: int = socket.SOCK_DGRAM) -> int:
    """A port (UDP by default, ``socket.SOCK_STREAM`` for TCP) free now for another process to
    bind, chosen below the kernel's ephemeral range where the system has one: a port from
    bind(0) was handed out again to another process's socket while a spawned node was still
    starting (a CI run lost a replay to "the node exited with code 2" that way; a test's
    client reached a just-started drone's autopilot link, its bind(0), on the port it had
    chosen for the drone's ``--live`` server); outside that range only an explicit bind can
    take it. Never one this process handed out among its last 256 (``_RECENT``)."""
    with _LOCK:
        port = _pick(host, kind)
        _RECENT.append(port)
        return port


def _pick(host: str, kind: int) -> int:
    low = ephemeral_low()
    if low > 12000:
        for _ in range(50):
            port = _PICK.randrange(10000, low)
            if port in _RECENT or any(port in r for r in _WELL_KNOWN):
                continue
            with socket.socket(socket.AF_INET, kind) as s:
                try:
                    s.bind((host, port))
                except OSError:
                    continue
            if reserve(port, kind):
                return port
    for _ in range(50):
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind((host, 0))
            port = int(s.getsockname()[1])
        if port not in _RECENT and reserve(port, kind):
            return port
    return port


def _reservations() -> Path | None:
    """The host-wide reservation directory (per user), or None where it cannot be made."""
    path = Path(tempfile.gettempdir()) / f"mcp-conform-ports-{os.getuid()}"
    try:
        path.mkdir(mode=0o700, exist_ok=True)
    except OSError:
        return None
    return path


def reserve(port: int, kind: int = socket.SOCK_DGRAM, now: float | None = None) -> bool:
    """Reserve ``port`` host-wide for ``RESERVE_S`` s: False when another call (any process)
    reserved it less than that ago. Where no reservation can be written, True (the pick's own
    bind check and ``_RECENT`` still hold)."""
    where = _reservations() if fcntl is not None else None
    if where is None:
        return True
    name = where / f"{'tcp' if kind == socket.SOCK_STREAM else 'udp'}-{port}"
    now = time.time() if now is None else now
    try:
        with open(where / ".lock", "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            with contextlib.suppress(FileNotFoundError):
                if now - name.stat().st_mtime < RESERVE_S:
                    return False
            name.touch()
            os.utime(name, (now, now))
            return True
    except OSError:
        return True

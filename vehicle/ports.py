"""Ports for another process to bind: a spawned node's MCP socket, a tool's ``--live``
server, the UDP port a node's autopilot link listens on (``vehicle.links``).

A port from bind(0), closed and handed on, can be handed out again by the kernel to the next
bind(0) anywhere on the host before its new owner binds it; one chosen below the kernel's
ephemeral range can be taken only by an explicit bind.
"""

from __future__ import annotations

import collections
import random
import socket
import threading

_PICK = random.SystemRandom()
#: the ports this process handed out last: a port is free until its new owner binds it, so
#: two calls before either owner starts (a drone's port and its manager's) could get the same
#: one (a CI run: the drone and the manager on one port, the mission never ended)
_RECENT: collections.deque[int] = collections.deque(maxlen=256)
_LOCK = threading.Lock()


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
            if port in _RECENT:
                continue
            with socket.socket(socket.AF_INET, kind) as s:
                try:
                    s.bind((host, port))
                except OSError:
                    continue
                return port
    for _ in range(50):
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind((host, 0))
            port = int(s.getsockname()[1])
        if port not in _RECENT:
            return port
    return port

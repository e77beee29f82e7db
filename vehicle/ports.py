"""Ports for another process to bind: a spawned node's MCP socket, a tool's ``--live``
server, the UDP port a node's autopilot link listens on (``vehicle.links``).

A port from bind(0), closed and handed on, can be handed out again by the kernel to the next
bind(0) anywhere on the host before its new owner binds it; one chosen below the kernel's
ephemeral range can be taken only by an explicit bind.
"""

from __future__ import annotations

import random
import socket

_PICK = random.SystemRandom()


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
    take it."""
    low = ephemeral_low()
    if low > 12000:
        for _ in range(50):
            port = _PICK.randrange(10000, low)
            with socket.socket(socket.AF_INET, kind) as s:
                try:
                    s.bind((host, port))
                except OSError:
                    continue
                return port
    with socket.socket(socket.AF_INET, kind) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])

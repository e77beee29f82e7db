"""The ports the runner gives spawned nodes are chosen outside the kernel's ephemeral range,
so no other process's socket is handed the same port while the node starts."""

from __future__ import annotations

import socket

import pytest

from mcp_conform.harness.session_base import free_port
from mcp_conform.vehicle.ports import ephemeral_low


@pytest.mark.parametrize("kind", [socket.SOCK_DGRAM, socket.SOCK_STREAM], ids=["udp", "tcp"])
def test_a_nodes_port_is_free_and_below_the_ephemeral_range(kind):
    """UDP for a node's MCP socket; TCP for a tool's ``--live`` server or an Nsqd backend (a
    loaded CI run's test, given a TCP port from bind(0) for a drone's ``--live``, reached the
    drone's autopilot link, which bind(0) had handed the same port)."""
    low = ephemeral_low()
    if low <= 12000:
        pytest.skip(f"no ephemeral range above 12000 here ({low}): bind(0) is all there is")
    ports = {free_port(kind=kind) for _ in range(20)}
    assert all(10000 <= p < low for p in ports), ports
    for p in ports:  # each is free to bind
        with socket.socket(socket.AF_INET, kind) as s:
            s.bind(("127.0.0.1", p))

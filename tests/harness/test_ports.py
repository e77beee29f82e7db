"""The ports the runner gives spawned nodes are chosen outside the kernel's ephemeral range,
so no other process's socket is handed the same port while the node starts."""

from __future__ import annotations

import socket

import pytest

from harness.session_base import _ephemeral_low, free_udp_port


def test_a_nodes_port_is_free_and_below_the_ephemeral_range():
    low = _ephemeral_low()
    if low <= 12000:
        pytest.skip(f"no ephemeral range above 12000 here ({low}): bind(0) is all there is")
    ports = {free_udp_port() for _ in range(20)}
    assert all(10000 <= p < low for p in ports), ports
    for p in ports:  # each is free to bind
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            s.bind(("127.0.0.1", p))

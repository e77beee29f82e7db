"""``vehicle.ports.free_port``: a port free for another process to bind, never one handed out
just before (two ports taken one after the other, before either owner binds, are distinct)."""

from __future__ import annotations

import socket

from mcp_conform.vehicle import ports


def test_ports_handed_out_one_after_another_are_distinct_though_none_is_bound():
    got = [ports.free_port() for _ in range(200)]
    assert len(set(got)) == len(got)


def test_a_recent_port_is_not_handed_out_again_even_when_the_pick_draws_it(monkeypatch):
    first = ports.free_port()
    draws = iter([first, first, first])

    class Pick:
        @staticmethod
        def randrange(a: int, b: int) -> int:
            return next(draws, a + (first - a + 1) % (b - a))

    monkeypatch.setattr(ports, "_PICK", Pick)
    second = ports.free_port()
    assert second != first
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", second))  # and it is free

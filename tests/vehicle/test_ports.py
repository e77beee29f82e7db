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


def test_a_port_handed_out_is_reserved_host_wide_until_its_reservation_expires(tmp_path, monkeypatch):
    """Another process picking the same port before its owner binds it must not get it: with
    SO_REUSEADDR both would bind, and the later one would take every datagram (a soak's
    correct manager went deaf for 7 s that way)."""
    monkeypatch.setattr(ports.tempfile, "gettempdir", lambda: str(tmp_path))
    port = ports.free_port()
    assert not ports.reserve(port)  # what another process's pick would be told
    assert ports.reserve(port, socket.SOCK_STREAM)  # TCP's port of that number is another
    later = ports.time.time() + ports.RESERVE_S + 1
    assert ports.reserve(port, now=later)  # expired: handed out again
    assert not ports.reserve(port, now=later)


def test_a_port_reserved_by_another_process_is_not_handed_out(tmp_path, monkeypatch):
    import subprocess
    import sys

    monkeypatch.setattr(ports.tempfile, "gettempdir", lambda: str(tmp_path))
    taken = ports.free_port()
    code = ("import tempfile,sys; tempfile.tempdir=sys.argv[1]\n"
            "from mcp_conform.vehicle import ports\n"
            f"print(ports.reserve({taken}))")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True,
                         text=True, timeout=60, check=True).stdout.strip()
    assert out == "False"


def test_well_known_mavlink_ports_are_never_handed_out(monkeypatch):
    draws = iter([14550, 14540, 18570])

    class Pick:
        @staticmethod
        def randrange(a: int, b: int) -> int:
            return next(draws, 20001)

    monkeypatch.setattr(ports, "_PICK", Pick)
    monkeypatch.setattr(ports, "_RECENT", ports.collections.deque(maxlen=256))
    monkeypatch.setattr(ports, "reserve", lambda port, kind=0: True)
    if ports.ephemeral_low() > 20001:
        assert ports.free_port() == 20001

"""The soak's medium records each node's datagram at the kernel's receive time, not when its
thread got round to reading it: on a loaded host that pickup lags, and the lag would widen the
gaps between a node's copies in the capture the monitor judges (a false MCP-RTX-3)."""

from __future__ import annotations

import socket
import sys
import time
from collections.abc import Iterator
from contextlib import contextmanager

import pytest

from mcp_conform.harness.impair import Impairment, parse_impairment
from mcp_conform.soak.medium import Medium
from mcp_conform.spec.codec import Action, Message, encode


class _Recorder:
    def __init__(self) -> None:
        self.records: list[tuple[str, int | None]] = []

    def datagram(self, direction, data, addr, t_ns=None, local=None) -> None:
        self.records.append((direction, t_ns))

    def impairment(self, decision, data) -> None:
        pass


@contextmanager
def _medium(rec: _Recorder, run_delays: dict | None = None) -> Iterator[tuple[socket.socket, Medium]]:
    """A one-drone medium recording the manager's view with ``rec`` (not serving: the test
    reads when it chooses), and the manager's socket."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as manager, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as drone:
        manager.bind(("127.0.0.1", 0))
        drone.bind(("127.0.0.1", 0))
        medium = Medium([1], Impairment(parse_impairment("seed=1")), manager.getsockname(), {1: drone.getsockname()},
                        {"manager": rec}, "127.0.0.1", run_delays)
        try:
            yield manager, medium
        finally:
            medium.stop()


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="kernel receive times (SO_TIMESTAMPNS) are Linux's")
def test_a_nodes_datagram_is_recorded_when_it_arrived_not_when_it_was_read():
    rec = _Recorder()
    with _medium(rec) as (manager, medium):
        time.sleep(0.05)  # the kernel stamps datagrams a moment after it is asked to
        sent = time.time_ns()
        manager.sendto(encode(Message(1, 0, 3, Action.START_MISSION, None)), medium.front_addr)
        time.sleep(0.3)  # the medium's thread is late to read it
        medium._read(medium.front, None, time.monotonic())
    tx = [t for d, t in rec.records if d == "tx"]
    assert len(tx) == 1 and tx[0] is not None
    assert 0 <= tx[0] - sent < 100_000_000, (tx[0] - sent) / 1e6  # ms after the send, not 300 ms


class _DelayRecorder(_Recorder):
    def datagram(self, direction, data, addr, t_ns=None, local=None, run_delay=None) -> None:
        self.records.append((direction, run_delay))


def test_a_nodes_own_messages_carry_its_run_delay():
    """MCP-RTX-3 under load (``judge.spacing``): ``mcp-soak``'s monitor gets each node's run
    delay on the messages that node sent, as the runner's does; not on ACKs."""
    rec = _DelayRecorder()
    with _medium(rec, {"manager": lambda: 777, "drone1": lambda: 999}) as (manager, medium):
        manager.sendto(encode(Message(1, 0, 3, Action.START_MISSION, None)), medium.front_addr)
        manager.sendto(encode(Message(1, 0, 4, Action.ACK, 9)), medium.front_addr)
        deadline = time.monotonic() + 2.0
        while len([d for d, _ in rec.records if d == "tx"]) < 2 and time.monotonic() < deadline:
            medium._read(medium.front, None, time.monotonic())
            time.sleep(0.01)
    assert [rd for d, rd in rec.records if d == "tx"] == [777, None]

"""The runner's receive times are the kernel's where it gives them (Linux SO_TIMESTAMPNS):
a datagram's time is when it arrived, not when the runner's receive thread got the CPU, so
on a loaded machine the gaps between a node's copies (MCP-RTX-3) and its ACK latency
(MCP-ACK-7) stay the node's."""

from __future__ import annotations

import socket
import struct
import sys
import time

import pytest

from mcp_conform.harness.driver import SO_TIMESTAMPNS, TargetDriver, arrival_ns, kernel_timestamps
from mcp_conform.spec.codec import Action, Message, encode


def test_the_ancillary_timespec_is_read_and_others_are_not():
    ts = struct.pack("@ll", 1_700_000_000, 123_456_789)
    assert arrival_ns([(socket.SOL_SOCKET, SO_TIMESTAMPNS, ts)]) == 1_700_000_000_123_456_789
    assert arrival_ns([(socket.SOL_SOCKET, SO_TIMESTAMPNS + 1, ts), (socket.IPPROTO_IP, 1, b"x")]) is None
    assert arrival_ns([]) is None


def test_a_datagram_takes_its_arrival_time_not_its_pickup_time():
    """``_arrive`` given the kernel's time 0.2 s ago dates the datagram 0.2 s back, on both
    clocks; a time from the future or far in the past (a clock step) is not believed."""
    drv = TargetDriver(("127.0.0.1", 9), ("127.0.0.1", 0))
    data = encode(Message(0, 1, 5, Action.ACK, 4))
    now_ns, now = time.time_ns(), time.monotonic()
    drv._arrive(data, ("127.0.0.1", 9), now_ns - 200_000_000)
    d = drv.received(0)[0]
    assert abs((now - d.t) - 0.2) < 0.05 and abs((now_ns - d.t_ns) / 1e9 - 0.2) < 0.05
    for wrong in (time.time_ns() + 10**9, time.time_ns() - 60 * 10**9):
        drv._arrive(data, ("127.0.0.1", 9), wrong)
        assert abs(drv.received(0)[-1].t - time.monotonic()) < 0.05


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SO_TIMESTAMPNS is Linux's")
def test_the_driver_asks_the_kernel_for_receive_times():
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    assert kernel_timestamps(probe)
    probe.close()
    drv = TargetDriver(("127.0.0.1", 9), ("127.0.0.1", 0))
    listen = drv.open()
    try:
        assert drv._kernel_times
        time.sleep(0.1)  # the kernel enables receive timestamps a moment after asking
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
            sent = time.time_ns()
            s.sendto(encode(Message(0, 1, 7, Action.ACK, 3)), ("127.0.0.1", listen[1]))
        got = drv.wait_for(lambda d: True, 2.0)
        assert got is not None and 0 <= got.t_ns - sent < 10**9
    finally:
        drv.close()


class _PreemptedClocks:
    """Fake clocks of one timeline (ns): every read advances it 1 µs, and the thread is
    preempted (``pause`` ns) between the first monotonic read and the wall-clock read after
    it — the moment the old conversion put into its offset."""

    OFFSET = 1_700_000_000 * 10**9  # wall clock minus monotonic

    def __init__(self, pause: int) -> None:
        self.now, self.pause, self.reads = 10**12, pause, 0

    def _tick(self) -> int:
        self.now += 1_000
        return self.now

    def monotonic(self) -> float:
        return self.monotonic_ns() / 1e9

    def monotonic_ns(self) -> int:
        self.reads += 1
        t = self._tick()
        if self.reads == 1:
            self.now += self.pause
        return t

    def time_ns(self) -> int:
        return self._tick() + self.OFFSET


def test_a_preempted_receive_thread_does_not_date_a_datagram_earlier(monkeypatch):
    """The kernel's receive time converted to the monotonic clock stays the arrival time when
    the receive thread is preempted between its clock reads: a manager's reply to the runner's
    ACK was dated before that ACK (a false MCP-BLK-1 under load) when the offset between the
    clocks was read across the pause."""
    import mcp_conform.harness.clock as clock  # the driver's clock reads the host's through it

    clocks = _PreemptedClocks(pause=30_000_000)  # 30 ms off the CPU
    monkeypatch.setattr(clock.time, "monotonic", clocks.monotonic)
    monkeypatch.setattr(clock.time, "monotonic_ns", clocks.monotonic_ns)
    monkeypatch.setattr(clock.time, "time_ns", clocks.time_ns)
    drv = TargetDriver(("127.0.0.1", 9), ("127.0.0.1", 0))
    arrived = clocks.now + clocks.OFFSET - 1_000_000  # 1 ms before the receive thread woke
    drv._arrive(encode(Message(0, 1, 5, Action.ACK, 4)), ("127.0.0.1", 9), arrived)
    d = drv.received(0)[0]
    assert d.t_ns == arrived
    assert abs(d.t * 1e9 - (arrived - clocks.OFFSET)) < 100_000  # within 0.1 ms, not 30 ms early


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="SO_TIMESTAMPNS and /proc/net/udp are Linux's")
@pytest.mark.parametrize("answers", [True, False])
def test_a_reply_read_late_behind_a_backlog_counts_by_its_arrival_time(answers):
    """The node answers the WP_Off at once, but 150 datagrams it sent before are still unread
    and the runner's receive thread takes 10 ms over each (a loaded host, a recorder): the ACK
    is read ~1.5 s after it came, past the exchange's 0.3 s. It counts: it arrived in time (a
    loaded CI run's flood probe, ACKed in 0.2 ms, said "no ACK after 5 copies", MCP-ROB-7). A
    node that does not answer is still unanswered once the backlog is read."""
    from mcp_conform.harness.driver import read_header

    node = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    node.bind(("127.0.0.1", 0))
    node.settimeout(2.0)
    drv = TargetDriver(("127.0.0.1", node.getsockname()[1]), ("127.0.0.1", 0))
    listen = drv.open()
    drv.add_observer(lambda direction, data, addr, t_ns: time.sleep(0.01) if direction == "rx" else None)
    try:
        time.sleep(0.1)  # the kernel enables receive timestamps a moment after asking
        junk = encode(Message(0, 1, 1, Action.ACK, 0))
        for _ in range(150):
            node.sendto(junk, ("127.0.0.1", listen[1]))
        sent = drv.send(Action.WP_OFF)
        data, addr = node.recvfrom(65535)
        h = read_header(data)
        assert h is not None
        if answers:
            node.sendto(encode(Message(h[1], h[0], 2, Action.ACK, h[2])), addr)
        ex = drv.exchange(sent, rto=0.1, copies=3)
        assert ex.acked is answers  # counted only if it arrived by the last wait's end
    finally:
        drv.close()
        node.close()

"""The run's observers miss nothing the driver received before they were added (issue 38).

``driver.open()`` starts the receiver thread; the capture (and the run's monitor) are added by
``observe_run`` after it. In attach mode the node already runs: a datagram that came in between
was in the driver's list but not in the capture. Here, on a real loopback socket, the window is
held open until such a datagram has been recorded by the driver (the event itself, bounded),
for the manager role's session (``ManagerSession.open``) and for the driver alone.
"""

from __future__ import annotations

import socket
import threading

import pytest

from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import TargetDriver
from mcp_conform.harness.manager_session import ManagerSession
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.traceio.reader import open_capture
from mcp_conform.traceio.recorder import McapRecorder
from mcp_conform.vehicle.ports import free_port

#: a datagram an attached manager may send at any time: a WP_Off to drone 1
EARLY = encode(Message(1, 0, 77, Action.WP_OFF, None))
#: drone 1's Mission_Ready to the runner (ID 0): a driver that ACKs ACKs it
READY = encode(Message(0, 1, 77, Action.MISSION_READY, None))


@pytest.fixture
def told(monkeypatch):
    """Bytes -> an event set once the driver has told its observers of a datagram of them (or
    kept it for them): the receiver thread tells them after it records the datagram."""
    events: dict[bytes, threading.Event] = {EARLY: threading.Event(), READY: threading.Event()}
    real = TargetDriver._notify

    def notify(self, direction, data, *args, **kw):
        real(self, direction, data, *args, **kw)
        if direction == "rx" and data in events:
            events[data].set()

    monkeypatch.setattr(TargetDriver, "_notify", notify)
    return events


@pytest.fixture
def sender():
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", free_port()))
    yield s
    s.close()


def test_the_manager_sessions_capture_holds_a_datagram_from_before_observe_run(tmp_path, sender, told, monkeypatch):
    """Before the fix the capture held no datagram at all (it came before the recorder was added)."""
    real_open = TargetDriver.open

    def open_and_hear_one(self: TargetDriver):
        addr = real_open(self)
        sender.sendto(EARLY, ("127.0.0.1", addr[1]))
        assert told[EARLY].wait(10.0)  # recorded, and its observers told: none yet
        return addr

    monkeypatch.setattr(TargetDriver, "open", open_and_hear_one)
    path = tmp_path / "run.mcap"
    recorder = McapRecorder(path)
    session = ManagerSession(RunConfig(role="manager", target=sender.getsockname(),
                                       listen=("127.0.0.1", free_port()), rto=0.2, ack_window=0.25),
                             recorder=recorder)
    try:
        session.open()
        drv = session.driver
        assert drv is not None and [d.data for d in drv.received()] == [EARLY]
    finally:
        session.close()
        recorder.close()
    got = [(d.direction, d.data, d.src_addr) for d in open_capture(path).datagrams()]
    assert got == [("rx", EARLY, sender.getsockname())]


def test_observers_added_at_once_hear_what_came_before_in_order_and_later_ones_do_not(sender, told):
    """The first ``add_observers`` call hands its observers what the driver received and sent
    since ``open``, in order, then everything live; an observer added later hears from then on."""
    drv = TargetDriver(sender.getsockname(), ("127.0.0.1", free_port()))
    drv.auto_ack = lambda d: False
    first: list[tuple[str, bytes]] = []
    second: list[tuple[str, bytes]] = []
    heard = threading.Event()

    def hear(direction: str, data: bytes, addr, t_ns: int) -> None:
        second.append((direction, data))
        heard.set()

    try:
        listen = drv.open()
        sender.sendto(READY, listen)
        assert told[READY].wait(10.0)
        ack = drv.send_ack(77, dst=1)  # (told, or kept, before it returns)
        drv.add_observers([lambda direction, data, addr, t_ns: first.append((direction, data))])
        assert first == [("rx", READY), ("tx", ack.data)]
        drv.add_observer(hear)
        assert second == []
        later = encode(Message(0, 1, 78, Action.MISSION_READY, None))
        sender.sendto(later, listen)
        assert heard.wait(10.0)
        ack2 = drv.send_ack(78, dst=1)
    finally:
        drv.close()
    assert first[2:] == second == [("rx", later), ("tx", ack2.data)]

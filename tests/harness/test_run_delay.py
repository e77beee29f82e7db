"""The spawned node's run delay (``harness.run_delay``): read from /proc for the process, its
threads and its descendants, and carried on every non-ACK datagram the driver receives and to
its observers (MCP-RTX-3 excuses a copy the loaded host made late, ``judge.spacing``)."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import pytest

from mcp_conform.harness.driver import TargetDriver
from mcp_conform.harness.run_delay import delay_for, run_delay_ns, takes_run_delay
from mcp_conform.spec.codec import Action, Message, encode

NODE = ("127.0.0.1", 9)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc/<pid>/task/*/schedstat is Linux's")
def test_our_own_run_delay_is_an_int_on_linux():
    rd = run_delay_ns(os.getpid())
    assert isinstance(rd, int) and rd >= 0


def _task(root: Path, pid: int, tid: int, delay: int, children: str = "") -> None:
    d = root / str(pid) / "task" / str(tid)
    d.mkdir(parents=True)
    (d / "schedstat").write_text(f"123456 {delay} 7\n")
    (d / "children").write_text(children)


def test_every_thread_and_every_descendant_counts(tmp_path):
    """A spawn command may be a shell: its child's (and grandchild's) waiting counts too."""
    _task(tmp_path, 10, 10, 100, "11 ")  # the shell
    _task(tmp_path, 11, 11, 50, "13")  # the node, with a second thread
    _task(tmp_path, 11, 12, 7)
    _task(tmp_path, 13, 13, 1000)
    _task(tmp_path, 20, 20, 99999)  # not a descendant
    assert run_delay_ns(10, str(tmp_path)) == 1157
    assert run_delay_ns(11, str(tmp_path)) == 1057
    assert run_delay_ns(42, str(tmp_path)) is None  # no such process
    assert run_delay_ns(10, str(tmp_path / "none")) is None  # no /proc at all


def test_only_a_nodes_own_messages_get_a_reading():
    read = lambda: 42  # noqa: E731
    assert delay_for(encode(Message(5, 1, 3, Action.WP_OFF, None)), read) == 42
    assert delay_for(encode(Message(5, 1, 3, Action.ACK, 2)), read) is None
    assert delay_for(b"garbage", read) is None
    assert delay_for(encode(Message(5, 1, 3, Action.WP_OFF, None)), None) is None

    def broken() -> int:
        raise OSError("gone")
    assert delay_for(encode(Message(5, 1, 3, Action.WP_OFF, None)), broken) is None


def test_the_driver_keeps_it_and_hands_it_to_observers_that_take_it():
    drv = TargetDriver(NODE, ("127.0.0.1", 0))
    drv.run_delay = lambda: 4242
    old, new = [], []
    drv.add_observer(lambda direction, data, addr, t_ns: old.append(data))  # a 4-parameter observer
    drv.add_observer(lambda direction, data, addr, t_ns, run_delay=None: new.append(run_delay))
    msg = encode(Message(5, 1, 3, Action.WP_OFF, None))  # (not to the runner: no auto ACK)
    ack = encode(Message(5, 1, 4, Action.ACK, 2))
    drv._arrive(msg, NODE)
    drv._arrive(ack, NODE)
    assert [d.run_delay for d in drv.received()] == [4242, None]
    assert old == [msg, ack] and new == [4242, None]  # the 4-parameter one still gets everything
    drv.run_delay = None  # attach mode: nothing known
    drv._arrive(msg, NODE)
    assert drv.received()[-1].run_delay is None and new[-1] is None
    drv.remove_observer(drv._observers[0][0])
    drv._arrive(msg, NODE)
    assert len(old) == 3 and len(new) == 4


def test_the_production_observers_take_it():
    from mcp_conform.conformance.run_display import FirstDatagram, Tee, TrafficPrinter
    from mcp_conform.fuzz.target_base import Traffic
    from mcp_conform.harness.session_base import _held
    from mcp_conform.judge.run_monitor import RunMonitor, SessionMonitors
    from mcp_conform.traceio.background import BackgroundRecorder
    from mcp_conform.traceio.recorder import McapRecorder

    for obs in (McapRecorder.datagram, RunMonitor.observe, SessionMonitors.observe, Traffic(),
                _held(print), Tee.datagram, TrafficPrinter.__call__, FirstDatagram.__call__,
                BackgroundRecorder.datagram):
        assert takes_run_delay(obs), obs
    assert not takes_run_delay(lambda direction, data, addr, t_ns: None)

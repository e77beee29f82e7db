"""A node's run delay as its capture ends (D-7; issue 38): the runner reads it a last time as
it stops a spawned node and writes it to the capture (``traceio.recorder.RUN_DELAY_METADATA``,
``harness.session_base``); ``mcp-capture check``'s judge (``judge.judging``) feeds it to the
monitor (``Monitor.run_delay``), whose veto weighs it as a datagram's run delay -- so the
seed ``monitor-rtx1-starved-then-closed``'s manager, stalled after its last datagram, is not
failed offline either; a capture without the record is judged as before."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import pytest

from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.run_delay import run_delay_ns
from mcp_conform.harness.session_base import DatagramSessionBase, SpawnedNode
from mcp_conform.judge.judging import Params, judge
from mcp_conform.sim.search import replay
from mcp_conform.traceio.reader import open_capture
from mcp_conform.traceio.recorder import (
    RUN_DELAY_METADATA,
    McapRecorder,
    recorded_run_delay,
    run_metadata,
)
from mcp_conform.traceio.records import Metadata
from tests.judge.sim_views import write_view

SEED = Path(__file__).resolve().parents[1] / "sim" / "seeds" / "monitor-rtx1-starved-then-closed.json"
MANAGER = 0


def _capture(path: Path, *, end_run_delay: bool) -> None:
    """The seed's manager view as its own capture, with its run delay at its view's end as the
    runner writes it as it stops a node, or without."""
    write_view(path, replay(SEED)[0], MANAGER, end_run_delay=end_run_delay)


def test_check_weighs_the_run_delay_the_capture_ends_with(tmp_path: Path) -> None:
    without, with_end = tmp_path / "without.mcap", tmp_path / "with.mcap"
    _capture(without, end_run_delay=False)
    _capture(with_end, end_run_delay=True)
    old = judge(without, Params())
    assert old.verdicts[MANAGER]["MCP-RTX-1"] == "failed"
    new = judge(with_end, Params())
    assert new.verdicts[MANAGER]["MCP-RTX-1"] == "passed"
    assert not [v for v in new.violations if v.rule == "MCP-RTX-1"]
    (note,) = [n for n in new.notes if n.startswith(f"MCP-RTX-1 not failed for node {MANAGER}")]
    assert "End_Mission" in note and "may have ended it" in note


@pytest.mark.parametrize("values", [{}, {"id": "0", "run_delay_ns": "x", "t_ns": "1"},
                                    {"id": "0", "run_delay_ns": "-1", "t_ns": "1"}])
def test_a_record_that_does_not_read_as_a_run_delay_is_ignored(values: dict[str, str]) -> None:
    assert recorded_run_delay(values) is None


class _Session(DatagramSessionBase):
    """The datagram session's stop path alone: its recorder and the node it spawned."""

    def __init__(self, recorder: McapRecorder, role: str) -> None:
        self.cfg = RunConfig(role=role)
        self.recorder = recorder
        self.driver = None


@pytest.mark.skipif(not Path("/proc/self/schedstat").exists(),
                    reason="no /proc/<pid>/schedstat: a run delay cannot be read on this system")
@pytest.mark.parametrize(("role", "node_id", "expected"), [("drone", 7, 7), ("manager", None, MANAGER)])
def test_the_runner_writes_the_run_delay_as_it_stops_its_node(tmp_path: Path, role: str,
                                                              node_id: int | None, expected: int) -> None:
    """A real process stopped by the session: its run delay, read before SIGTERM, is in the
    capture under the ID the capture knows (a drone's as ``record_node`` named it, a manager's
    its role's), and once only (a second stop writes nothing)."""
    path = tmp_path / "run.mcap"
    with McapRecorder(path, metadata=run_metadata("mcp-conform")) as rec:
        s = _Session(rec, role)
        s.recorded_node_id = node_id
        s.node = SpawnedNode([sys.executable, "-c", "import time; time.sleep(30)"])
        pid = s.node.proc.pid
        if run_delay_ns(pid) is None:
            s.node.stop(0.5)
            pytest.skip("/proc does not give this process's run delay")
        s.node.stop(0.5)
        s.node.stop(0.5)
        assert not s.node.alive()
    got = [recorded_run_delay(r.data) for r in open_capture(path)
           if isinstance(r, Metadata) and r.name == RUN_DELAY_METADATA]
    assert len(got) == 1 and got[0] is not None
    _t, node, ns = got[0]
    assert node == expected and ns >= 0


@pytest.mark.skipif(not Path("/proc/self/schedstat").exists(),
                    reason="no /proc/<pid>/schedstat: a run delay cannot be read on this system")
def test_a_node_that_closed_itself_and_was_reaped_still_leaves_its_run_delay(tmp_path: Path) -> None:
    """A manager that closes itself is reaped by the runner's liveness check before the stop:
    its run delay, read between its exit and its reaping (``harness.procs``), is still written
    as the session stops it (before: no /proc entry left, no record)."""
    path = tmp_path / "run.mcap"
    with McapRecorder(path, metadata=run_metadata("mcp-conform")) as rec:
        s = _Session(rec, "manager")
        s.recorded_node_id = None
        s.node = SpawnedNode([sys.executable, "-c", "pass"])
        deadline = time.monotonic() + 30
        while s.node.alive() and time.monotonic() < deadline:  # alive() polls: it reaps
            time.sleep(0.02)
        assert not s.node.alive() and s.node.returncode == 0
        assert run_delay_ns(s.node.proc.pid) is None or s.node.run_delay() is not None
        s.node.stop(0.5)
    got = [recorded_run_delay(r.data) for r in open_capture(path)
           if isinstance(r, Metadata) and r.name == RUN_DELAY_METADATA]
    assert len(got) == 1 and got[0] is not None and got[0][1] == MANAGER


@pytest.mark.parametrize("end_run_delay", [False, True])
def test_the_live_monitor_gets_the_same_sample_and_verdict(end_run_delay: bool) -> None:
    """One judge: the runner's own monitor (``judge.run_monitor``, fed as the session stops the
    node) weighs the run delay at the stop as ``mcp-capture check`` weighs the capture's record."""
    from mcp_conform.judge.run_monitor import SessionMonitors

    o, _ = replay(SEED)
    w, s = o.world, o.schedule
    mons = SessionMonitors(rto=s.rto, ack_window=max(0.5, 2 * s.rto), broadcast_id=0xFFFF, node_id=MANAGER,
                           node_addr=None, complete=True, drones=tuple(w.drones))
    mons.begin("mission")
    run = mons.current
    assert run is not None
    for r in w.views[MANAGER]:  # the runner's monitor sees the manager's view, as its capture holds it
        run._push(r.t_ns, run.monitor.datagram, r.src_addr, r.dst_addr, r.data, None,
                  r.run_delay if r.tx else None)
    end = int(w.view_end(MANAGER) * 1e9)
    if end_run_delay:
        mons.run_delay(end, MANAGER, w.run_delay_ns[MANAGER])
    run.finish(end)
    assert mons.verdicts()[MANAGER]["MCP-RTX-1"] == ("passed" if end_run_delay else "failed")


def test_a_stall_after_the_last_datagram_speaks_only_of_the_tail() -> None:
    """The run delay read at the stop measures the time after the node's last datagram: it is
    a lag for a failure whose copies end there (the seed's), never for one long before it (a
    node that stopped on a wrong ACK early in a run, then kept sending for many cases: the CI
    mutant rtx-stop-on-any-ack lost its MCP-RTX-2 to a whole run's CPU wait while the stop
    sample counted as one more datagram's)."""
    from mcp_conform.judge.veto import Record, _sent, _tail_lags, _window_lag
    from mcp_conform.spec.codec import Action, build_datagram

    s = 10 ** 9
    sent = [Record(1 * s, build_datagram(0, 1, 1, Action.MISSION_READY), False, 0),
            Record(2 * s, build_datagram(0, 1, 2, Action.WP_OFF), False, s // 10)]
    assert _window_lag(_sent(sent)[1], 1 * s, 1 * s, None) == 0.1
    assert _tail_lags(sent, {1: [(10 * s, 3 * s)]}) == {1: (2 * s, 2.9)}
    assert _tail_lags(sent, {1: [(10 * s, s // 10)]}) == {}  # no growth after the last datagram
    assert _tail_lags([r._replace(run_delay=None) for r in sent], {1: [(10 * s, 3 * s)]}) == {}
    # an ACK after them carries no run delay (harness.run_delay.delay_for), yet the node sent
    # it: the tail begins there, after both messages' copies (CI's second failure of the mutant)
    acked = [*sent, Record(5 * s, build_datagram(0, 1, 3, Action.ACK, (9).to_bytes(2, "big")), False, None)]
    assert _tail_lags(acked, {1: [(10 * s, 3 * s)]}) == {1: (5 * s, 2.9)}

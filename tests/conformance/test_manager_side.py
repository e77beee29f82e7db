"""harness.manager_side: the silent drone's scenario beside the main mission (issue 23), on
a manager instance of its own — run at the same time, each datagram attributed to its
instance by the socket it reached, its traffic a session of its own in the capture and the
run's monitor, judged the same live and offline; ``overlap`` empty (``--serial``): after it."""

from __future__ import annotations

import pytest

from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.manager_session import ManagerSession, embedded_command
from mcp_conform.harness.manager_side import side_by_side_why_not
from mcp_conform.harness.session_base import EMBEDDED_ACK_WINDOW, EMBEDDED_RTO


def test_a_second_instance_needs_ports_of_its_own():
    assert side_by_side_why_not(embedded_command(), (1, 2, 3)) is None
    assert "attach mode" in side_by_side_why_not(None, (1, 2, 3))
    assert "two drones" in side_by_side_why_not(embedded_command(), (1,))
    fixed = "python my_manager.py --bind 127.0.0.1:7889 --send-to 127.0.0.1:{listen_port}"
    assert "{target_port}" in side_by_side_why_not(fixed, (1, 2))
    assert "{listen_port}" in side_by_side_why_not("m --bind {target_host}:{target_port} --send-to x:7890", (1, 2))


def test_the_tee_records_a_datagram_with_the_socket_it_reached():
    """``mcp-conform -v`` wraps the recorder (``conformance.run_display.Tee``): a datagram of the
    side instance's socket is recorded with that socket as its ``local``, not the main one's."""
    from mcp_conform.conformance.run_display import Tee

    got = []

    class Rec:
        local = ("", 1)

        def datagram(self, *a, **kw):
            got.append((a, kw))

    tee = Tee(Rec(), None)
    tee.datagram("rx", b"x", ("127.0.0.1", 5), 7, local=("", 2))
    tee.datagram("rx", b"x", ("127.0.0.1", 5), 8, run_delay=3)
    assert got == [(("rx", b"x", ("127.0.0.1", 5), 7), {"local": ("", 2)}),
                   (("rx", b"x", ("127.0.0.1", 5), 8), {"run_delay": 3})]


def _run(tmp_path, overlap: set[str]):
    from mcp_conform.conformance.manager_case import ManagerCaseContext
    from mcp_conform.traceio.recorder import McapRecorder

    cfg = RunConfig(role="manager", embedded=True, rto=EMBEDDED_RTO, ack_window=EMBEDDED_ACK_WINDOW, challenge=2)
    capture = tmp_path / "run.mcap"
    rec = McapRecorder(str(capture))
    s = ManagerSession(cfg, recorder=rec)
    s.make_context = ManagerCaseContext
    s.overlap = overlap
    try:
        s.start()
        side = s.side.get("silent")
        side_target = side.target if side is not None else None
        silent = s.mission("silent")
    finally:
        s.close()
        rec.close()
    return s, s.missions["main"], silent, side_target, capture


@pytest.mark.slow
def test_the_silent_scenario_runs_beside_the_main_one_attributed_by_socket(tmp_path):
    from mcp_conform.judge.judging import Params, judge

    s, main, silent, side_target, capture = _run(tmp_path, {"silent"})
    assert side_target is not None and side_target != s.node_address
    # at the same time: the silent mission started before the main one ended
    assert silent.t0 < main.t_end, (silent.t0, main.t_end)
    # exact attribution: each mission holds its own instance's datagrams only
    assert main.rx and silent.rx
    assert {d.addr[1] for d in main.rx} == {s.node_address[1]}
    assert {d.addr[1] for d in silent.rx} == {side_target[1]}
    # judged as before: the silent drone given up on, the others' missions ended
    assert silent.ended_by == "end_mission" and silent.silent_from is not None, silent.notes
    assert main.ended_by == "end_mission"
    # one session each in the capture and the run's monitor, the silent one with its own
    # instance's address; offline and live agree, and nothing is violated in either
    for complete in (False, True):
        j = judge(str(capture), Params(complete=complete))
        assert set(j.segments) == {"main", "silent"}, list(j.segments)
        assert not j.violations, j.violations
        assert j.verdicts == s.monitor.verdicts(), complete
    assert s.monitor.parts["silent"].node_addr == side_target
    assert not s.monitor.violations()


@pytest.mark.slow
def test_without_overlap_the_silent_scenario_runs_after_the_main_one(tmp_path):
    s, main, silent, side_target, _ = _run(tmp_path, set())
    assert side_target is None and silent.t0 > main.t_end
    assert {d.addr[1] for d in silent.rx} == {s.node_address[1]}  # the same ports, one after the other


def test_the_held_traffic_and_the_main_managers_reach_capture_and_monitor_in_one_order():
    """One judge: while the side scenario's held traffic is handed to the recorder and the
    monitor, the main manager may still send (its driver's receiver thread tells the same
    observers). Each observer must see one and the same order, or the capture is judged
    otherwise than the live monitor was (CI: MCP-BLK-3 twice live, once offline)."""
    import threading
    import time
    from types import SimpleNamespace

    from mcp_conform.harness.driver import TargetDriver
    from mcp_conform.harness.manager_side import SideScenario

    rec, mon = [], []

    def recorder(direction, data, addr, t_ns, run_delay=None, local=None):
        rec.append(data)
        time.sleep(0)  # let the other thread in between two observers

    def monitor(direction, data, addr, t_ns, run_delay=None):
        mon.append(data)
        time.sleep(0)

    main = TargetDriver(("127.0.0.1", 9), ("127.0.0.1", 0))
    main.add_observer(lambda d, data, addr, t: recorder(d, data, addr, t))
    main.add_observer(lambda d, data, addr, t: monitor(d, data, addr, t))
    side = SideScenario("silent", spawn="true", placeholders={}, listen_host="127.0.0.1", target_host="127.0.0.1",
                        drones=(1, 2), challenge=1, waypoints=None, obstacles=None, seq_base=1000, rto=0.2,
                        ack_window=0.25, broadcast_id=0xFFFF, seed=1, ready_limit=5.0)
    side._held = [("rx", b"held%d" % k, ("127.0.0.1", 1), k, None) for k in range(3000)]
    fake = SimpleNamespace(driver=main, monitor=SimpleNamespace(observe=monitor, observe_held=monitor, current=None),
                           recorder=SimpleNamespace(datagram=recorder), _begin_session=lambda *a, **k: None,
                           _settle=lambda m, ok, elapsed: m)
    stop = threading.Event()

    def main_manager_sends() -> None:
        k = 0
        while not stop.is_set() and k < 100_000:
            main._notify("rx", b"main%d" % k, ("127.0.0.1", 2), 10**9 + k)
            k += 1

    t = threading.Thread(target=main_manager_sends)
    t.start()
    try:
        ManagerSession._side_mission(fake, side)
    finally:
        stop.set()
        t.join()
    assert sum(1 for d in rec if d.startswith(b"held")) == 3000
    assert rec == mon

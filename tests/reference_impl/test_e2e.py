"""End to end on loopback: one manager and three drones as separate processes on one host,
the drones sharing one UDP port and the manager reaching them by IP broadcast
(127.255.255.255, MCP-TRN-1), for challenges 1, 2 and 3 (MCP-FLOW-1..6).

Each drone's application must receive each command exactly once (MCP-DUP-1), and every
process must exit 0 after End_Mission. Ports are picked free; every process is killed in a
``finally``.
"""

from __future__ import annotations

import json
import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from spec import SPEC
from spec.mission import load_waypoints

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).parent / "data"
WAYPOINTS = DATA / "challenge.waypoints"
OBSTACLES = DATA / "obstacles.waypoints"
BROADCAST = SPEC.protocol["broadcast_address"]
DRONES = (1, 2, 3)
RTO = "0.3"
DEADLINE = 40.0  # seconds for the whole mission; a hang fails instead of blocking CI

pytestmark = pytest.mark.slow


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("", 0))
        return int(s.getsockname()[1])


def node(*args: str, log: Path) -> subprocess.Popen[bytes]:
    with open(log, "wb") as err:
        return subprocess.Popen([sys.executable, "-m", "reference_impl", *args], cwd=ROOT,
                                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)


def wait_all(procs: dict[str, subprocess.Popen[bytes]], seconds: float) -> dict[str, int | None]:
    """Each process's exit code, None for one still running when ``seconds`` are up."""
    deadline = time.monotonic() + seconds
    codes: dict[str, int | None] = {}
    for name, proc in procs.items():
        try:
            codes[name] = proc.wait(timeout=max(0.1, deadline - time.monotonic()))
        except subprocess.TimeoutExpired:
            codes[name] = None
    return codes


def expected(challenge: int) -> dict[str, int]:
    n_wp = len(load_waypoints(WAYPOINTS))
    middle = {1: {"WP_List": 1}, 2: {"WP_On": n_wp, "WP_Off": n_wp}, 3: {"Obstacles_List": 1}}[challenge]
    return {"Start_Mission": 1, **middle, "End_Mission": 1}


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_manager_and_three_drones(challenge: int, tmp_path: Path) -> None:
    drone_port, manager_port = free_port(), free_port()
    while manager_port == drone_port:
        manager_port = free_port()
    run_mission(challenge, tmp_path, drone_port, manager_port, capture=True)
    judge_own_captures(challenge, tmp_path)


def judge_own_captures(challenge: int, tmp_path: Path) -> None:
    """Each node's own capture (``mcp-node --capture``, our recorder) judged by the trace
    monitor as ``mcp-capture check`` does: no violation in any of them, and the manager's,
    which holds every exchange of the mission, shows the challenge's flow rule passed."""
    from judge.judging import Params, judge

    items = tuple(load_waypoints(OBSTACLES if challenge == 3 else WAYPOINTS))
    for name in ("manager", *(f"drone{i}" for i in DRONES)):
        params = Params(rto=float(RTO), ack_window=0.5, drones=DRONES, challenge=challenge, waypoints=items)
        j = judge(tmp_path / f"{name}.mcap", params)
        assert j.truncated is None and j.datagrams > 10, (name, j.truncated, j.datagrams)
        assert [(v.rule, v.node, v.actual) for v in j.violations] == [], name
        if name == "manager":
            flow = "MCP-FLOW-" + {1: "4", 2: "5", 3: "6"}[challenge]
            assert j.verdicts[0][flow] == "passed"
            assert all(j.verdicts[d]["MCP-ACK-1"] == "passed" for d in DRONES)


def run_mission(challenge: int, tmp_path: Path, drone_port: int, manager_port: int,
                records: bool = True, capture: bool = False) -> None:
    """The manager and three drones through one mission; every process exits 0 and (with
    ``records``) every drone's application gets each command exactly once, arms and RTLs."""
    procs: dict[str, subprocess.Popen[bytes]] = {}
    try:
        for i in DRONES:
            procs[f"drone{i}"] = node("drone", "--id", str(i), BROADCAST, str(drone_port), str(manager_port),
                                      "--reuse-port", "--rto", RTO, "--record", str(tmp_path / f"drone{i}.json"),
                                      *(("--capture", str(tmp_path / f"drone{i}.mcap")) if capture else ()),
                                      log=tmp_path / f"drone{i}.log")
        procs["manager"] = node("manager", "--challenge", str(challenge), "--drones", ",".join(map(str, DRONES)),
                                "--waypoints", str(WAYPOINTS), "--obstacles", str(OBSTACLES),
                                BROADCAST, str(manager_port), str(drone_port), "--rto", RTO,
                                "--record", str(tmp_path / "manager.json"),
                                *(("--capture", str(tmp_path / "manager.mcap")) if capture else ()),
                                log=tmp_path / "manager.log")
        codes = wait_all(procs, DEADLINE)
        logs = {name: (tmp_path / f"{name}.log").read_text(errors="replace")[-1500:] for name in procs}
        assert codes == {name: 0 for name in procs}, logs
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait(5)

    if not records:
        return
    manager = json.loads((tmp_path / "manager.json").read_text())
    assert manager["outcome"] == "end_mission" and sorted(manager["ready"]) == list(DRONES)
    assert manager["failed"] == []
    want = expected(challenge)
    for i in DRONES:
        rec = json.loads((tmp_path / f"drone{i}.json").read_text())
        assert rec["outcome"] == "end_mission"
        assert rec["received"] == want, f"drone {i}"  # each command exactly once
        seqs = [seq for _, _, seq in rec["deliveries"]]
        assert len(seqs) == len(set(seqs)) == sum(want.values())
        assert all(src == 0 for _, src, _ in rec["deliveries"])
        assert rec["deliveries"][0][0] == "Start_Mission" and rec["deliveries"][-1][0] == "End_Mission"
        assert rec["armed"] and rec["rtl"]
        sent_to_i = [a for a, d in manager["sent"] if d == i]
        assert sent_to_i == [a for a, _, _ in rec["deliveries"]]


# ---------------------------------------------------------------- the trace monitor
class LoopbackCapture:
    """tcpdump on the loopback interface, writing a pcap of the two MCP ports."""

    def __init__(self, path: Path, ports: tuple[int, int]) -> None:
        self.path = path
        self.log = path.with_suffix(".log")
        tcpdump = shutil.which("tcpdump")
        if tcpdump is None:
            pytest.skip("tcpdump is not installed (.ci/apt-tools installs it)")
        with open(self.log, "wb") as err:
            self.proc = subprocess.Popen(
                [tcpdump, "-i", "lo", "-U", "-n", "-B", "8192", "-w", str(path),
                 f"udp port {ports[0]} or udp port {ports[1]}"],
                stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)
        deadline = time.monotonic() + 10.0
        while b"listening on" not in self.log.read_bytes():
            if self.proc.poll() is not None or time.monotonic() > deadline:
                self.stop()
                pytest.skip(f"tcpdump cannot capture on lo here: {self.log.read_text(errors='replace')[-300:]}")
            time.sleep(0.05)

    def stop(self) -> int | None:
        """Stop it; the number of packets the kernel dropped (None if it did not say)."""
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(5)
        m = re.search(rb"(\d+) packets? dropped by kernel", self.log.read_bytes())
        return int(m.group(1)) if m else None


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_the_trace_monitor_finds_nothing_in_their_traffic(challenge: int, tmp_path: Path) -> None:
    """The same mission captured by tcpdump on lo, read back (traceio.reader) and judged by
    judge.monitor with the mission's drones, challenge and items: no violation. Every
    node runs on this host, so the capture holds every datagram (judged as a complete trace)
    unless tcpdump reports drops."""
    from judge.monitor import Monitor
    from traceio.reader import Datagram, open_capture

    drone_port, manager_port = free_port(), free_port()
    while manager_port == drone_port:
        manager_port = free_port()
    cap = LoopbackCapture(tmp_path / "mission.pcap", (drone_port, manager_port))
    try:
        run_mission(challenge, tmp_path, drone_port, manager_port, records=False)
    finally:
        dropped = cap.stop()
    items = load_waypoints(OBSTACLES if challenge == 3 else WAYPOINTS)
    monitor = Monitor(rto=float(RTO), ack_window=0.5, drones=DRONES, challenge=challenge, waypoints=items,
                      complete=dropped == 0)
    violations = []
    last = 0
    for rec in open_capture(cap.path):
        if type(rec) is Datagram:
            violations += monitor.datagram(rec.t_ns, rec.src_addr, rec.dst_addr, rec.data)
            last = rec.t_ns
    violations += monitor.finish(last)
    assert monitor.count > 20, f"tcpdump captured {monitor.count} datagrams"
    assert [(v.rule, v.node, v.actual) for v in violations] == []
    verdicts = monitor.verdicts()
    assert sorted(verdicts) == [0, *DRONES]
    assert verdicts[0]["MCP-FLOW-" + {1: "4", 2: "5", 3: "6"}[challenge]] == "passed"
    assert all(verdicts[d]["MCP-ACK-1"] == "passed" for d in DRONES) or dropped != 0

"""End to end on loopback: one manager and three drones as separate processes on one host,
the drones sharing one UDP port and the manager reaching them by IP broadcast
(127.255.255.255, MCP-TRN-1), for challenges 1, 2 and 3 (MCP-FLOW-1..6).

Each drone's application must receive each command exactly once (MCP-DUP-1), and every
process must exit 0 after End_Mission. Ports are picked free; every process is killed in a
``finally``. One mission a challenge, judged three ways: the nodes' records, each node's own
capture and tcpdump's capture of ``lo`` (the tcpdump mission was a second run of the same
mission, 1.3 CPU s and ~5 s each; now tcpdump records the one run).
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mcp_conform.spec import SPEC
from mcp_conform.spec.mission import load_waypoints
from tests.capturing import dropped_by_kernel, free_port, start_capture, stop_capture

ROOT = Path(__file__).resolve().parents[2]
DATA = Path(__file__).parent / "data"
WAYPOINTS = DATA / "challenge.waypoints"
OBSTACLES = DATA / "obstacles.waypoints"
BROADCAST = SPEC.protocol["broadcast_address"]
DRONES = (1, 2, 3)
RTO = "0.3"
DEADLINE = 40.0  # seconds for the whole mission; a hang fails instead of blocking CI

pytestmark = pytest.mark.slow


def node(*args: str, log: Path) -> subprocess.Popen[bytes]:
    with open(log, "wb") as err:
        return subprocess.Popen([sys.executable, "-m", "mcp_conform.reference_impl", *args], cwd=ROOT,
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
    """The mission: every process exits 0, every command delivered once (the records), no
    violation in any node's own capture, then in tcpdump's (``judge_tcpdump_capture``; skipped
    last, the rest checked, where tcpdump cannot capture)."""
    drone_port, manager_port = free_port(), free_port()
    while manager_port == drone_port:
        manager_port = free_port()
    pcap, log = tmp_path / "mission.pcap", tmp_path / "tcpdump.log"
    try:
        cap = start_capture(["tcpdump", "-i", "lo", "-U", "-n", "-B", "8192", "-w", str(pcap),
                             f"udp port {drone_port} or udp port {manager_port}"], log, "listening on")
        cannot = None
    except pytest.skip.Exception as exc:
        cap, cannot = None, str(exc)
    try:
        run_mission(challenge, tmp_path, drone_port, manager_port, capture=True)
    finally:
        if cap is not None:
            stop_capture(cap)
    judge_own_captures(challenge, tmp_path)
    if cannot is not None:
        pytest.skip(f"the records and the nodes' captures checked; tcpdump's not: {cannot}")
    judge_tcpdump_capture(challenge, pcap, log)


def judge_own_captures(challenge: int, tmp_path: Path) -> None:
    """Each node's own capture (``mcp-node --capture``, our recorder) judged by the trace
    monitor as ``mcp-capture check`` does: no violation in any of them, and the manager's,
    which holds every exchange of the mission, shows the challenge's flow rule passed."""
    from mcp_conform.judge.judging import Params, judge

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
        # the manager first, its socket bound before any drone sends: a drone's own capture
        # holds every Mission_Ready copy it sent, and copies sent before the manager listened
        # (a loaded host took 1.9 s to start it) read as a manager that ACKed none of 6 (MCP-ACK-1)
        procs["manager"] = node("manager", "--challenge", str(challenge), "--drones", ",".join(map(str, DRONES)),
                                "--waypoints", str(WAYPOINTS), "--obstacles", str(OBSTACLES),
                                BROADCAST, str(manager_port), str(drone_port), "--rto", RTO,
                                "--record", str(tmp_path / "manager.json"),
                                *(("--capture", str(tmp_path / "manager.mcap")) if capture else ()),
                                log=tmp_path / "manager.log")
        listening = time.monotonic() + 60
        while (time.monotonic() < listening and procs["manager"].poll() is None
               and "manager listening on" not in (tmp_path / "manager.log").read_text(errors="replace")):
            time.sleep(0.05)
        for i in DRONES:
            procs[f"drone{i}"] = node("drone", "--id", str(i), BROADCAST, str(drone_port), str(manager_port),
                                      "--reuse-port", "--rto", RTO, "--record", str(tmp_path / f"drone{i}.json"),
                                      *(("--capture", str(tmp_path / f"drone{i}.mcap")) if capture else ()),
                                      log=tmp_path / f"drone{i}.log")
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
def judge_tcpdump_capture(challenge: int, pcap: Path, log: Path) -> None:
    """The mission captured by tcpdump on lo, judged as ``mcp-capture check`` judges a
    capture (judge.judging) with the mission's drones, challenge and items: no violation.
    Every node runs on this host, so the capture holds every datagram (judged as a complete
    trace) unless tcpdump reports drops; then MCP-ACK-1 is not judged on absences."""
    from mcp_conform.judge.judging import Params, judge

    dropped = dropped_by_kernel(log)
    assert dropped is not None, f"tcpdump did not say how many packets it dropped: {log.read_text()[-300:]}"
    items = tuple(load_waypoints(OBSTACLES if challenge == 3 else WAYPOINTS))
    j = judge(pcap, Params(rto=float(RTO), ack_window=0.5, drones=DRONES, challenge=challenge,
                           waypoints=items, complete=dropped == 0))
    assert j.datagrams > 20, f"tcpdump captured {j.datagrams} datagrams"
    assert [(v.rule, v.node, v.actual) for v in j.violations] == []
    assert sorted(j.verdicts) == [0, *DRONES]
    assert j.verdicts[0]["MCP-FLOW-" + {1: "4", 2: "5", 3: "6"}[challenge]] == "passed"
    if dropped == 0:  # absences are evidence only in a capture that holds every datagram
        assert all(j.verdicts[d]["MCP-ACK-1"] == "passed" for d in DRONES)

"""mcp-capture check on captures the user's own tools take of a real run.

The reference manager and two reference drones run a whole mission on loopback (the drones
sharing one port, the manager reaching them by IP broadcast, as in
tests/reference_impl/test_e2e.py) while tcpdump captures it on ``lo`` (Ethernet link type)
and on ``any`` (Linux cooked SLL2), and dumpcap (tshark's capture engine) on ``lo``
(pcapng). Each capture, checked as a user would (the ``mcp-capture`` command), must find
nothing, and all three must show the same nodes and datagram counts. The captures are
filtered to the run's own ports: other processes on this host use loopback too.

Skips, with the reason, where a capture tool is not installed (``.ci/apt-tools`` installs
tcpdump and tshark) or capturing is not permitted (not root, no CAP_NET_RAW).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from mcp_conform.spec import SPEC
from tests.capturing import dropped_by_kernel, start_capture, stop_capture
from tests.forkserver import run_module
from tests.reference_impl.test_e2e import free_port, node, wait_all

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "tests" / "reference_impl" / "data"
BROADCAST = SPEC.protocol["broadcast_address"]
DRONES = (1, 2)
RTO = "0.3"
DEADLINE = 40.0

pytestmark = pytest.mark.slow


def check(path: Path, tmp_path: Path, *extra: str) -> tuple[int, dict, str]:
    out = tmp_path / f"{path.name}.json"
    # the mcp-capture command (python -m mcp_conform.captures), served by the tests' fork server
    proc = run_module("captures", ["check", str(path), "--rto", RTO, "--ack-window", "0.5", "--json", str(out), *extra],
                      cwd=ROOT, timeout=120, env=dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1"))
    doc = json.loads(out.read_text()) if out.exists() else {}
    return proc.returncode, doc, proc.stdout + proc.stderr


def test_check_on_tcpdump_and_dumpcap_captures_of_a_real_mission(tmp_path: Path) -> None:
    for tool in ("tcpdump", "dumpcap"):
        if shutil.which(tool) is None:
            pytest.skip(f"{tool} is not installed (apt-get install tcpdump tshark; .ci/apt-tools)")
    if hasattr(os, "geteuid") and os.geteuid() != 0:
        pytest.skip("capturing on loopback needs root (or CAP_NET_RAW)")
    drone_port, manager_port = free_port(), free_port()
    while manager_port == drone_port:
        manager_port = free_port()
    bpf = f"udp and (port {drone_port} or port {manager_port})"
    files = {"lo.pcap": tmp_path / "lo.pcap", "any.pcap": tmp_path / "any.pcap",
             "lo.pcapng": tmp_path / "lo.pcapng"}
    captures = [
        start_capture(["tcpdump", "-i", "lo", "-U", "-n", "-w", str(files["lo.pcap"]), bpf],
                      tmp_path / "tcpdump-lo.log", "listening on"),
        start_capture(["tcpdump", "-i", "any", "-U", "-n", "-w", str(files["any.pcap"]), bpf],
                      tmp_path / "tcpdump-any.log", "listening on"),
        start_capture(["dumpcap", "-q", "-i", "lo", "-f", bpf, "-w", str(files["lo.pcapng"])],
                      tmp_path / "dumpcap.log", "Capturing on"),
    ]
    procs: dict[str, subprocess.Popen[bytes]] = {}
    try:
        for i in DRONES:
            procs[f"drone{i}"] = node("drone", "--id", str(i), BROADCAST, str(drone_port), str(manager_port),
                                      "--rto", RTO, "--reuse-port", log=tmp_path / f"drone{i}.log")
        procs["manager"] = node("manager", "--challenge", "2", "--drones", ",".join(map(str, DRONES)),
                                "--waypoints", str(DATA / "challenge.waypoints"), BROADCAST, str(manager_port),
                                str(drone_port), "--rto", RTO, log=tmp_path / "manager.log")
        codes = wait_all(procs, DEADLINE)
        assert codes == {name: 0 for name in procs}, {
            n: (tmp_path / f"{n}.log").read_text(errors="replace")[-800:] for n in procs}
        time.sleep(0.3)  # the last ACKs reach the capture
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.wait(5)
        for cap in captures:
            stop_capture(cap)
    dropped = [dropped_by_kernel(tmp_path / log) for log in ("tcpdump-lo.log", "tcpdump-any.log")]
    dropped_any = any(n is None or n > 0 for n in dropped)  # unknown counts as dropped
    tables = {}
    for name, path in files.items():
        rc, doc, out = check(path, tmp_path, "--drones", "1,2", "--waypoints", str(DATA / "challenge.waypoints"))
        assert rc == 0 and doc["violations"] == [], out
        assert doc["file"]["truncated"] is None, doc["file"]
        assert doc["parameters"]["challenge"] == 2 and doc["parameters"]["challenge_source"] == "inferred"
        assert doc["rules"]["0"]["MCP-FLOW-5"] == "passed" and doc["rules"]["1"]["MCP-ACK-1"] == "passed", out
        tables[name] = [(n["id"], n["role"], n["datagrams"]["sent"], n["datagrams"]["received"]) for n in doc["nodes"]]
        if not dropped_any:  # the capture holds every datagram: absences are evidence too
            rc, doc, out = check(path, tmp_path, "--drones", "1,2", "--complete")
            assert rc == 0 and doc["violations"] == [], out
    assert [n[0] for n in tables["lo.pcap"]] == [0, *DRONES]
    assert tables["lo.pcap"] == tables["lo.pcapng"] == tables["any.pcap"], tables
    print(tables, "dropped:", dropped)
    assert tables["lo.pcap"][0][2] > 20  # the manager's commands and ACKs were all seen

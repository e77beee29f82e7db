"""``mcp-node --capture``: the node's own traffic and autopilot link in the runner's format,
and a valid file however the node stops (End_Mission, SIGINT, SIGTERM, SIGKILL)."""

from __future__ import annotations

import base64
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from mcp_conform.spec.codec import Action, Message, decode, encode
from tests.forkserver import run_module
from tests.traceio.test_recorder import read_all

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


def _manager_socket() -> socket.socket:
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sock.settimeout(0.2)
    return sock


def _drone(capture: Path, manager_port: int) -> subprocess.Popen[bytes]:
    return subprocess.Popen(
        [sys.executable, "-m", "mcp_conform.reference_impl", "drone", "--id", "3", "--bind", "127.0.0.1:0",
         "--send-to", f"127.0.0.1:{manager_port}", "--rto", "0.2", "--capture", str(capture), "-q"],
        cwd=ROOT, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)


def _await_ready(sock: socket.socket, copies: int, limit: float = 20.0) -> tuple[Message, tuple]:
    """Mission_Ready copies from the drone (unACKed, so it retransmits)."""
    deadline = time.monotonic() + limit
    seen: list[tuple[Message, tuple]] = []
    while len(seen) < copies and time.monotonic() < deadline:
        try:
            data, addr = sock.recvfrom(2048)
        except TimeoutError:
            continue
        msg = decode(data)
        if msg.action == Action.MISSION_READY:
            seen.append((msg, addr))
    assert len(seen) >= copies, "the drone sent no Mission_Ready"
    return seen[0]


def _wait_file(path: Path, limit: float = 20.0):
    deadline = time.monotonic() + limit
    while True:
        try:
            return read_all(path)[0]
        except Exception:  # noqa: BLE001 - the writer may still be finishing
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


@pytest.mark.parametrize("how", ["SIGINT", "SIGTERM", "SIGKILL"])
def test_interrupted_node_leaves_a_valid_capture(tmp_path, how):
    path = tmp_path / f"{how}.mcap"
    sock = _manager_socket()
    proc = _drone(path, sock.getsockname()[1])
    manager = f"127.0.0.1:{sock.getsockname()[1]}"
    try:
        ready, addr = _await_ready(sock, copies=2)
        # one ACK from the "manager", so the capture holds a received datagram too
        sock.sendto(encode(Message(3, 0, 1, Action.WP_OFF, None)), addr)
        time.sleep(0.3)
        proc.send_signal(getattr(signal, how))
        proc.wait(timeout=20)
    finally:
        if proc.poll() is None:
            os.kill(proc.pid, signal.SIGKILL)
            proc.wait()
        sock.close()
    msgs = _wait_file(path)
    tx = [body for _, body in msgs["/mcp/tx"]]
    readies = [b for b in tx if b["action_name"] == "MISSION_READY"]
    assert len(readies) >= 2 and all(b["src"] == 3 and b["peer"] == manager for b in readies)
    assert readies[0]["seq"] == ready.seq
    assert base64.b64decode(readies[0]["raw_base64"]) == encode(ready)
    assert readies[0]["local"].startswith("127.0.0.1:")
    rx = [body for _, body in msgs["/mcp/rx"]]
    assert any(b["action_name"] == "WP_OFF" for b in rx)
    assert any(b["action_name"] == "ACK" and b["payload"] == 1 for b in tx)
    # both directions of the autopilot link (the built-in vehicle)
    mav = {(b["direction"], b["msg_type"]) for _, b in msgs["/mavlink"]}
    assert ("tx", "HEARTBEAT") in mav and ("tx", "GPS_RAW_INT") in mav


def test_a_mission_end_to_end_is_captured_on_every_node(tmp_path):
    """The manager and a drone, each with --capture: each file holds its side of the mission."""
    from mcp_conform.harness.drone_session import free_port
    from tests.spawned import Node

    pm, pd = free_port(), free_port()
    waypoints = ROOT / "tests" / "reference_impl" / "data" / "challenge.waypoints"
    base = [sys.executable, "-m", "mcp_conform.reference_impl"]
    drone = Node(base + ["drone", "--id", "1", "127.255.255.255", str(pd), str(pm), "--rto", "0.2",
                         "--capture", str(tmp_path / "d.mcap"), "-q"], cwd=ROOT)  # its stderr kept
    try:
        manager = subprocess.run(base + ["manager", "--challenge", "1", "--drones", "1", "--waypoints",
                                         str(waypoints), "127.255.255.255", str(pm), str(pd), "--rto", "0.2",
                                         "--capture", str(tmp_path / "m.mcap"), "-q"], cwd=ROOT,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, timeout=60, text=True)
        assert drone.proc.wait(timeout=30) == 0 and manager.returncode == 0, \
            f"the manager: exit {manager.returncode}; {manager.stderr}\nthe drone: {drone.explain()}"
    finally:
        drone.stop(kill=True)
    m, d = read_all(tmp_path / "m.mcap")[0], read_all(tmp_path / "d.mcap")[0]
    sent = [b["action_name"] for _, b in m["/mcp/tx"] if b["action_name"] != "ACK"]
    assert sent == ["START_MISSION", "WP_LIST", "END_MISSION"]
    got = [b["action_name"] for _, b in d["/mcp/rx"] if b["action_name"] != "ACK"]
    assert got == sent
    assert {b["direction"] for _, b in d["/mavlink"]} == {"tx", "rx"}


def test_the_runner_capture_is_complete(tmp_path):
    """Issue 13 item 5: both directions of the autopilot link, the MCP-ROB-7 flood as one
    counted record, base64 content encoding, a metadata record."""
    import json

    from mcap.reader import make_reader

    from mcp_conform.traceio.reader import Datagram, open_capture

    path = tmp_path / "run.mcap"
    proc = run_module("conformance", ["--select", "MCP-ROB-7", "--capture", str(path)], cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stdout[-1500:] + proc.stderr[-1500:]
    msgs = read_all(path)[0]
    (_, burst), = msgs["/mcp/burst"]
    assert burst["count"] == 10000 and burst["direction"] == "tx" and len(burst["cycle"]) >= 3
    assert burst["first_t_ns"] < burst["last_t_ns"] and burst["local"] != burst["peer"]
    mav = {(b["direction"], b["msg_type"]) for _, b in msgs["/mavlink"]}
    assert ("tx", "HEARTBEAT") in mav and ("tx", "GPS_RAW_INT") in mav  # the vehicle's telemetry
    assert any(d == "rx" for d, _ in mav)  # what the node sent the vehicle
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        (meta,) = [m for m in reader.iter_metadata() if m.name == "mcp-conform"]
        schemas = {s.name: json.loads(s.data) for s in reader.get_summary().schemas.values()}
    assert meta.metadata["recorder"] == "mcp-conform" and meta.metadata["seed"] and meta.metadata["spec_version"]
    assert schemas["mcp.Datagram"]["properties"]["raw_base64"]["contentEncoding"] == "base64"
    # every reader sees the flood datagram by datagram
    sent = [r for r in open_capture(path) if type(r) is Datagram and r.direction == "tx"]
    assert len(sent) >= 10000 + len(msgs["/mcp/tx"])

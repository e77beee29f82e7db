"""The independent sample node (tests/conformance/nodes/sample_node.py) driven by hand.

A plain UDP socket plays the Mission Manager and the simulated vehicle is the autopilot,
so these tests check the node itself, without the conformance runner: the correct node
behaves as the description says, and a few faults break what they document.
"""

from __future__ import annotations

import os
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from mcp_conform.spec.codec import (
    BROADCAST_ID,
    Action,
    DecodeError,
    Message,
    build_datagram,
    decode,
    encode,
)
from mcp_conform.vehicle import SimVehicle, make_probe
from tests.conformance.nodes.sample_node import FAULTS

ROOT = Path(__file__).resolve().parents[2]
NODE = ROOT / "tests" / "conformance" / "nodes" / "sample_node.py"
RTO = 0.2
NODE_ID = 7


class Manager:
    """A UDP socket on loopback playing ID 0; the node's address is learned from its datagrams."""

    def __init__(self) -> None:
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.node_addr: tuple[str, int] | None = None
        self.seq = 40000

    def recv(self, timeout: float) -> tuple[bytes, float] | None:
        self.sock.settimeout(max(timeout, 0.001))
        try:
            data, addr = self.sock.recvfrom(65535)
        except TimeoutError:
            return None
        self.node_addr = addr
        return data, time.monotonic()

    def collect(self, duration: float) -> list[bytes]:
        out, deadline = [], time.monotonic() + duration
        while (left := deadline - time.monotonic()) > 0:
            got = self.recv(left)
            if got is not None:
                out.append(got[0])
        return out

    def wait_ready(self, timeout: float = 10.0) -> tuple[Message, float]:
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            got = self.recv(left)
            if got is not None:
                msg = decode(got[0])
                if msg.action == Action.MISSION_READY:
                    return msg, got[1]
        raise AssertionError("no Mission_Ready")

    def send_raw(self, data: bytes) -> None:
        assert self.node_addr is not None
        self.sock.sendto(data, self.node_addr)

    def send(self, action: Action, payload=None, dst: int = NODE_ID, seq: int | None = None, src: int = 0) -> bytes:
        if seq is None:
            self.seq = (self.seq + 1) & 0xFFFF
            seq = self.seq
        data = encode(Message(dst, src, seq, action, payload))
        self.send_raw(data)
        return data

    def acks(self, duration: float) -> list[Message]:
        out = []
        for data in self.collect(duration):
            msg = decode(data)
            if msg.action == Action.ACK:
                out.append(msg)
        return out

    def ack_ready(self, ready: Message) -> None:
        self.send(Action.ACK, ready.seq, dst=ready.src)

    def close(self) -> None:
        self.sock.close()


class NodeProc:
    def __init__(self, mgr: Manager, *extra: str) -> None:
        self.err = tempfile.TemporaryFile()
        cmd = [sys.executable, str(NODE), "--id", str(NODE_ID), "--bind", "127.0.0.1:0",
               "--send-to", f"127.0.0.1:{mgr.port}", "--rto", str(RTO), *extra]
        env = dict(os.environ, PYTHONPATH=str(ROOT))
        self.proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=self.err, env=env)

    def stderr(self) -> str:
        self.err.seek(0)
        return self.err.read().decode(errors="replace")

    def wait(self, timeout: float) -> int:
        return self.proc.wait(timeout=timeout)

    def stop(self) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGTERM)
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        self.err.close()


@pytest.fixture
def mgr():
    m = Manager()
    yield m
    m.close()


@pytest.fixture
def spawn(mgr):
    procs: list[NodeProc] = []

    def start(*extra: str) -> NodeProc:
        p = NodeProc(mgr, *extra)
        procs.append(p)
        return p

    yield start
    for p in procs:
        p.stop()


def started(mgr: Manager, spawn, *extra: str) -> tuple[NodeProc, Message]:
    """A node without autopilot whose Mission_Ready has been ACKed."""
    node = spawn(*extra)
    ready, _ = mgr.wait_ready()
    mgr.ack_ready(ready)
    mgr.collect(0.1)
    return node, ready


def test_correct_node_full_mission_with_the_simulated_vehicle(mgr, spawn):
    with SimVehicle(fix_withheld=True, climb_rate=100.0) as v:
        node = spawn("--mavlink", v.url)
        assert v.wait_for(lambda: v.connected, timeout=5)
        assert mgr.collect(0.5) == [], "Mission_Ready before the fix"
        v.give_fix()
        first, t0 = mgr.wait_ready(5.0)
        assert first.src == NODE_ID and first.dst == 0 and first.payload is None
        # retransmissions: same seq, same bytes, spaced by the rto
        raw = encode(first)
        copies = [t0]
        while len(copies) < 3:
            got = mgr.recv(2.0)
            assert got is not None, "no retransmission"
            assert got[0] == raw
            copies.append(got[1])
        gaps = [b - a for a, b in zip(copies, copies[1:], strict=False)]
        assert all(0.1 < g < 0.5 for g in gaps), gaps
        # a wrong-seq ACK and a wrong-src ACK do not stop it; the right one does
        mgr.send(Action.ACK, (first.seq + 1) & 0xFFFF, dst=NODE_ID)
        mgr.send(Action.ACK, first.seq, dst=NODE_ID, src=3)
        assert any(d == raw for d in mgr.collect(0.5))
        mgr.ack_ready(first)
        mgr.collect(0.1)
        assert mgr.collect(0.5) == []
        assert not v.armed

        # a command and its duplicate copy are both ACKed, with the right payload and header
        start = mgr.send(Action.START_MISSION)
        acks = mgr.acks(0.2)
        mgr.send_raw(start)
        acks += mgr.acks(0.2)
        seq = decode(start).seq
        assert [a.payload for a in acks] == [seq, seq]
        assert all(a.dst == 0 and a.src == NODE_ID for a in acks)
        assert v.wait_for(lambda: v.armed and v.altitude > 0, timeout=5)
        assert v.mode == "GUIDED"

        # broadcasts are not ACKed; ACKs are not ACKed; other IDs are not ACKed
        mgr.send(Action.WP_OFF, dst=BROADCAST_ID)
        mgr.send(Action.ACK, 1234)
        mgr.send(Action.WP_OFF, dst=NODE_ID + 1)
        assert mgr.acks(0.3) == []

        # a passthrough frame reaches the vehicle once, its duplicate copy is ACKed only
        probe = mgr.send(Action.MAV_PASSTHROUGH, make_probe("once"))
        mgr.send_raw(probe)
        assert [a.payload for a in mgr.acks(0.3)] == [decode(probe).seq] * 2
        assert v.wait_for(lambda: v.probe_count("once") == 1, timeout=3)
        # wraparound on the receiving side: 0 after 65535 is new
        mgr.send(Action.MAV_PASSTHROUGH, make_probe("wrap-a"), seq=65535)
        mgr.send(Action.MAV_PASSTHROUGH, make_probe("wrap-b"), seq=0)
        assert v.wait_for(lambda: v.probe_count("wrap-b") == 1, timeout=3)
        # the same seq from another src is not a duplicate
        mgr.send(Action.MAV_PASSTHROUGH, make_probe("other-src"), seq=0, src=9)
        assert v.wait_for(lambda: v.probe_count("other-src") == 1, timeout=3)
        mgr.seq = 0
        mgr.collect(0.2)  # their ACKs
        assert v.probe_count("once") == 1 and v.probe_count("wrap-a") == 1

        # malformed input and a maximum-size datagram: no ACK, still live
        mgr.send_raw(b"short")
        mgr.send_raw(build_datagram(NODE_ID, 0, 999, 9))
        mgr.send_raw(build_datagram(NODE_ID, 0, 998, Action.START_MISSION, b"xx"))
        mgr.send_raw(build_datagram(NODE_ID, 0, 997, Action.WP_OFF, preamble=b"NCSU-CM\x01\x02"))
        mgr.send_raw(build_datagram(NODE_ID, 0, 996, Action.WP_OFF, b"\0" * (65507 - 17)))
        assert mgr.acks(0.3) == []
        live = mgr.send(Action.WP_OFF)
        assert [a.payload for a in mgr.acks(0.3)] == [decode(live).seq]

        # End_Mission: ACKed, RTL, still ACKing for a while, then exit 0
        end = mgr.send(Action.END_MISSION)
        assert [a.payload for a in mgr.acks(0.1)] == [decode(end).seq]
        mgr.send_raw(end)
        assert [a.payload for a in mgr.acks(0.1)] == [decode(end).seq]
        assert node.wait(5) == 0, node.stderr()
        assert v.rtl_commanded


def test_own_seq_advances_with_every_ack(mgr, spawn):
    _, ready = started(mgr, spawn)
    mgr.send(Action.WP_OFF)
    mgr.send(Action.WP_OFF)
    raw = [d for d in mgr.collect(0.3)]
    seqs = [decode(d).seq for d in raw]
    assert seqs == [(ready.seq + 1) & 0xFFFF, (ready.seq + 2) & 0xFFFF]


def test_recv_loop_mode_acks_what_queued_while_busy(mgr, spawn):
    started(mgr, spawn, "--ack-mode", "recv-loop", "--busy-start", "0.5")
    start = mgr.send(Action.START_MISSION)
    t0 = time.monotonic()
    assert [a.payload for a in mgr.acks(0.2)] == [decode(start).seq]
    off = mgr.send(Action.WP_OFF)  # arrives while the Start_Mission handler is busy
    got = mgr.recv(2.0)
    assert got is not None and decode(got[0]).payload == decode(off).seq
    assert got[1] - t0 >= 0.4


def test_reply_to_source(mgr, spawn):
    started(mgr, spawn, "--reply-to-source")
    other = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    other.bind(("127.0.0.1", 0))
    other.settimeout(1.0)
    try:
        assert mgr.node_addr is not None
        other.sendto(encode(Message(NODE_ID, 0, 5, Action.WP_OFF)), mgr.node_addr)
        ack = decode(other.recvfrom(100)[0])
        assert ack.action == Action.ACK and ack.payload == 5
    finally:
        other.close()


def test_sigterm_exits_cleanly_while_waiting_for_the_ack(mgr, spawn):
    node = spawn()
    mgr.wait_ready()
    node.proc.send_signal(signal.SIGTERM)
    assert node.wait(20) == 0  # it exits, with 0: how fast is a loaded host's business


def test_a_signal_while_the_main_thread_logs_does_not_hang_the_node(mgr):
    """A loaded CI run's SIGTERM landed while the main thread was inside ``log()``: the handler
    logged too, waited for the log's lock its own thread held, and the node never exited.
    Here the main thread holds that lock when the signal comes: the node still exits 0 and
    says which signal ended it."""
    script = (
        "import os, signal, sys, time\n"
        f"sys.path.insert(0, {str(NODE.parent)!r})\n"
        "import sample_node as s\n"
        "def run(self):\n"
        "    with s._log_lock:\n"
        "        os.kill(os.getpid(), signal.SIGTERM)\n"
        "        self.stop.wait(5)\n"
        "    return 0 if self.stop.is_set() else 9\n"
        "s.Node.run = run\n"
        f"sys.exit(s.main(['--id', '{NODE_ID}', '--bind', '127.0.0.1:0', '--send-to', '127.0.0.1:{mgr.port}']))\n")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60,
                          env=dict(os.environ, PYTHONPATH=str(ROOT)))
    assert proc.returncode == 0, proc.stderr
    assert "signal 15: exiting" in proc.stderr, proc.stderr


def test_every_fault_names_a_rule_of_the_spec():
    from mcp_conform.spec import SPEC

    for name, (rule, _) in FAULTS.items():
        assert SPEC.rule(rule) is not None, name


# ------------------------------------------------------------------ faults
def test_fault_ack_little_endian(mgr, spawn):
    started(mgr, spawn, "--fault", "ack-little-endian")
    mgr.send(Action.WP_OFF, seq=0x0102)
    (raw,) = mgr.collect(0.3)
    assert raw[17:] == b"\x02\x01"


def test_fault_ack_to_manager(mgr, spawn):
    """MCP-ACK-3 broken only for a src other than 0: the manager's message is ACKed to 0 (right),
    another src's to 0 too (wrong). Each ACK awaited by itself, bounded."""
    started(mgr, spawn, "--fault", "ack-to-manager")

    def ack_of(seq: int) -> Message:
        deadline = time.monotonic() + 10.0
        while (left := deadline - time.monotonic()) > 0:
            got = mgr.recv(left)
            if got is not None and (msg := decode(got[0])).action == Action.ACK and msg.payload == seq:
                return msg
        raise AssertionError(f"no ACK of seq {seq}")

    mgr.send(Action.WP_OFF, seq=501)
    assert ack_of(501).dst == 0
    mgr.send(Action.WP_OFF, seq=502, src=5)
    assert ack_of(502).dst == 0


def test_fault_crash_on_short(mgr, spawn):
    node, _ = started(mgr, spawn, "--fault", "crash-on-short")
    mgr.send_raw(b"NCSU")
    assert node.wait(20) == 3


def test_fault_ack_first_copy_only(mgr, spawn):
    started(mgr, spawn, "--fault", "ack-first-copy-only")
    data = mgr.send(Action.WP_OFF)
    mgr.send_raw(data)
    assert len(mgr.acks(0.3)) == 1


def test_fault_ack_broadcast(mgr, spawn):
    started(mgr, spawn, "--fault", "ack-broadcast")
    mgr.send(Action.WP_OFF, dst=BROADCAST_ID, seq=77)
    assert [a.payload for a in mgr.acks(0.3)] == [77]


def test_fault_rtx_new_seq(mgr, spawn):
    spawn("--fault", "rtx-new-seq")
    first, _ = mgr.wait_ready()
    raws = mgr.collect(0.5)
    seqs = [decode(d).seq for d in raws]
    assert len(seqs) >= 2 and len(set(seqs + [first.seq])) == len(seqs) + 1
    mgr.send(Action.ACK, first.seq, dst=NODE_ID)  # an ACK of the first copy stops it
    mgr.collect(0.1)
    assert mgr.collect(0.5) == []


def test_fault_bad_preamble(mgr, spawn):
    spawn("--fault", "bad-preamble")
    deadline = time.monotonic() + 5
    while time.monotonic() < deadline:
        got = mgr.recv(1.0)
        if got is not None:
            break
    assert got is not None and got[0][:9] == b"NCSU-CM\x01\x02"
    with pytest.raises(DecodeError):
        decode(got[0])


def test_fault_mission_ready_wrong_src_keeps_ack_src(mgr, spawn):
    spawn("--fault", "mission-ready-wrong-src")
    ready, _ = mgr.wait_ready()
    assert ready.src == NODE_ID + 1
    mgr.ack_ready(ready)
    mgr.collect(0.1)
    mgr.send(Action.WP_OFF, seq=3)
    (ack,) = mgr.acks(0.3)
    assert ack.src == NODE_ID and ack.payload == 3


def test_fault_ready_bad_payload_and_wrong_id(mgr, spawn):
    spawn("--fault", "ready-bad-payload", "--fault", "ready-to-wrong-id")
    got = mgr.recv(5.0)
    assert got is not None
    raw = got[0]
    assert struct.unpack("!H", raw[9:11])[0] == 5 and len(raw) == 17 + 4


def test_fault_arm_early_and_no_rtl(mgr, spawn):
    with SimVehicle(climb_rate=100.0) as v:
        node = spawn("--mavlink", v.url, "--fault", "arm-early", "--fault", "no-rtl")
        ready, _ = mgr.wait_ready()
        assert v.armed
        mgr.ack_ready(ready)
        mgr.send(Action.START_MISSION)
        mgr.send(Action.END_MISSION)
        assert node.wait(5) == 0
        assert not v.rtl_commanded


def test_fault_passthrough_twice(mgr, spawn):
    with SimVehicle() as v:
        spawn("--mavlink", v.url, "--fault", "passthrough-twice")
        ready, _ = mgr.wait_ready()
        mgr.ack_ready(ready)
        mgr.send(Action.MAV_PASSTHROUGH, make_probe("twice"))
        assert v.wait_for(lambda: v.probe_count("twice") == 2, timeout=3)


@pytest.mark.slow
@pytest.mark.parametrize("fault", ["ack-own-seq", "ack-previous-seq", "ack-zero"])
def test_faults_ack_payload_names_another_seq(mgr, spawn, fault):
    started(mgr, spawn, "--fault", fault)
    mgr.send(Action.WP_OFF, seq=0x0102)
    mgr.send(Action.WP_OFF, seq=0x0103)
    first, second = mgr.acks(0.4)
    named = [first.payload, second.payload]  # big-endian, as decoded
    if fault == "ack-own-seq":
        assert named == [first.seq, second.seq]
    elif fault == "ack-previous-seq":
        assert named == [0, 0x0102]
    else:
        assert named == [0, 0]


@pytest.mark.slow
def test_fault_arm_before_fix_is_refused_and_recorded(mgr, spawn):
    with SimVehicle(fix_withheld=True) as v:
        spawn("--mavlink", v.url, "--fault", "arm-before-fix")
        assert v.wait_for(lambda: any(e.detail["request"] == "arm" for e in v.events("request")), 10)
        [arm] = [e.detail for e in v.events("request") if e.detail["request"] == "arm"]
        assert (arm["result"], arm["reason"]) == ("denied", "PreArm: Need 3D Fix") and not v.armed


@pytest.mark.slow
def test_fault_arm_before_start_and_a_refused_rtl_request(mgr, spawn):
    with SimVehicle(climb_rate=100.0) as v:
        node = spawn("--mavlink", v.url, "--fault", "arm-before-start", "--rtl-refused")
        ready, _ = mgr.wait_ready()
        mgr.ack_ready(ready)
        assert v.wait_for(lambda: v.armed, 5)  # armed before any Start_Mission
        mgr.send(Action.START_MISSION)
        mgr.send(Action.END_MISSION)
        assert node.wait(5) == 0
        rtl = [e.detail for e in v.events("request") if e.detail.get("mode") == "RTL"]
        assert [(d["request"], d["result"], d["via"]) for d in rtl] == [("mode", "denied", "SET_MODE")]
        assert v.mode != "RTL"

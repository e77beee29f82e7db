"""The Wireshark dissector (issue 24 item 3): value names for actions, MAV_CMD and MAV_FRAME;
which ACK answers which command and how fast; retransmissions; Mav_Passthrough handed to
mavgen's MAVLink dissector; every malformed datagram on an MCP port marked with the rule our
decoder names. tshark runs on the golden captures and on a fuzz capture of the reference drone."""

from __future__ import annotations

import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from mcp_conform.captures import dissector, dissector_mavlink, export
from mcp_conform.captures.scenarios import GOLDEN
from mcp_conform.spec.codec import Action, DecodeError, Message, build_datagram, decode, encode
from mcp_conform.spec.mavframe import heartbeat_frame
from mcp_conform.traceio.recorder import McapRecorder
from tests.captures.test_export import ITEMS, _tshark
from tests.capturing import run_subcommand
from tests.spawned import start_node

ROOT = Path(__file__).resolve().parents[2]
MANAGER = ("127.0.0.1", 7889)
DRONE = ("127.0.0.2", 7890)
T0 = 1_700_000_000_000_000_000
MS = 1_000_000
FIELDS = ["frame.number", "udp.srcport", "udp.dstport", "centmesh.src", "centmesh.dst", "centmesh.seq",
          "centmesh.action", "centmesh.ack_seq", "centmesh.rule", "centmesh.acks", "centmesh.acked_in",
          "centmesh.ack_time_ms", "centmesh.retransmission_of", "centmesh.mavlink_msg",
          "mavlink_proto.msgid", "centmesh.item.command", "_ws.col.Info", "_ws.expert.message",
          "udp", "centmesh"]  # the protocols' own items: present (their text) or not (empty)


_run = run_subcommand  # one mcp-capture subcommand in process (tests.capturing)


def test_value_names_come_from_pymavlink_and_the_spec():
    lua = dissector.generate()
    assert '[16]="MAV_CMD_NAV_WAYPOINT"' in lua and '[3]="MAV_FRAME_GLOBAL_RELATIVE_ALT"' in lua
    assert '[76]="COMMAND_LONG"' in lua and "[0]=50" in lua  # HEARTBEAT's CRC_EXTRA
    assert 'ProtoField.uint16("centmesh.item.command", "MAV_CMD", base.DEC, mav_cmd)' in lua or \
        ", base.DEC, mav_cmd)" in lua
    assert ", base.DEC, mav_frame)" in lua and ", base.DEC, actions)" in lua
    for field in ("centmesh.acks", "centmesh.acked_in", "centmesh.retransmission_of", "centmesh.rule"):
        assert f'"{field}"' in lua
    assert dissector_mavlink.enum_names("MAV_CMD")[22] == "MAV_CMD_NAV_TAKEOFF"


def test_install_writes_ours_and_mavgens_mavlink_dissector(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    code, out, err = _run(dissector, "dissector", "--install")
    folder = tmp_path / ".local" / "lib" / "wireshark" / "plugins"
    assert code == 0, err
    assert (folder / "centmesh.lua").read_text() == dissector.generate()
    mav = (folder / dissector_mavlink.FILENAME).read_text()
    assert 'Proto("mavlink_proto"' in mav and "mavgen" in mav and "COMMAND_LONG" in mav
    assert "Generating" not in out  # mavgen's progress lines stay out of our output


# ---------------------------------------------------------------- tshark
@pytest.fixture(scope="module")
def scripts(tmp_path_factory) -> tuple[Path, Path]:
    """Our dissector and mavgen's MAVLink dissector, as ``mcp-capture dissector -o FILE --mavlink
    FILE`` writes them: once for the module's tshark runs (the same files every time)."""
    d = tmp_path_factory.mktemp("lua")
    lua, mav = d / "centmesh.lua", d / "mav.lua"
    assert _run(dissector, "dissector", "-o", str(lua), "--mavlink", str(mav))[0] == 0
    return lua, mav


def _plain_udp(row: dict[str, str]) -> bool:
    """A UDP datagram the dissector left as plain UDP (what ``-Y "udp && !centmesh"`` selects)."""
    return bool(row["udp"]) and not row["centmesh"]


def _dissect(tmp_path: Path, mcap: Path, scripts: tuple[Path, Path], *extra: str) -> list[dict[str, str]]:
    """tshark's fields of each frame of ``mcap`` exported to pcapng; none of them plain UDP."""
    tshark = _tshark()
    pcap = tmp_path / (mcap.stem + ".pcapng")
    code, _, err = _run(export, "export", str(mcap), "--pcap", str(pcap))
    assert code == 0, err
    lua, mav = scripts
    cmd = [tshark, "-2", "-n", "-X", f"lua_script:{mav}", "-X", f"lua_script:{lua}", "-r", str(pcap), *extra,
           "-T", "fields", "-E", "separator=\t", "-E", "occurrence=a", "-E", "aggregator=,"]
    for f in FIELDS:
        cmd += ["-e", f]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    rows = [dict(zip(FIELDS, line.split("\t"), strict=True)) for line in proc.stdout.splitlines()]
    plain = [r["frame.number"] for r in rows if _plain_udp(r)]
    assert not plain, f"plain UDP, not centmesh: frames {plain[:20]}"
    return rows


def _check_acks(rows: list[dict[str, str]]) -> int:
    """Every ACK that answers a datagram of the capture names it; returns how many did."""
    by_frame = {int(r["frame.number"]): r for r in rows}
    linked = 0
    for r in rows:
        if r["centmesh.ack_seq"] and not r["centmesh.rule"]:
            sent = {int(o["frame.number"]) for o in rows if o["centmesh.seq"] and o["centmesh.src"] == r["centmesh.dst"]
                    and int(o["centmesh.seq"]) == int(r["centmesh.ack_seq"])
                    and int(o["frame.number"]) < int(r["frame.number"]) and not o["centmesh.ack_seq"]}
            if sent:
                cmd = int(r["centmesh.acks"])
                assert cmd in sent and cmd == max(sent), r  # the latest copy before the ACK
                assert f"(acknowledges frame {cmd})" in r["_ws.col.Info"]
                first = by_frame[min(sent)]
                assert first["centmesh.acked_in"], first
                linked += 1
            else:
                assert not r["centmesh.acks"] and "ACK of seq" in r["_ws.expert.message"], r
    return linked


def _check_rules(rows: list[dict[str, str]], datagrams: dict[int, bytes]) -> None:
    """Our decoder's verdict on each datagram is the dissector's: well-formed, or malformed
    naming the rule the decoder names."""
    for r in rows:
        data = datagrams[int(r["frame.number"])]
        rules = set(filter(None, r["centmesh.rule"].split(",")))
        try:
            decode(data)
        except DecodeError as exc:
            assert exc.rule in rules, (exc.rule, exc.reason, r, data[:40].hex())
            assert exc.rule in r["_ws.expert.message"]
        else:
            assert not rules, (r, data[:40].hex())


@pytest.mark.slow
def test_tracking_retransmissions_names_and_mavlink(tmp_path, scripts):
    mission_ready = encode(Message(0, 1, 100, Action.MISSION_READY, 1))
    wp_on = encode(Message(1, 0, 200, Action.WP_ON, ITEMS[1]))
    passthrough = encode(Message(1, 0, 201, Action.MAV_PASSTHROUGH, heartbeat_frame()))
    bad_crc = bytearray(passthrough)
    bad_crc[-1] ^= 0xFF
    traffic = [  # (ms, from the drone?, bytes)
        (0, True, mission_ready),
        (500, True, mission_ready),                                 # 2: retransmitted, same bytes
        (510, False, encode(Message(1, 0, 7, Action.ACK, 100))),    # 3: ACKs frame 2
        (600, False, wp_on),                                        # 4
        (1100, False, wp_on),                                       # 5: retransmission of 4
        (1112, True, encode(Message(0, 1, 101, Action.ACK, 200))),  # 6: ACKs frame 5
        (1200, False, passthrough),                                 # 7
        (1210, False, bytes(bad_crc)),                              # 8: MCP-PAY-6
        (1220, True, build_datagram(0, 1, 102, int(Action.MISSION_READY), b"\x00\x02")),  # ID 2 from 1
        (1230, True, encode(Message(0, 1, 103, Action.ACK, 999))),  # 10: ACK of nothing here
        # 11: MCP-PAY-6, a frame of an id the dialect has not (32765): no checksum of it is valid
        (1240, False, build_datagram(1, 0, 202, int(Action.MAV_PASSTHROUGH),
                                     bytes([0xFD, 3, 0, 0, 5, 1, 1]) + (32765).to_bytes(3, "little") + b"\x01\x02\x03\x12\x34")),
    ]
    path = tmp_path / "t.mcap"
    with McapRecorder(path) as rec:
        for ms, from_drone, data in traffic:
            rec.datagram("rx" if from_drone else "tx", data, DRONE, T0 + ms * MS, local=MANAGER)
    rows = _dissect(tmp_path, path, scripts)
    assert len(rows) == len(traffic)
    r = {int(x["frame.number"]): x for x in rows}
    assert r[2]["centmesh.retransmission_of"] == "1" and "retransmission of frame 1" in r[2]["_ws.col.Info"]
    assert "Retransmission" in r[2]["_ws.expert.message"]
    assert r[3]["centmesh.acks"] == "2" and r[1]["centmesh.acked_in"] == r[2]["centmesh.acked_in"] == "3"
    assert float(r[2]["centmesh.ack_time_ms"]) == pytest.approx(10.0, abs=0.01)
    assert float(r[1]["centmesh.ack_time_ms"]) == pytest.approx(510.0, abs=0.01)
    assert "[ACKed in frame 3, +10.0 ms]" in r[2]["_ws.col.Info"]
    assert r[5]["centmesh.retransmission_of"] == "4" and r[6]["centmesh.acks"] == "5"
    assert r[4]["centmesh.item.command"] == "22"
    assert r[7]["centmesh.mavlink_msg"] == "HEARTBEAT" and r[7]["mavlink_proto.msgid"] == "0"
    assert r[7]["centmesh.rule"] == "" and r[8]["centmesh.rule"] == "MCP-PAY-6"
    assert "CRC" in r[8]["_ws.expert.message"]
    assert r[9]["centmesh.rule"] == "MCP-ROB-4" and "(D-3)" in r[9]["_ws.expert.message"]
    assert r[10]["centmesh.acks"] == "" and "ACK of seq 999" in r[10]["_ws.expert.message"]
    assert r[11]["centmesh.rule"] == "MCP-PAY-6" and "not in the ardupilotmega dialect" in r[11]["_ws.expert.message"]
    _check_rules(rows, {n: d for n, (_, _, d) in enumerate(traffic, 1)})
    # the names, as tshark prints them
    verbose = subprocess.run([_tshark(), "-2", "-n", "-X", f"lua_script:{scripts[1]}", "-X",
                              f"lua_script:{scripts[0]}", "-r", str(tmp_path / "t.pcapng"), "-V",
                              "-Y", "frame.number == 4 || frame.number == 7"], capture_output=True, text=True,
                             timeout=120).stdout
    assert "WP_On (4)" in verbose and "MAV_CMD_NAV_TAKEOFF (22)" in verbose
    assert "MAV_FRAME_GLOBAL_RELATIVE_ALT_INT (6)" in verbose and "MAV_TYPE_GCS (6)" in verbose


@pytest.mark.slow
@pytest.mark.parametrize("name", ["challenge1", "challenge2", "challenge3", "drone-suite"])
def test_tshark_on_the_golden_captures(tmp_path, scripts, name):
    from mcp_conform.traceio.reader import Datagram, open_capture

    datagrams = {n: r.data for n, r in enumerate((r for r in open_capture(GOLDEN / f"{name}.mcap")
                                                  if type(r) is Datagram), 1)}
    rows = _dissect(tmp_path, GOLDEN / f"{name}.mcap", scripts)
    assert len(rows) == len(datagrams)  # every datagram is centmesh, on whatever port
    assert all(r["centmesh.seq"] or r["centmesh.rule"] == "MCP-ROB-1" for r in rows)
    _check_rules(rows, datagrams)
    assert _check_acks(rows) >= 4
    if name.startswith("challenge"):
        assert all(not r["centmesh.rule"] for r in rows)


def _conventional_ports() -> set[int]:
    """The UDP ports tshark hands to a dissector of its own (``tshark -G decodes``: 19999 to
    GPRS-NS, 20000 to DNP3, ...): a datagram there goes to that dissector, never to our
    heuristic, as in a user's Wireshark (``-o centmesh.ports`` is their remedy)."""
    proc = subprocess.run([_tshark(), "-G", "decodes"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return {int(f[1]) for f in (line.split("\t") for line in proc.stdout.splitlines())
            if len(f) >= 2 and f[0] == "udp.port" and f[1].isdigit()}


def _fuzz_capture(path: Path, cases: int, seed: int, conventional: set[int]) -> int:
    """The reference drone on a port of no convention, fed the stateless fuzzer's cases
    (fuzz.mutators) 2 ms apart, both directions recorded as mcp-fuzz's target sees them;
    returns the drone's port. Ours is none of ``conventional``."""
    from mcp_conform.fuzz.mutators import CaseGenerator

    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))  # ours before the node's port is chosen: no race for it
    while sock.getsockname()[1] in conventional:
        sock.close()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
    us = sock.getsockname()[1]
    sock.settimeout(0.2)
    stop = threading.Event()
    got = threading.Event()
    node = None
    try:
        with McapRecorder(path, local=("127.0.0.1", us)) as rec:
            def receive() -> None:
                while not stop.is_set():
                    try:
                        data, addr = sock.recvfrom(70000)
                    except OSError:
                        continue
                    rec.datagram("rx", data, addr, time.time_ns())
                    got.set()

            t = threading.Thread(target=receive, daemon=True)
            t.start()
            # started again on a fresh port if it exits first; its stderr in the failure
            node, port = start_node(lambda p: [sys.executable, "-m", "mcp_conform.reference_impl", "drone", "--id", "1",
                                               "--bind", f"127.0.0.1:{p}", "--send-to", f"127.0.0.1:{us}",
                                               "--rto", "0.3", "-q"], got.wait, cwd=ROOT)
            time.sleep(0.7)  # its Mission_Ready, retransmitted
            gen = CaseGenerator(seed, node_id=1, broadcast_id=65535)
            for _ in range(cases):
                data = gen.next().data
                t_ns = time.time_ns()  # before the send: the node's answer comes after it
                sock.sendto(data, ("127.0.0.1", port))
                rec.datagram("tx", data, ("127.0.0.1", port), t_ns)
                time.sleep(0.002)
            time.sleep(0.5)
            stop.set()
            t.join(5)
    finally:
        stop.set()
        if node is not None:
            node.stop()
        sock.close()
    return port


@pytest.mark.slow
def test_tshark_on_a_fuzz_capture(tmp_path, scripts):
    from mcp_conform.traceio.reader import Datagram, open_capture

    path = tmp_path / "fuzz.mcap"
    conventional = _conventional_ports()
    node = _fuzz_capture(path, cases=600, seed=24, conventional=conventional)
    while node in conventional:  # recorded again: a run whose drone got 19999 was dissected as GPRS-NS
        node = _fuzz_capture(path, cases=600, seed=24, conventional=conventional)
    records = [r for r in open_capture(path) if type(r) is Datagram]
    datagrams = {n: r.data for n, r in enumerate(records, 1)}
    rows = _dissect(tmp_path, path, scripts)
    to_node = [r for r in rows if r["udp.dstport"] == str(node)]
    assert len(rows) == len(datagrams) and len(to_node) >= 600  # each one is centmesh, no plain UDP
    malformed = [r for r in to_node if r["centmesh.rule"]]
    assert len(malformed) > 200, len(malformed)
    _check_rules(rows, datagrams)
    passthrough = [r for r in to_node if r["centmesh.action"] == str(int(Action.MAV_PASSTHROUGH))
                   and not r["centmesh.rule"]]
    assert passthrough and all(r["mavlink_proto.msgid"] for r in passthrough)
    assert _check_acks(rows) >= 50
    assert any(r["centmesh.retransmission_of"] for r in rows if r["udp.srcport"] == str(node))


def test_the_ports_preference_makes_any_datagram_there_centmesh(tmp_path):
    """``-o centmesh.ports:RANGE``: a datagram on such a port is MCP without a preamble to find
    it by — 2 bytes and 0 bytes, both MCP-ROB-1; without the preference, plain UDP."""
    tshark = _tshark()
    from scapy.layers.inet import IP, UDP
    from scapy.layers.l2 import Ether
    from scapy.utils import wrpcap

    pcap, lua = tmp_path / "p.pcap", tmp_path / "centmesh.lua"
    wrpcap(str(pcap), [Ether() / IP(src="127.0.0.1", dst="127.0.0.1") / UDP(sport=50000, dport=40005) / b"xx",
                       Ether() / IP(src="127.0.0.1", dst="127.0.0.1") / UDP(sport=50001, dport=40005)])
    assert _run(dissector, "dissector", "-o", str(lua))[0] == 0

    def rules(*opts: str) -> list[str]:
        proc = subprocess.run([tshark, "-n", *opts, "-X", f"lua_script:{lua}", "-r", str(pcap), "-T", "fields",
                               "-e", "centmesh.rule"], capture_output=True, text=True, timeout=120)
        assert proc.returncode == 0, proc.stderr
        return proc.stdout.splitlines()

    assert rules("-o", "centmesh.ports:40000-40010") == ["MCP-ROB-1", "MCP-ROB-1"]
    assert rules() == ["", ""]

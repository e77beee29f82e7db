"""The Nsqd scapy layer and Wireshark dissector, both generated from spec/nsqd.yaml, on one
TCP conversation written as a pcap: a frame cut into single-byte segments, frames batched in
one segment, a length of 0 (NSQD-FRM-4), UPDATE's state by name (issue 20)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest
from scapy.layers.inet import IP, TCP
from scapy.packet import Raw
from scapy.sendrecv import sniff
from scapy.sessions import TCPSession
from scapy.utils import wrpcap

from mcp_conform.captures.dissector_nsqd import generate
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import encode
from mcp_conform.spec.scapy_nsqd import BODY_LAYERS, NSQD_Frame

CLIENT = (encode(NSQD, "TAKEOFF")
          + encode(NSQD, "SET_RPYTFF", roll="1.5", pitch="2", yaw="3", thrust="4", flag=1, file_name="a.csv")
          + bytes.fromhex("00000000"))
UPDATE = dict(roll=0, pitch=0, yaw=0, thrust=0, lat=55, lon=10, alt=3)
SERVER = (encode(NSQD, "UPDATE", **UPDATE, state=2) + encode(NSQD, "UPDATE", **UPDATE, state=8)
          + encode(NSQD, "ERROR", text="unknown message id 200"))


def conversation(path: Path) -> Path:
    c, s, cp, sp = "127.0.0.1", "127.0.0.2", 40000, NSQD.port("backend")
    cs, ss = 1000, 5000
    pk = [IP(src=c, dst=s) / TCP(sport=cp, dport=sp, flags="S", seq=cs - 1),
          IP(src=s, dst=c) / TCP(sport=sp, dport=cp, flags="SA", seq=ss - 1, ack=cs),
          IP(src=c, dst=s) / TCP(sport=cp, dport=sp, flags="A", seq=cs, ack=ss)]
    for i in range(5):  # TAKEOFF one byte per segment
        pk.append(IP(src=c, dst=s) / TCP(sport=cp, dport=sp, flags="PA", seq=cs + i, ack=ss) / Raw(CLIENT[i:i + 1]))
    pk.append(IP(src=c, dst=s) / TCP(sport=cp, dport=sp, flags="PA", seq=cs + 5, ack=ss) / Raw(CLIENT[5:]))
    pk.append(IP(src=s, dst=c) / TCP(sport=sp, dport=cp, flags="PA", seq=ss, ack=cs + len(CLIENT)) / Raw(SERVER))
    wrpcap(str(path), pk)
    return path


def test_scapy_layer_builds_the_codecs_bytes_and_reassembles_a_stream(tmp_path):
    built = NSQD_Frame(msg_id=1) / BODY_LAYERS["UPDATE"](**UPDATE, state=2)
    assert bytes(built) == encode(NSQD, "UPDATE", **UPDATE, state=2)
    frame = NSQD_Frame(encode(NSQD, "SET_RPYTFF", roll="1.5", pitch="2", yaw="3", thrust="4", flag=1, file_name="a.csv"))
    assert frame.length == 30 and frame[BODY_LAYERS["SET_RPYTFF"]].file_name == b"a.csv"
    pkts = sniff(offline=str(conversation(tmp_path / "n.pcap")), session=TCPSession)
    frames = [p[NSQD_Frame] for p in pkts if p.haslayer(NSQD_Frame)]
    assert [f.msg_id for f in frames][:1] == [NSQD.message("TAKEOFF").id]  # whole, from five segments


def test_wireshark_dissector_reassembles_names_and_flags(tmp_path):
    tshark = shutil.which("tshark")
    if tshark is None:
        pytest.skip("tshark is not installed (apt-get install -y tshark)")
    lua = tmp_path / "nsqd.lua"
    lua.write_text(generate())
    out = subprocess.run([tshark, "-r", str(conversation(tmp_path / "n.pcap")), "-X", f"lua_script:{lua}",
                          "-Y", "nsqd", "-T", "fields", "-E", "separator=|", "-e", "nsqd.id", "-e", "nsqd.length",
                          "-e", "nsqd.update.state", "-e", "nsqd.set_rpytff.file_name", "-e", "_ws.expert.message"],
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    rows = [line.split("|") for line in out.stdout.strip().splitlines()]
    assert rows[0][:2] == ["4", "5"]  # TAKEOFF, reassembled from five one-byte segments
    assert rows[1][3] == "a.csv" and "NSQD-FRM-4" in rows[1][4]  # a frame and a length of 0 in one segment
    assert rows[2][0] == "1,1,0" and rows[2][2] == "2,8"  # two UPDATEs and an ERROR in one segment
    shown = subprocess.run([tshark, "-r", str(tmp_path / "n.pcap"), "-X", f"lua_script:{lua}", "-Y", "nsqd.update.state",
                            "-V"], capture_output=True, text=True, timeout=60).stdout
    assert "START_TEST (8)" in shown

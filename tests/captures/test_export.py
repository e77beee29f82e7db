"""mcp-capture export (pcap/pcapng through scapy) and the generated Wireshark dissector,
checked in tshark field by field against our own decoder."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest

from captures import dissector, export
from spec import SPEC
from spec.codec import (
    HEADER_SIZE,
    ITEM_SIZE,
    Action,
    Message,
    MissionItem,
    build_datagram,
    decode,
    encode,
)
from spec.mavframe import heartbeat_frame
from tests.capturing import run_subcommand
from traceio.recorder import McapRecorder

ITEMS = (MissionItem(0.5, 1.5, 2.5, 3.5, 35.771103, -78.674659, 12.25, 0, 16, 1, 1, 3, 1, 1),
         MissionItem(0.0, 0.0, 0.0, 0.0, 35.772, -78.675, 30.0, 1, 22, 2, 3, 6, 0, 1))
MANAGER = ("127.0.0.1", 7889)
DRONE = ("127.0.0.2", 7890)
T0 = 1_700_000_000_123_456_000

#: one well-formed datagram per action code on the wire
MESSAGES = [
    Message(0, 1, 100, Action.MISSION_READY, 1),
    Message(1, 0, 200, Action.START_MISSION, None),
    Message(1, 0, 201, Action.END_MISSION, None),
    Message(1, 0, 202, Action.WP_LIST, ITEMS),
    Message(1, 0, 203, Action.WP_ON, ITEMS[0]),
    Message(1, 0, 204, Action.WP_OFF, None),
    Message(1, 0, 205, Action.OBSTACLES_LIST, ITEMS[1:]),
    Message(0, 1, 101, Action.ACK, 205),
    Message(1, 0, 206, Action.MAV_PASSTHROUGH, heartbeat_frame()),
]
#: malformed datagrams and the rule the dissector must name
MALFORMED = [
    (b"NCSU-CM\x01", "MCP-ROB-1"),
    (b"XCSU-CM\x01\x01" + bytes(8), "MCP-ROB-2"),
    (build_datagram(1, 0, 300, 42), "MCP-ROB-3"),
    (build_datagram(1, 0, 301, int(Action.WP_ON), b"\x00" * 5), "MCP-ROB-4"),
    (build_datagram(1, 0, 302, int(Action.WP_LIST), b"\x00\x03" + bytes(ITEM_SIZE)), "MCP-ROB-4"),
]


def _capture(path) -> list[bytes]:
    """A manager-side MCAP with every datagram above, 1 ms apart."""
    datagrams = [encode(m) for m in MESSAGES] + [d for d, _ in MALFORMED]
    with McapRecorder(path) as rec:
        for n, data in enumerate(datagrams):
            from_drone = n < len(MESSAGES) and MESSAGES[n].src == 1
            rec.datagram("rx" if from_drone else "tx", data, DRONE, T0 + n * 1_000_000, local=MANAGER)
    return datagrams


_run = run_subcommand  # one mcp-capture subcommand in process (tests.capturing)


@pytest.mark.parametrize("suffix", ["pcap", "pcapng"])
def test_export_keeps_addresses_timestamps_and_bytes(tmp_path, suffix):
    from scapy.layers.inet import IP, UDP
    from scapy.utils import rdpcap

    datagrams = _capture(tmp_path / "c.mcap")
    out = tmp_path / f"c.{suffix}"
    code, text, _ = _run(export, "export", str(tmp_path / "c.mcap"), "--pcap", str(out))
    assert code == 0 and f"wrote {len(datagrams)} datagrams" in text
    with open(out, "rb") as f:
        assert f.read(4) == (b"\x0a\x0d\x0d\x0a" if suffix == "pcapng" else b"\xd4\xc3\xb2\xa1")
    pkts = rdpcap(str(out))
    assert [bytes(p[UDP].payload) for p in pkts] == datagrams
    first, ack = pkts[1], pkts[7]  # Start_Mission: manager -> drone; the ACK: drone -> manager
    assert (first[IP].src, first[UDP].sport, first[IP].dst, first[UDP].dport) == (*MANAGER, *DRONE)
    assert (ack[IP].src, ack[UDP].sport, ack[IP].dst, ack[UDP].dport) == (*DRONE, *MANAGER)
    assert abs(float(pkts[3].time) - (T0 + 3_000_000) / 1e9) < 1e-6


def test_export_errors_are_one_line(tmp_path):
    code, _, err = _run(export, "export", str(tmp_path / "missing.mcap"), "--pcap", str(tmp_path / "o.pcap"))
    assert code == 2 and err.count("\n") == 1 and "missing.mcap" in err
    _capture(tmp_path / "c.mcap")
    code, _, err = _run(export, "export", str(tmp_path / "c.mcap"), "--pcap", str(tmp_path / "no" / "o.pcap"))
    assert code == 2 and "cannot write" in err


def test_dissector_is_derived_from_the_spec():
    lua = dissector.generate()
    assert 'Proto("centmesh"' in lua and 'Proto("mcp"' not in lua
    assert SPEC.sha256 in lua and SPEC.preamble.hex().upper() in lua
    for a in SPEC.actions:
        assert (f'[{a.code}] = "{a.wire_name}"' in lua) == a.on_wire
    for f in SPEC.mission_item["fields"]:
        assert f'"centmesh.item.{f["name"]}"' in lua
    for rule in ("MCP-ROB-1", "MCP-ROB-2", "MCP-ROB-3", "MCP-ROB-4"):
        assert SPEC.rule(rule).text.split(" (")[0][:40] in lua
    for port in SPEC.protocol["ports"].values():
        assert f"udp_port:add({port}, centmesh)" in lua
    assert 'register_heuristic("udp"' in lua


def test_dissector_install_writes_the_plugin_folder(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    code, out, _ = _run(dissector, "dissector", "--install")
    target = tmp_path / ".local" / "lib" / "wireshark" / "plugins" / "centmesh.lua"
    assert code == 0 and str(target) in out and target.read_text() == dissector.generate()
    code, out, _ = _run(dissector, "dissector")
    assert code == 0 and out == dissector.generate()


# ---------------------------------------------------------------- tshark
def _tshark() -> str:
    """tshark, installed through apt where it is missing and we may; else skip with why."""
    path = shutil.which("tshark")
    if path:
        return path
    if os.geteuid() != 0 or not shutil.which("apt-get"):
        pytest.skip("tshark is not installed and cannot be installed here (needs root and apt-get)")
    env = dict(os.environ, DEBIAN_FRONTEND="noninteractive")
    proc = subprocess.run(["apt-get", "install", "-y", "-q", "tshark"], env=env, capture_output=True,
                          text=True, timeout=600)
    path = shutil.which("tshark")
    if not path:
        pytest.skip(f"tshark could not be installed through apt: {proc.stderr.strip()[-200:]}")
    return path


FIELDS = ["frame.number", "centmesh.preamble", "centmesh.dst", "centmesh.src", "centmesh.seq",
          "centmesh.action", "centmesh.ready_id", "centmesh.ack_seq", "centmesh.count", "centmesh.mavlink"] + \
         [f"centmesh.item.{f['name']}" for f in SPEC.mission_item["fields"]] + ["_ws.expert.message"]


@pytest.mark.slow
def test_tshark_dissects_every_action_code_like_our_decoder(tmp_path):
    tshark = _tshark()
    datagrams = _capture(tmp_path / "c.mcap")
    assert _run(export, "export", str(tmp_path / "c.mcap"), "--pcap", str(tmp_path / "c.pcapng"))[0] == 0
    lua = tmp_path / "centmesh.lua"
    assert _run(dissector, "dissector", "-o", str(lua))[0] == 0
    cmd = [tshark, "-n", "-X", f"lua_script:{lua}", "-r", str(tmp_path / "c.pcapng"), "-Y", "centmesh",
           "-T", "fields", "-E", "separator=|", "-E", "occurrence=a", "-E", "aggregator=,"]
    for f in FIELDS:
        cmd += ["-e", f]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    rows = [dict(zip(FIELDS, line.split("|"), strict=True)) for line in proc.stdout.splitlines()]
    assert len(rows) == len(datagrams), proc.stdout  # every one recognised, malformed included
    for row, sent in zip(rows, MESSAGES, strict=False):
        data = encode(sent)
        msg = decode(data)  # our decoder's reading is the reference
        assert row["centmesh.preamble"].replace(":", "") == data[:9].hex()
        assert (int(row["centmesh.dst"]), int(row["centmesh.src"]), int(row["centmesh.seq"]),
                int(row["centmesh.action"])) == (msg.dst, msg.src, msg.seq, int(msg.action)), row
        assert row["_ws.expert.message"] == ""
        p = msg.payload
        if msg.action == Action.MISSION_READY:
            assert int(row["centmesh.ready_id"]) == p
        elif msg.action == Action.ACK:
            assert int(row["centmesh.ack_seq"]) == p
        elif msg.action == Action.MAV_PASSTHROUGH:
            assert bytes.fromhex(row["centmesh.mavlink"].replace(":", "")) == p
        items = (p,) if isinstance(p, MissionItem) else p if isinstance(p, tuple) else ()
        if msg.action in (Action.WP_LIST, Action.OBSTACLES_LIST):
            assert int(row["centmesh.count"]) == len(items)
        for f in MissionItem._fields:
            got = row[f"centmesh.item.{f}"]
            values = got.split(",") if got else []
            assert len(values) == len(items), (f, row)
            for v, item in zip(values, items, strict=True):
                # tshark prints float32 fields with about 6 significant digits
                assert float(v) == pytest.approx(getattr(item, f), rel=1e-5, abs=1e-5), (msg.action, f, v)
    for row, (data, rule) in zip(rows[len(MESSAGES):], MALFORMED, strict=True):
        assert rule in row["_ws.expert.message"], (rule, row)
        if len(data) >= HEADER_SIZE:
            assert int(row["centmesh.seq"]) == int.from_bytes(data[13:15], "big")

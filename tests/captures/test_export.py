"""mcp-capture export (pcap/pcapng built with dpkt; read back by scapy, tshark and our own
reader) and the generated Wireshark dissector, checked in tshark field by field against our
own decoder."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest

from mcp_conform.captures import dissector, export
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import (
    HEADER_SIZE,
    ITEM_SIZE,
    Action,
    Message,
    MissionItem,
    build_datagram,
    decode,
    encode,
)
from mcp_conform.spec.mavframe import heartbeat_frame
from mcp_conform.traceio.recorder import McapRecorder
from tests.capturing import run_subcommand

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


#: times that the float arithmetic before (t_ns / 1e9 through scapy) stamped a microsecond off:
#: 500 ns past a microsecond, just under a second's end (a pcap's rounding carries into the
#: seconds), whole microseconds, and times of the golden drone-suite capture
TIMES = [0, 1_000_000_500, 1_700_000_000_000_001_000, 1_700_000_000_999_999_500, 1_700_000_001_123_456_499,
         1_700_000_001_123_456_500, 1_700_000_001_123_456_501, 1_795_629_244_084_981_505,
         1_795_629_244_661_675_949, 2**32 * 10**9 - 1_000_000_000]
#: (local, peer, direction, sender's MCP id) and what the packet must say: (src, dst) after
#: the export's rules (a wildcard or missing host is loopback, a missing port the sender's
#: role's, MCP-TRN-1)
PEERS = [((("10.1.2.3", 7889), ("10.1.2.4", 40001), "tx", 0), (("10.1.2.3", 7889), ("10.1.2.4", 40001))),
         ((("10.1.2.3", 7889), ("10.1.2.4", 40001), "rx", 1), (("10.1.2.4", 40001), ("10.1.2.3", 7889))),
         ((("0.0.0.0", 7889), ("192.168.7.9", 0), "rx", 3), (("192.168.7.9", 7890), ("127.0.0.1", 7889))),
         ((None, ("192.168.7.9", 0), "tx", 0), (("127.0.0.1", 7889), ("192.168.7.9", 7890)))]


def _read_back(reader: str, path) -> list[tuple[int, tuple, tuple, bytes]]:
    """(time in ns, (src host, port), (dst host, port), UDP payload) of every packet of ``path``
    as tshark or our own reader (traceio.reader) reads it."""
    if reader == "traceio":
        from mcp_conform.traceio.reader import Datagram, open_capture

        return [(r.t_ns, r.src_addr, r.dst_addr, bytes(r.data)) for r in open_capture(path) if type(r) is Datagram]
    tshark = shutil.which("tshark")
    if tshark is None:
        pytest.skip("tshark is not installed (bash .ci/apt-tools); the traceio case reads the same files")
    proc = subprocess.run([tshark, "-n", "-r", str(path), "-T", "fields", "-e", "frame.time_epoch",
                           "-e", "ip.src", "-e", "udp.srcport", "-e", "ip.dst", "-e", "udp.dstport",
                           "-e", "udp.payload"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    rows = []
    for line in proc.stdout.splitlines():
        t, sh, sp, dh, dp, payload = line.split("\t")
        sec, frac = t.split(".")
        rows.append((int(sec) * 10**9 + int(frac.ljust(9, "0")), (sh, int(sp)), (dh, int(dp)), bytes.fromhex(payload)))
    return rows


@pytest.mark.parametrize("reader", ["tshark", "traceio"])
@pytest.mark.parametrize("suffix", ["pcap", "pcapng"])
def test_every_packet_reads_back_with_the_captures_addresses_ports_times_and_bytes(tmp_path, suffix, reader):
    """Packet by packet, what a reader finds in the export is what the MCAP held: the
    addresses and ports (the export's rules for missing ones), the payload, and the time at
    the file's resolution computed from the capture's nanoseconds (pcap: to the nearest
    microsecond; pcapng: cut to the microsecond, as scapy's writer did)."""
    expected = []
    with McapRecorder(tmp_path / "c.mcap") as rec:
        for n, t_ns in enumerate(TIMES):
            (local, peer, direction, sender), (src, dst) = PEERS[n % len(PEERS)]
            dst_id = 1 if sender == 0 else 0
            data = encode(Message(dst_id, sender, n, Action.ACK, 7 * n)) + bytes(n * 150)  # up to 1.4 kB
            rec.datagram(direction, data, peer, t_ns, local=local)
            us = t_ns // 1000 if suffix == "pcapng" else (t_ns + 500) // 1000
            expected.append((us * 1000, src, dst, data))
    out = tmp_path / f"c.{suffix}"
    code, text, err = _run(export, "export", str(tmp_path / "c.mcap"), "--pcap", str(out))
    assert code == 0 and f"wrote {len(TIMES)} datagrams" in text, err
    got = _read_back(reader, out)
    assert len(got) == len(expected)
    for k, (g, e) in enumerate(zip(got, expected, strict=True)):
        assert g == e, (k, TIMES[k], g[:3], e[:3])


def test_export_errors_are_one_line(tmp_path):
    code, _, err = _run(export, "export", str(tmp_path / "missing.mcap"), "--pcap", str(tmp_path / "o.pcap"))
    assert code == 2 and err.count("\n") == 1 and "missing.mcap" in err
    _capture(tmp_path / "c.mcap")
    code, _, err = _run(export, "export", str(tmp_path / "c.mcap"), "--pcap", str(tmp_path / "no" / "o.pcap"))
    assert code == 2 and "cannot write" in err


@pytest.mark.parametrize("peer,size,why", [
    (("localhost", 7890), 20, "'localhost' is not an IPv4 address"),  # scapy looked the name up
    (("::1", 7890), 20, "'::1' is not an IPv4 address"),
    (("10.0.0.1", 70000), 20, "port 70000 is outside 0..65535"),  # scapy: struct.error, a traceback
    (("10.0.0.1", 7890), 65508, "a 65508-byte datagram is longer than IPv4/UDP carries (65507)"),
])
@pytest.mark.parametrize("suffix", ["pcap", "pcapng"])
def test_a_datagram_no_packet_can_carry_is_one_line_and_no_output(tmp_path, suffix, peer, size, why):
    with McapRecorder(tmp_path / "c.mcap") as rec:
        rec.datagram("tx", encode(MESSAGES[1]), DRONE, T0, local=MANAGER)
        rec.datagram("tx", encode(MESSAGES[1]).ljust(size, b"\0"), peer, T0 + 1000, local=MANAGER)
    out = tmp_path / f"o.{suffix}"
    code, text, err = _run(export, "export", str(tmp_path / "c.mcap"), "--pcap", str(out))
    assert code == 2 and err == f"mcp-capture: error: export: {tmp_path / 'c.mcap'}: datagram #1: {why}\n", err
    assert not out.exists() and text == ""


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

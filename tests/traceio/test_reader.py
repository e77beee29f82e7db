"""traceio.reader: MCAP, pcap and pcapng into one stream of records.

Every link type a user's tcpdump or Wireshark writes, IP fragments, snap-length cuts, and
files cut at every byte offset or followed by garbage: a prefix of the records and a
``truncated`` reason, never a traceback.
"""

from __future__ import annotations

import gzip
import struct

import pytest
from scapy.layers.inet import IP, TCP, UDP, fragment
from scapy.layers.l2 import CookedLinux, CookedLinuxV2, Dot1Q, Ether, Loopback
from scapy.packet import Raw
from scapy.utils import wrpcap, wrpcapng

import mcp_conform.traceio.recorder as recorder_mod
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.traceio.reader import (
    CaptureError,
    CaseMark,
    Datagram,
    MavlinkFrame,
    Truncated,
    open_capture,
)
from mcp_conform.traceio.recorder import McapRecorder

START = encode(Message(1, 0, 5, Action.START_MISSION))
ACK = encode(Message(0, 1, 9, Action.ACK, 5))
MANAGER, DRONE = ("10.0.0.1", 7889), ("10.0.0.2", 7890)


def udp(data: bytes, src=MANAGER, dst=DRONE, ident: int = 1) -> IP:
    return IP(src=src[0], dst=dst[0], id=ident) / UDP(sport=src[1], dport=dst[1]) / Raw(data)


def conversation() -> list[IP]:
    """Start_Mission, its ACK, a datagram of another protocol, garbage to the drone's port."""
    return [udp(START), udp(ACK, DRONE, MANAGER, 2), udp(b"dns?", ("10.0.0.9", 5353), ("10.0.0.7", 53), 3),
            udp(b"\x00" * 5, ("10.0.0.3", 40000), DRONE, 4)]


LINKS = {
    "ether": lambda p: Ether() / p,
    "vlan": lambda p: Ether() / Dot1Q(vlan=7) / p,
    "sll": lambda p: CookedLinux(pkttype=0, lladdrtype=1, proto=0x800) / p,
    "sll2": lambda p: CookedLinuxV2(proto=0x800, pkttype=4, lladdrtype=1) / p,
    "null": lambda p: Loopback(type=2) / p,
    "raw": lambda p: p,
}
LINKTYPES = {"ether": 1, "vlan": 1, "sll": 113, "sll2": 276, "null": 0, "raw": 101}


def write(path, pkts, link="ether", ng=False, **kw):
    framed = [LINKS[link](p) for p in pkts]
    for i, p in enumerate(framed):
        p.time = 100 + i * 0.25
    if ng:
        wrpcapng(str(path), framed)
    else:
        wrpcap(str(path), framed, linktype=LINKTYPES[link], **kw)
    return path


def datagrams(path):
    cap = open_capture(path)
    return [r for r in cap if type(r) is Datagram], cap


@pytest.mark.parametrize("ng", [False, True], ids=["pcap", "pcapng"])
@pytest.mark.parametrize("link", sorted(LINKS))
def test_every_link_type(tmp_path, link, ng):
    got, cap = datagrams(write(tmp_path / f"x.{'pcapng' if ng else 'pcap'}", conversation(), link, ng))
    assert cap.format == ("pcapng" if ng else "pcap")
    assert cap.truncated is None
    assert [(d.index, d.src_addr, d.dst_addr, d.data) for d in got] == [
        (0, MANAGER, DRONE, START), (1, DRONE, MANAGER, ACK), (2, ("10.0.0.3", 40000), DRONE, b"\x00" * 5)]
    assert [d.t_ns for d in got] == [100_000_000_000, 100_250_000_000, 100_750_000_000]
    assert "1 UDP datagram(s) of other protocols skipped" in cap.notes
    if link == "sll2":  # the cooked header says which way the packet went
        assert {d.direction for d in got} == {"tx"}


def test_nanosecond_big_endian_and_gzip(tmp_path):
    pkts = [Ether() / udp(START)]
    pkts[0].time = 1.000000123
    wrpcap(str(tmp_path / "n.pcap"), pkts, nano=True, endianness=">")
    (got,), _ = datagrams(tmp_path / "n.pcap")
    assert got.t_ns == 1_000_000_123
    (tmp_path / "n.pcap.gz").write_bytes(gzip.compress((tmp_path / "n.pcap").read_bytes()))
    (gz,), cap = datagrams(tmp_path / "n.pcap.gz")
    assert gz == got and cap.format == "pcap.gz"


def test_ethernet_padding_and_non_udp_are_not_payload(tmp_path):
    short = Ether() / udp(b"\x01")  # padded to 60 bytes on the wire
    path = tmp_path / "p.pcap"
    wrpcap(str(path), [Ether() / udp(START), Ether(bytes(short) + b"\xee" * 20),
                       Ether() / IP(src="10.0.0.1", dst="10.0.0.2") / TCP(dport=7890)])
    got, cap = datagrams(path)
    assert [d.data for d in got] == [START, b"\x01"]
    assert "1 non-UDP or non-IP packet(s) skipped" in cap.notes


def test_mcp_found_by_preamble_on_any_port(tmp_path):
    odd = [udp(START, ("10.1.1.1", 1234), ("10.1.1.2", 4321)), udp(b"junk", ("10.1.1.2", 4321), ("10.1.1.1", 1234))]
    got, _ = datagrams(write(tmp_path / "o.pcap", odd))
    assert [d.data for d in got] == [START, b"junk"]


def test_ip_fragments_reassembled_in_any_order(tmp_path):
    big = START + b"\xaa" * 3000
    frags = fragment(udp(big, ident=77), fragsize=1000)
    assert len(frags) == 4
    path = write(tmp_path / "f.pcap", [frags[2], frags[0], frags[3], frags[1], udp(ACK, DRONE, MANAGER)])
    got, cap = datagrams(path)
    assert [d.data for d in got] == [big, ACK]
    assert "1 IP-fragmented datagram(s) reassembled" in cap.notes
    got, cap = datagrams(write(tmp_path / "g.pcap", frags[:3]))
    assert got == [] and "1 IP-fragmented datagram(s) incomplete at the end of the capture, dropped" in cap.notes


def test_snaplen_cut_datagram_is_dropped_and_counted(tmp_path):
    path = tmp_path / "s.pcap"
    wrpcap(str(path), [Ether() / udp(START + b"\x00" * 100), Ether() / udp(ACK, DRONE, MANAGER)], snaplen=64)
    raw = bytearray(path.read_bytes())
    # rewrite the first record as tcpdump -s 64 would: caplen 64, wirelen the whole frame
    first = Ether() / udp(START + b"\x00" * 100)
    rec = struct.pack("<IIII", 0, 0, 64, len(first)) + bytes(first)[:64]
    rest = raw[24 + 16 + len(first):]
    path.write_bytes(bytes(raw[:24]) + rec + bytes(rest))
    got, cap = datagrams(path)
    assert [d.data for d in got] == [ACK]
    assert "1 UDP datagram(s) cut by the snap length, dropped" in cap.notes


def test_loopback_outgoing_copy_on_any_is_skipped(tmp_path):
    def sll(pkttype):
        return CookedLinux(pkttype=pkttype, lladdrtype=772, proto=0x800) / udp(START)
    path = tmp_path / "any.pcap"
    wrpcap(str(path), [sll(4), sll(0)], linktype=113)
    got, cap = datagrams(path)
    assert len(got) == 1 and got[0].direction is None
    assert "1 outgoing loopback copies skipped (seen again incoming)" in cap.notes


@pytest.mark.parametrize("name,content,words", [
    ("empty", b"", "empty file"),
    ("text", b"hello world, not a capture\n", "not a capture"),
    ("mcapcut", b"\x89MCA", "cut inside its magic"),
    ("pcaphead", bytes.fromhex("d4c3b2a1") + b"\x02\x00", "file header"),
])
def test_unreadable_files_are_one_line_errors(tmp_path, name, content, words):
    path = tmp_path / name
    path.write_bytes(content)
    with pytest.raises(CaptureError) as exc:
        open_capture(path)
    assert words in str(exc.value) and "\n" not in str(exc.value) and str(path) in str(exc.value)


def test_missing_file(tmp_path):
    with pytest.raises(CaptureError, match="cannot read"):
        open_capture(tmp_path / "nope.pcap")


def growing(path, whole: bytes, cuts):
    """The file cut at each of ``cuts`` (ascending) in turn: written by appending what each
    cut adds, never rewritten: a rewrite truncates, and on ext4 mounted with ``discard`` each
    truncation waited ~4 ms for the freed blocks (20,000 cuts: 77 s of a CI run's wall)."""
    with open(path, "wb") as f:
        at = 0
        for n in cuts:
            f.write(whole[at:n])
            f.flush()
            at = n
            yield n


def records(path):
    try:
        cap = open_capture(path)
    except CaptureError:
        return None, None
    return list(cap), cap


@pytest.mark.parametrize("ng", [False, True], ids=["pcap", "pcapng"])
def test_cut_at_every_byte_and_trailing_garbage(tmp_path, ng):
    full_path = write(tmp_path / "full", [udp(START), udp(ACK, DRONE, MANAGER), udp(START)], "ether", ng)
    whole = full_path.read_bytes()
    full, cap = records(full_path)
    assert cap.truncated is None and len(full) == 3
    cut = tmp_path / "cut"
    header_end = None
    for n in growing(cut, whole, range(len(whole))):
        got, cap = records(cut)
        if got is None:  # only a file cut inside its file header is unreadable
            assert header_end is None, f"unreadable at {n} after a readable cut"
            continue
        header_end = header_end if header_end is not None else n
        body = [r for r in got if type(r) is Datagram]
        assert body == full[:len(body)], n
        if got and type(got[-1]) is Truncated:
            assert cap.truncated == got[-1].reason
        else:  # not truncated: the cut fell exactly between two records
            assert cap.truncated is None
    assert header_end is not None and header_end <= 40
    for junk in (b"\x00", b"garbage!" * 5, b"\xff" * 64):
        cut.write_bytes(whole + junk)
        got, cap = records(cut)
        assert [r for r in got if type(r) is Datagram] == full
        assert cap.truncated and "garbage" in cap.truncated


# ---------------------------------------------------------------- our MCAP files
def small_chunks(monkeypatch):
    """A recorder that writes ~600-byte chunks, so a small file has many of them."""
    writer = recorder_mod.Writer
    monkeypatch.setattr(recorder_mod, "Writer", lambda *a, **k: writer(*a, **{**k, "chunk_size": 600}))


def write_mcap(path, n=12):
    with McapRecorder(path) as rec:
        rec.case_mark("ACK/test_x", "start", 1_000, rules=("MCP-ACK-1",))
        for i in range(n):
            rec.datagram("tx", START, ("127.0.0.1", 7890), 2_000 + 10 * i)
            rec.datagram("rx", ACK, ("127.0.0.1", 40000), 2_005 + 10 * i)
        rec.mavlink("rx", b"\xfd\x09\x00\x00\x00\x01\x01\x00\x00\x00", 3_000, msg_type="HEARTBEAT")
        rec.case_mark("ACK/test_x", "end", 4_000, outcome="passed", rules=("MCP-ACK-1",))
    return path


def test_mcap_records(tmp_path):
    got, cap = records(write_mcap(tmp_path / "r.mcap", n=1))
    assert cap.format == "mcap" and cap.truncated is None
    assert got == [
        CaseMark(1_000, "ACK/test_x", "start", None, ("MCP-ACK-1",)),
        Datagram(0, 2_000, None, ("127.0.0.1", 7890), START, "tx", "mcp-conform"),
        Datagram(1, 2_005, ("127.0.0.1", 40000), None, ACK, "rx", "mcp-conform"),
        MavlinkFrame(0, 3_000, "rx", "HEARTBEAT", b"\xfd\x09\x00\x00\x00\x01\x01\x00\x00\x00"),
        CaseMark(4_000, "ACK/test_x", "end", "passed", ("MCP-ACK-1",)),
    ]


@pytest.mark.parametrize("stride", [11, pytest.param(1, marks=pytest.mark.slow)])
def test_mcap_cut_at_every_byte(tmp_path, monkeypatch, stride):
    """A file cut anywhere (every byte with the slow tests, every 11th in the quick ones);
    every 37th of those cuts read as ``mcap``'s own StreamReader reads it too (each record
    parsed field by field, traceio.mcap_chunks): the same records and the same reason."""
    from mcap.stream_reader import StreamReader

    import mcp_conform.traceio.mcap_chunks as chunks

    small_chunks(monkeypatch)
    path = write_mcap(tmp_path / "r.mcap")
    whole = path.read_bytes()
    full, cap = records(path)
    assert cap.truncated is None and len(full) == 27
    cut = tmp_path / "cut.mcap"
    seen, compared = set(), set()
    for k, n in enumerate(growing(cut, whole, [*range(9), *range(9, len(whole), stride)])):
        got, cap = records(cut)
        if k % 37 == 0:
            with pytest.MonkeyPatch.context() as mp:
                mp.setattr(chunks, "stream_reader", lambda f, limit: StreamReader(
                    f, validate_crcs=True, record_size_limit=limit, emit_chunks=True))
                plain, plain_cap = records(cut)
            assert plain == got and getattr(plain_cap, "truncated", None) == getattr(cap, "truncated", None), n
            compared.add(cap.truncated if cap is not None else None)
        if got is None:
            assert n < 8, n  # only an empty file or one cut inside the magic
            continue
        assert got[-1] == Truncated(cap.truncated), n
        assert got[:-1] == full[:len(got) - 1], n
        seen.add(len(got) - 1)
    assert len(compared) >= 3, compared  # cut inside a chunk, inside the summary, ...
    assert len(seen) > 4  # several whole chunks were recovered along the way
    cut.write_bytes(whole + b"garbage")
    got, cap = records(cut)
    assert got == full and cap.truncated is None
    assert "7 byte(s) after the MCAP footer ignored" in cap.notes


def test_mcap_records_come_out_in_time_order(tmp_path):
    """The recorder's receiver thread may write an ACK before the command it answers."""
    path = tmp_path / "o.mcap"
    with McapRecorder(path) as rec:
        rec.datagram("rx", ACK, ("127.0.0.1", 40000), 5_000_300)
        rec.datagram("tx", START, ("127.0.0.1", 7890), 5_000_100)
        rec.case_mark("X/y", "end", 5_000_200, outcome="passed")
        rec.datagram("tx", START, ("127.0.0.1", 7890), 9_000_000_000)  # far later: flushes the rest
    got, _ = records(path)
    assert [(type(r).__name__, r.t_ns) for r in got] == [
        ("Datagram", 5_000_100), ("CaseMark", 5_000_200), ("Datagram", 5_000_300), ("Datagram", 9_000_000_000)]
    assert [r.index for r in got if type(r) is Datagram] == [0, 1, 2]

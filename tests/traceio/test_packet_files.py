"""The pcap and pcapng readers of ``traceio.packets`` (dpkt's readers and block classes):
several interfaces, direction flags, sections, and a gzip'd file cut anywhere read as the
same file uncompressed (the stream path and the mapped path agree, reasons included)."""

from __future__ import annotations

import gzip
import struct

import pytest
from dpkt import pcapng
from scapy.layers.inet import IP, UDP
from scapy.layers.l2 import Ether
from scapy.utils import wrpcap

from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.traceio.packets import MAX_RECORD
from mcp_conform.traceio.reader import Datagram, open_capture

START = encode(Message(1, 0, 5, Action.START_MISSION))
IPV4 = bytes(IP(src="10.0.0.1", dst="10.0.0.2") / UDP(sport=7889, dport=7890) / START)


def opt(code: int, data: bytes) -> pcapng.PcapngOptionLE:
    return pcapng.PcapngOptionLE(code=code, data=data)


def end() -> pcapng.PcapngOptionLE:
    return pcapng.PcapngOptionLE(code=pcapng.PCAPNG_OPT_ENDOFOPT)


def idb(linktype: int, *opts: pcapng.PcapngOptionLE) -> bytes:
    return bytes(pcapng.InterfaceDescriptionBlockLE(linktype=linktype, snaplen=65535,
                                                    opts=[*opts, end()] if opts else []))


def epb(iface: int, ts: int, data: bytes, flags: int | None = None) -> bytes:
    opts = [opt(2, struct.pack("<I", flags)), end()] if flags is not None else []
    return bytes(pcapng.EnhancedPacketBlockLE(iface_id=iface, ts_high=ts >> 32, ts_low=ts & 0xFFFFFFFF,
                                              pkt_data=data, opts=opts))


def test_two_interfaces_with_their_own_link_resolution_name_and_direction(tmp_path):
    """dumpcap -i lo -i any: interface 0 Ethernet in nanoseconds, interface 1 raw IP in
    microseconds, an if_tsoffset of 10 s; epb_flags outbound/inbound; a packet naming
    interface 5 skipped and counted."""
    path = tmp_path / "two.pcapng"
    path.write_bytes(
        bytes(pcapng.SectionHeaderBlockLE())
        + idb(1, opt(pcapng.PCAPNG_OPT_IF_NAME, b"lo"), opt(pcapng.PCAPNG_OPT_IF_TSRESOL, b"\x09"))
        + idb(101, opt(pcapng.PCAPNG_OPT_IF_NAME, b"any"),
              opt(pcapng.PCAPNG_OPT_IF_TSOFFSET, struct.pack("<q", 10)))
        + epb(0, 1_000_000_123, bytes(Ether(dst="00:00:00:00:00:01", type=0x800)) + IPV4, flags=2)
        + epb(1, 2_000_000, IPV4, flags=1)
        + epb(5, 3_000_000, IPV4)
        + epb(1, 4_000_000, IPV4))
    cap = open_capture(path)
    got = [(d.t_ns, d.direction, d.recorder, d.data) for d in cap if type(d) is Datagram]
    assert got == [(1_000_000_123, "tx", "lo", START), (12_000_000_000, "rx", "any", START),
                   (14_000_000_000, None, "any", START)]
    assert cap.truncated is None
    assert "1 pcapng packet(s) naming an interface the file does not describe, skipped" in cap.notes


def test_a_new_section_starts_its_interfaces_anew(tmp_path):
    """Interface IDs count from 0 in each section (a big-endian one here): interface 1 of
    the first section is not one of the second."""
    second = pcapng.SectionHeaderBlock()  # big-endian
    path = tmp_path / "sections.pcapng"
    path.write_bytes(
        bytes(pcapng.SectionHeaderBlockLE()) + idb(101) + idb(1) + epb(1, 1, bytes(Ether(dst="00:00:00:00:00:01", type=0x800)) + IPV4)
        + bytes(second) + bytes(pcapng.InterfaceDescriptionBlock(linktype=101, snaplen=65535))
        + bytes(pcapng.EnhancedPacketBlock(iface_id=0, ts_high=0, ts_low=2, pkt_data=IPV4))
        + bytes(pcapng.EnhancedPacketBlock(iface_id=1, ts_high=0, ts_low=3, pkt_data=IPV4)))
    cap = open_capture(path)
    assert [d.t_ns for d in cap if type(d) is Datagram] == [1000, 2000]
    assert cap.truncated is None and cap.counts["unknown_interface"] == 1


def _records(path):
    cap = open_capture(path)
    return [r for r in cap], cap.truncated, cap.corrupt


@pytest.mark.parametrize("nano", [False, True], ids=["usec", "nsec"])
def test_a_gzip_cut_anywhere_reads_as_the_plain_file_cut_there(tmp_path, nano):
    """The gzip'd path (a stream, short reads) and the plain path (a mapped file, the last
    record's header) say the same: the same records, the same reason, the same verdict."""
    pkts = [Ether() / IP(src="10.0.0.1", dst="10.0.0.2") / UDP(sport=7889, dport=7890) / START
            for _ in range(3)]
    for i, p in enumerate(pkts):
        p.time = 100 + i * 0.25
    wrpcap(str(tmp_path / "whole.pcap"), pkts, nano=nano)
    whole = (tmp_path / "whole.pcap").read_bytes()
    plain, gz = tmp_path / "cut.pcap", tmp_path / "cut.pcap.gz"
    for n in range(24, len(whole) + 1):
        plain.write_bytes(whole[:n])
        gz.write_bytes(gzip.compress(whole[:n], compresslevel=1))
        assert _records(gz) == _records(plain), n


def test_a_record_longer_than_the_bound_is_garbage_in_either_path(tmp_path):
    header = struct.pack("<IHHiIII", 0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)
    record = struct.pack("<IIII", 1, 0, MAX_RECORD + 1, MAX_RECORD + 1) + bytes(64)
    plain, gz = tmp_path / "long.pcap", tmp_path / "long.pcap.gz"
    plain.write_bytes(header + record)
    gz.write_bytes(gzip.compress(header + record))
    for path in (plain, gz):
        cap = open_capture(path)
        with pytest.raises(Exception, match="corrupt, nothing could be read: record 1 at byte 24 claims "
                                            f"{MAX_RECORD + 1:,} bytes"):
            list(cap)

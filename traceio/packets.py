"""The packet side of the capture reader (``traceio.reader``): scapy's raw pcap and pcapng
readers, bounded and told to say where a file is cut, and the link, IPv4 and UDP layers
parsed with ``struct`` (Ethernet with VLAN tags, Linux SLL/SLL2, raw IP, BSD loopback), with
IPv4 fragments reassembled. Scapy reads the files; it never dissects on this hot path."""

from __future__ import annotations

import socket
import struct
import zlib
from collections import Counter
from typing import Any

from scapy.utils import RawPcapNgReader, RawPcapReader

__all__ = ["EPB_DIRECTION", "FRAGMENT", "LINKS", "MAX_RECORD", "GuardedStream", "NgReader", "PcapReader", "Reassembly"]

MAX_RECORD = 1 << 20  # scapy's per-read cap on a packet record: bigger than any IP datagram


# ---------------------------------------------------------------- scapy's raw readers
class PcapReader(RawPcapReader):
    def cut_reason(self, offset: int) -> str | None:
        pos = self.f.tell()
        if pos > offset:
            return f"{pos - offset} byte(s) after the last whole record (at byte {offset}): cut short or garbage"
        return None


class NgReader(RawPcapNgReader):
    _good_end = 0
    unknown_interface = 0  # packets naming an interface no IDB described (skipped, counted)

    def _check_interface_id(self, intid: int) -> bool:
        if 0 <= intid < len(self.interfaces):
            return True
        self.unknown_interface += 1
        return False

    def _read_block(self, size: int = MAX_RECORD) -> Any:
        res = super()._read_block(size)
        self._good_end = self.f.tell()
        return res

    def cut_reason(self, offset: int) -> str | None:
        pos = self.f.tell()
        if pos > self._good_end:
            return (f"{pos - self._good_end} byte(s) after the last whole block "
                    f"(at byte {self._good_end}): cut short or garbage")
        return None


#: A gzip'd capture expanding more than this many times, past :data:`BOMB_FLOOR` bytes, is
#: refused as a decompression bomb (issue 19): pcaps compress 3-10 fold; a gigabyte of zeros
#: compresses 1000-fold and would be read as tens of millions of empty records.
BOMB_RATIO = 200
BOMB_FLOOR = 2 << 20  # a capture that small is read whatever its ratio; a bomb is refused within a moment


class DecompressionBomb(OSError):
    """The gzip stream expands past :data:`BOMB_RATIO` times its compressed size."""


class GuardedStream:
    """A decompressing stream (gzip) whose failures scapy's readers would take for the end of
    the file (they turn OSError and zlib.error into EOFError): the failure is kept in
    ``error`` for the reader to report (issue 19 item 8: a .gz whose CRC failed read "OK").
    ``raw_file`` (the compressed file) bounds the expansion: :class:`DecompressionBomb`."""

    def __init__(self, raw: Any, raw_file: Any = None) -> None:
        self._raw = raw
        self._file = raw_file
        self._out = 0
        self.error: BaseException | None = None

    def read(self, n: int = -1) -> bytes:
        try:
            data = self._raw.read(n)
            self._out += len(data)
            if self._out > BOMB_FLOOR and self._file is not None:
                consumed = max(1, self._file.tell())
                if self._out > BOMB_RATIO * consumed:
                    raise DecompressionBomb(f"the gzip stream expands {self._out // consumed}-fold "
                                            f"({self._out >> 20} MiB from {consumed >> 10} KiB): "
                                            "a decompression bomb, not a capture")
            return data
        except (OSError, EOFError, zlib.error) as exc:
            if self.error is None:
                self.error = exc
            raise

    def tell(self) -> int:
        return self._raw.tell()

    def close(self) -> None:
        self._raw.close()


# ---------------------------------------------------------------- link, IP and UDP headers
# This is the hot path of `mcp-capture check` on a big pcap (1,000,000 datagrams end to end):
# precompiled struct unpacking of the few header fields we need runs at about a million
# packets a second, where dissecting each packet with scapy (Ether()/IP()/UDP()) manages
# ~15k/s (docs/design.md, "Performance targets"). scapy stays the file-format reader
# (RawPcap*Reader, bytes only).
_ETHERTYPE_AT = struct.Struct("!H").unpack_from
_IP4 = struct.Struct("!BxHHHxBxx4s4s")  # ver_ihl, total_len, id, flags_frag, proto, src, dst
_ip4 = _IP4.unpack_from
_UDP = struct.Struct("!HHH")  # sport, dport, length
_udp = _UDP.unpack_from
_NULL_INET = (b"\x02\x00\x00\x00", b"\x00\x00\x00\x02")
_ETH_IPV4, _ETH_IPV6, _ETH_VLAN = 0x0800, 0x86DD, (0x8100, 0x88A8, 0x9100)
_ARPHRD_LOOPBACK = 772
_SLL_DIRECTION = {0: "rx", 1: "rx", 2: "rx", 3: "rx", 4: "tx"}
EPB_DIRECTION = {1: "rx", 2: "tx"}
FRAGMENT = object()
_ADDR: dict[bytes, str] = {}


def _host(raw: bytes) -> str:
    host = _ADDR.get(raw)
    if host is None:
        host = _ADDR[raw] = socket.inet_ntoa(raw)
    return host


def _ipv4(data: bytes, off: int, counts: Counter[str], link_dir: str | None) -> Any:
    """(src, dst, payload, direction) of a UDP datagram in the IPv4 packet at ``off``."""
    try:
        ver_ihl, total, ident, frag, proto, src, dst = _ip4(data, off)
    except struct.error:
        counts["bad_ip"] += 1
        return None
    if ver_ihl >> 4 != 4:
        if ver_ihl >> 4 == 6:
            counts["ipv6"] += 1
        else:
            counts["bad_ip"] += 1
        return None
    if proto != 17:
        counts["not_udp"] += 1
        return None
    ihl = (ver_ihl & 15) * 4
    end = off + total  # the IP length, not the frame's: Ethernet pads short frames
    if ihl < 20 or total < ihl:
        counts["bad_ip"] += 1
        return None
    if end > len(data):
        counts["snaplen_cut"] += 1
        return None
    if frag & 0x3FFF:  # more fragments, or a non-zero offset
        return (FRAGMENT, (src, dst, ident, link_dir), (frag & 0x1FFF, frag & 0x2000, data[off + ihl:end]))
    return _udp_of(data, off + ihl, end, src, dst, counts, link_dir)


def _udp_of(data: bytes, u: int, end: int, src: bytes, dst: bytes, counts: Counter[str],
            link_dir: str | None) -> Any:
    try:
        sport, dport, ulen = _udp(data, u)
    except struct.error:
        counts["bad_ip"] += 1
        return None
    if ulen < 8 or u + ulen > end:
        counts["bad_ip"] += 1
        return None
    return (_host(src), sport), (_host(dst), dport), data[u + 8:u + ulen], link_dir


def _ether(data: bytes, counts: Counter[str]) -> Any:
    try:
        etype = _ETHERTYPE_AT(data, 12)[0]
        off = 14
        while etype in _ETH_VLAN:
            etype = _ETHERTYPE_AT(data, off + 2)[0]
            off += 4
    except struct.error:
        counts["not_udp"] += 1
        return None
    if etype != _ETH_IPV4:
        counts["ipv6" if etype == _ETH_IPV6 else "not_udp"] += 1
        return None
    return _ipv4(data, off, counts, None)


def _cooked(layout: str, ip_off: int, sll1: bool) -> Any:
    """A parser for a Linux cooked header: ``layout`` unpacks (pkttype, hatype, protocol) for
    SLL, (protocol, hatype, pkttype) for SLL2."""
    unpack = struct.Struct(layout).unpack_from

    def parse(data: bytes, counts: Counter[str]) -> Any:
        try:
            etype, hatype, pkttype = unpack(data, 0)
        except struct.error:
            counts["not_udp"] += 1
            return None
        if sll1:
            etype, pkttype = pkttype, etype
        if etype != _ETH_IPV4:
            counts["ipv6" if etype == _ETH_IPV6 else "not_udp"] += 1
            return None
        if hatype == _ARPHRD_LOOPBACK:
            if pkttype == 4:  # on "any", some kernels show a loopback packet going out, then in
                counts["loopback_copy"] += 1
                return None
            return _ipv4(data, ip_off, counts, None)
        return _ipv4(data, ip_off, counts, _SLL_DIRECTION.get(pkttype))

    return parse


# SLL: pkttype u16, hatype u16, addr len, 8-byte addr, protocol u16 (16 bytes); SLL2:
# protocol u16, reserved, ifindex u32, hatype u16, pkttype u8, addr len, 8-byte addr (20).
_sll = _cooked("!HH10xH", 16, sll1=True)
_sll2 = _cooked("!H6xHB", 20, sll1=False)


def _raw_ip(data: bytes, counts: Counter[str]) -> Any:
    return _ipv4(data, 0, counts, None)


def _null(data: bytes, counts: Counter[str]) -> Any:
    family = data[:4]
    if family not in _NULL_INET:  # host byte order of the machine that wrote it
        counts["not_udp"] += 1
        return None
    return _ipv4(data, 4, counts, None)


#: link type -> header parser (LINKTYPE_* numbers of pcap/pcapng)
LINKS = {
    1: _ether,      # ETHERNET (tcpdump -i lo on Linux too)
    113: _sll,      # LINUX_SLL (tcpdump -i any, libpcap < 1.10)
    276: _sll2,     # LINUX_SLL2 (tcpdump -i any, libpcap >= 1.10)
    101: _raw_ip,   # RAW
    228: _raw_ip,   # IPV4
    12: _raw_ip,    # DLT_RAW as some BSDs write it in pcap headers
    14: _raw_ip,    # DLT_RAW (OpenBSD)
    0: _null,       # NULL (BSD loopback)
    108: _null,     # LOOP (OpenBSD loopback; family in network order)
}


class Reassembly:
    """IPv4 fragments of UDP datagrams, by (src, dst, id); bounded, oldest groups evicted."""

    LIMIT = 4096

    def __init__(self, counts: Counter[str]) -> None:
        self.groups: dict[tuple[Any, ...], list[Any]] = {}
        self.counts = counts

    def add(self, key: tuple[Any, ...], piece: tuple[int, int, bytes], t_ns: int) -> Any:
        units, more, body = piece
        group = self.groups.get(key)
        if group is None:
            if len(self.groups) >= self.LIMIT:
                self.groups.pop(next(iter(self.groups)))
                self.counts["fragments_evicted"] += 1
            group = self.groups[key] = [None, {}]  # [total length or None, {offset: bytes}]
        group[1][units * 8] = body
        if not more:
            group[0] = units * 8 + len(body)
        total = group[0]
        if total is None:
            return None
        have = 0
        for off in sorted(group[1]):
            if off > have:
                return None
            have = max(have, off + len(group[1][off]))
        if have < total:
            return None
        del self.groups[key]
        whole = bytearray(total)
        for off in sorted(group[1]):
            chunk = group[1][off]
            whole[off:off + len(chunk)] = chunk
        self.counts["fragments_reassembled"] += 1
        src, dst, _ident, link_dir = key
        return _udp_of(bytes(whole), 0, total, src, dst, self.counts, link_dir)

    def open_groups(self) -> int:
        return len(self.groups)

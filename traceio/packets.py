"""The packet side of the capture reader (``traceio.reader``): pcap and pcapng files read with
dpkt's public readers and block classes, bounded, and told where a file is cut; the link, IPv4
and UDP layers parsed with ``struct`` (Ethernet with VLAN tags, Linux SLL/SLL2, raw IP, BSD
loopback), with IPv4 fragments reassembled. Nothing dissects on this hot path.

- pcap: ``dpkt.pcap.Reader`` (file header, either byte order, micro- or nanosecond
  timestamps, record headers). It reads a plain file memory-mapped (an ``mmap``'s read never
  returns more than the file holds, where a file object's read allocates the length a
  hostile record claims) and a gzip'd one through a :class:`GuardedStream`, which counts the
  bytes, notes a read that came back short (a record cut by the end of the file) and refuses
  a record longer than :data:`MAX_RECORD` before reading it (garbage).
- pcapng: the block framing (type, length) is walked here, so that the file's last whole
  block is known; each block is decoded by dpkt's classes (``SectionHeaderBlock``,
  ``InterfaceDescriptionBlock``, ``EnhancedPacketBlock``, ``PacketBlock``, in either byte
  order). ``dpkt.pcapng.Reader`` itself takes every packet for the first interface's: a file
  with several interfaces (dumpcap -i a -i b) or direction flags needs the blocks. Simple
  Packet Blocks have no dpkt class: their 4-byte length is read with ``struct``.

Block layouts and option codes: the pcapng draft (draft-ietf-opsawg-pcapng, sections 4.1-4.4;
``epb_flags`` bits 0-1 the direction, 1 inbound, 2 outbound; ``if_tsresol``, ``if_tsoffset``);
pcap: the libpcap file format (draft-ietf-opsawg-pcap).
"""

from __future__ import annotations

import gzip
import mmap
import socket
import struct
import zlib
from collections import Counter
from collections.abc import Iterator
from typing import Any

from dpkt import UnpackError
from dpkt import pcap as dpcap
from dpkt import pcapng as ng

__all__ = ["EPB_DIRECTION", "FRAGMENT", "LINKS", "MAX_RECORD", "GuardedStream", "NgFile", "PcapFile",
           "Reassembly", "open_packets"]

MAX_RECORD = 1 << 20  # the longest packet record or block read: bigger than any IP datagram


# ---------------------------------------------------------------- the stream the readers read
#: A gzip'd capture expanding more than this many times, past :data:`BOMB_FLOOR` bytes, is
#: refused as a decompression bomb (issue 19): pcaps compress 3-10 fold; a gigabyte of zeros
#: compresses 1000-fold and would be read as tens of millions of empty records.
BOMB_RATIO = 200
BOMB_FLOOR = 2 << 20  # a capture that small is read whatever its ratio; a bomb is refused within a moment


class DecompressionBomb(OSError):
    """The gzip stream expands past :data:`BOMB_RATIO` times its compressed size."""


class RecordTooLong(ValueError):
    """A record claims more than :data:`MAX_RECORD` bytes: garbage, refused before reading."""


class GuardedStream:
    """The byte stream a reader reads: ``pos`` bytes read so far, ``short`` set (to the
    length asked) when a read came back short (the file ends inside what was asked), reads
    longer than :data:`MAX_RECORD` refused (:class:`RecordTooLong`).

    A gzip stream (:meth:`gzip`): its failure is kept in ``error`` for the reader to report
    (issue 19 item 8: a .gz whose CRC failed read "OK"); the compressed file bounds its
    expansion (:class:`DecompressionBomb`). A plain file (:meth:`plain`) is memory-mapped
    where it can be: ``mapped`` is then the ``mmap`` (whose ``read`` never returns more than
    the file holds), which the pcap reader reads directly, and ``size`` the file's length."""

    def __init__(self, raw: Any, raw_file: Any = None, size: int | None = None,
                 mapped: mmap.mmap | None = None, compressed: bool = False) -> None:
        self._read = raw.read
        self._raw = raw
        self._file = raw_file
        self._bounded = compressed  # a gzip stream: its expansion is watched
        self.size = size
        self.mapped = mapped
        self.pos = 0
        self.short: int | None = None
        self.error: BaseException | None = None

    @classmethod
    def gzip(cls, fd: Any) -> GuardedStream:
        return cls(gzip.GzipFile(fileobj=fd), fd, compressed=True)

    @classmethod
    def plain(cls, fd: Any) -> GuardedStream:
        try:
            mapped = mmap.mmap(fd.fileno(), 0, access=mmap.ACCESS_READ)
        except (OSError, ValueError):  # not a regular file (a pipe, /dev/stdin): read as a stream
            return cls(fd)
        return cls(mapped, fd, len(mapped), mapped)

    def read(self, n: int) -> bytes:
        if n > MAX_RECORD:
            raise RecordTooLong(n)
        try:
            data = self._read(n)
        except (OSError, EOFError, zlib.error) as exc:
            if self.error is None:
                self.error = exc
            raise
        got = len(data)
        self.pos += got
        if got < n:
            self.short = n
        if self._bounded and self.pos > BOMB_FLOOR:
            self._check_ratio()
        return data

    def _check_ratio(self) -> None:
        consumed = max(1, self._file.tell())
        if self.pos > BOMB_RATIO * consumed:
            self.error = DecompressionBomb(f"the gzip stream expands {self.pos // consumed}-fold "
                                           f"({self.pos >> 20} MiB from {consumed >> 10} KiB): "
                                           "a decompression bomb, not a capture")
            raise self.error

    def drain(self) -> None:
        """Read a gzip stream to its end, so that its CRC is checked: garbage where a record
        should start is, in a gzip'd capture, most often the deflate stream damaged (the
        failure then found in ``error``); bounded like every read (:class:`DecompressionBomb`)."""
        if not self._bounded:
            return
        try:
            while self.error is None and self.read(MAX_RECORD):
                pass
        except (OSError, EOFError, zlib.error):
            pass

    def extra(self, good_end: int) -> int:
        """Bytes in the file after ``good_end`` (those read, where the size is unknown)."""
        return (self.size if self.size is not None else self.pos) - good_end

    def close(self) -> None:
        self._raw.close()
        if self._file is not None:
            self._file.close()


class HeaderError(ValueError):
    """The file header (pcap) or first Section Header Block (pcapng) is cut or not one."""


def open_packets(stream: GuardedStream, magic: bytes, linktypes: set[int]) -> PcapFile | NgFile:
    """The reader of a pcap or pcapng ``stream`` whose first 4 bytes are ``magic``,
    adding the link types of the packets it reads to ``linktypes``; :class:`HeaderError` (or
    the stream's OSError) when its header is unreadable."""
    if magic == ng.PCAPNG_BT_SHB.to_bytes(4, "big"):
        return NgFile(stream, linktypes)
    return PcapFile(stream, linktypes, magic)


class _File:
    """After iteration: ``truncated`` (why the reading stopped early, or None), ``corrupt``
    (it stopped at garbage, not at a cut), ``count`` (packets yielded)."""

    truncated: str | None = None
    corrupt = False
    count = 0
    unknown_interface = 0  # pcapng packets naming an interface no IDB described (skipped, counted)

    def __init__(self, stream: GuardedStream, linktypes: set[int]) -> None:
        self.stream = stream
        self.linktypes = linktypes

    def close(self) -> None:
        self.stream.close()


class PcapFile(_File):
    """A pcap file through ``dpkt.pcap.Reader``: (t_ns, link type, bytes, None, None) per
    record. dpkt's timestamp is seconds, a float (exact to the microsecond for any 32-bit
    second: the error of ``sec + usec / 1e6`` stays under half a microsecond) or, in a
    nanosecond pcap, a Decimal (exact). dpkt gives a record's data, not its length: a record
    cut by the end of the file is told by a short read (a stream), or (a mapped file) by
    its header, read again with dpkt's record header class, when it is the file's last."""

    def __init__(self, stream: GuardedStream, linktypes: set[int], magic: bytes) -> None:
        super().__init__(stream, linktypes)
        try:
            self._reader = dpcap.Reader(stream.mapped if stream.mapped is not None else stream)
        except (UnpackError, ValueError) as exc:
            raise HeaderError(str(exc) or type(exc).__name__) from None
        self.linktype = self._reader.datalink()
        (number,) = struct.unpack(">I", magic)
        self._nano = number in (dpcap.TCPDUMP_MAGIC_NANO, dpcap.PMUDPCT_MAGIC_NANO)
        self._record_header = dpcap.MAGIC_TO_PKT_HDR[number]

    def __iter__(self) -> Iterator[tuple[int, int, bytes, None, None]]:
        stream, link, nano, n = self.stream, self.linktype, self._nano, 0
        offset = 24  # where the next record starts
        mapped, size = stream.mapped, stream.size
        try:
            if mapped is not None:  # a mapped file: its last record is checked against its header
                for ts, data in self._reader:
                    end = offset + 16 + len(data)
                    if end == size:
                        caplen = self._record_header(mapped[offset:offset + 16]).caplen
                        if caplen > MAX_RECORD:
                            raise RecordTooLong(caplen)
                        if caplen > len(data):
                            self._cut(n, offset, caplen, len(data))
                            break
                    offset = end
                    n += 1
                    yield int(ts * 1_000_000_000) if nano else round(ts * 1_000_000) * 1000, link, data, None, None
            else:  # a stream: a short read is a cut record
                for ts, data in self._reader:
                    if stream.short is not None:
                        self._cut(n, offset, stream.short, len(data))
                        break
                    offset += 16 + len(data)
                    n += 1
                    yield int(ts * 1_000_000_000) if nano else round(ts * 1_000_000) * 1000, link, data, None, None
        except UnpackError:  # a record header cut by the end of the file
            self.truncated = (f"{stream.extra(offset)} byte(s) after the last whole record "
                              f"(at byte {offset}): cut short or garbage")
        except RecordTooLong as exc:
            self.truncated = (f"record {n + 1} at byte {offset} claims {exc.args[0]:,} bytes, more "
                              f"than any packet record ({MAX_RECORD:,}): garbage")
            self.corrupt = True
        except (OSError, EOFError, zlib.error) as exc:
            self.corrupt = True
            self.truncated = f"read error after packet {n}: {exc}"
        finally:
            self.count = n
        if n:
            self.linktypes.add(link)

    def _cut(self, n: int, offset: int, caplen: int, present: int) -> None:
        self.truncated = (f"record {n + 1} at byte {offset} is cut short or garbage "
                          f"(caplen {caplen}, {present} bytes present)")


_SHB, _IDB, _PB, _SPB, _EPB = ng.PCAPNG_BT_SHB, ng.PCAPNG_BT_IDB, ng.PCAPNG_BT_PB, ng.PCAPNG_BT_SPB, ng.PCAPNG_BT_EPB
_BOM = {b"\x4d\x3c\x2b\x1a": "<", b"\x1a\x2b\x3c\x4d": ">"}
_BLOCK = {"<": {_SHB: ng.SectionHeaderBlockLE, _IDB: ng.InterfaceDescriptionBlockLE,
                _EPB: ng.EnhancedPacketBlockLE, _PB: ng.PacketBlockLE},
          ">": {_SHB: ng.SectionHeaderBlock, _IDB: ng.InterfaceDescriptionBlock,
                _EPB: ng.EnhancedPacketBlock, _PB: ng.PacketBlock}}
_EPB_FLAGS = 2  # epb_flags (pack_flags in a Packet Block): bits 0-1 the direction


class _Garbage(Exception):
    """A block that is not one: the reading stops at the last whole block."""


class NgFile(_File):
    """A pcapng file, block by block: (t_ns, link type, bytes, direction, interface name)
    per packet, from Enhanced, Simple and (obsolete) Packet Blocks of every section."""

    def __init__(self, stream: GuardedStream, linktypes: set[int]) -> None:
        super().__init__(stream, linktypes)
        head = stream.read(12)
        order = _BOM.get(head[8:12])
        if len(head) < 12 or order is None:
            raise HeaderError("not a pcapng Section Header Block")
        try:
            self._section(head, order)
        except _Garbage as exc:
            raise HeaderError(str(exc)) from None
        self.good_end = stream.pos  # where the last whole block ends

    def _section(self, head: bytes, order: str) -> None:
        """A Section Header Block whose first 12 bytes are ``head``: a new byte order and no
        interfaces yet (interface IDs count from 0 in each section)."""
        blen = struct.unpack(order + "I", head[4:8])[0]
        if blen < 28 or blen > MAX_RECORD:
            raise _Garbage(f"Section Header Block length {blen}")
        rest = self.stream.read(blen - 12 + (-blen % 4))
        if self.stream.short is not None:
            raise _Garbage("Section Header Block cut short")
        try:
            shb = _BLOCK[order][_SHB](head + rest)
        except (UnpackError, ValueError, struct.error) as exc:
            raise _Garbage(f"Section Header Block unreadable: {exc}") from None
        if shb.v_major != 1:
            raise _Garbage(f"pcapng version {shb.v_major} (1 is read)")
        self.order = order
        self._u32 = struct.Struct(order + "I").unpack
        self._head = struct.Struct(order + "II").unpack
        self.interfaces: list[tuple[int, int, int, int, str | None]] = []

    def _interface(self, buf: bytes) -> None:
        """An IDB: (link type, ns per tick or 0, ticks per second, offset ns, name)."""
        idb = _BLOCK[self.order][_IDB](buf)
        tsresol, offset_s, name = 1_000_000, 0, None
        for opt in idb.opts:
            if opt.code == ng.PCAPNG_OPT_IF_TSRESOL and len(opt.data) == 1:
                v = opt.data[0]
                tsresol = (2 if v & 128 else 10) ** (v & 127)
            elif opt.code == ng.PCAPNG_OPT_IF_TSOFFSET and len(opt.data) == 8:
                offset_s = struct.unpack(self.order + "q", opt.data)[0]
            elif opt.code == ng.PCAPNG_OPT_IF_NAME:
                name = opt.data.decode("utf-8", "replace") or None
        per_tick = 1_000_000_000 // tsresol if 1_000_000_000 % tsresol == 0 else 0
        self.interfaces.append((idb.linktype, per_tick, tsresol, offset_s * 1_000_000_000, name))

    def __iter__(self) -> Iterator[tuple[int, int, bytes, str | None, str | None]]:
        stream = self.stream
        read = stream.read
        n = 0
        try:
            while True:
                head = read(8)
                if len(head) < 8:
                    if head:
                        raise _Garbage
                    break
                btype, blen = self._head(head)
                if btype == _SHB:
                    bom = read(4)
                    if bom not in _BOM:
                        raise _Garbage
                    self._section(head + bom, _BOM[bom])
                    self.good_end = stream.pos
                    continue
                if blen < 12 or blen > MAX_RECORD:
                    raise _Garbage
                buf = head + read(blen - 8 + (-blen % 4))
                if stream.short is not None:
                    raise _Garbage
                try:
                    got = self._block(btype, buf)
                except (UnpackError, ValueError, struct.error, IndexError):
                    raise _Garbage from None
                self.good_end = stream.pos
                if got is not None:
                    n += 1
                    yield got
        except _Garbage:
            self.truncated = (f"{stream.extra(self.good_end)} byte(s) after the last whole block "
                              f"(at byte {self.good_end}): cut short or garbage")
        except (OSError, EOFError, zlib.error) as exc:
            self.corrupt = True
            self.truncated = f"read error after packet {n}: {exc}"
        finally:
            self.count = n

    def _block(self, btype: int, buf: bytes) -> tuple[int, int, bytes, str | None, str | None] | None:
        if btype == _EPB or btype == _PB:
            blk = _BLOCK[self.order][btype](buf)
            direction = None
            for opt in blk.opts:
                if opt.code == _EPB_FLAGS and len(opt.data) == 4:
                    direction = EPB_DIRECTION.get(self._u32(opt.data)[0] & 3)
            ts, intid, data = blk.ts_high << 32 | blk.ts_low, blk.iface_id, blk.pkt_data
        elif btype == _SPB:  # interface 0, no timestamp: original length, then the packet
            (orig,) = self._u32(buf[8:12])
            ts, intid, data, direction = 0, 0, buf[12:min(12 + orig, len(buf) - 4)], None
        else:
            if btype == _IDB:
                self._interface(buf)
            return None
        if intid >= len(self.interfaces):
            self.unknown_interface += 1
            return None
        linktype, per_tick, tsresol, offset_ns, name = self.interfaces[intid]
        self.linktypes.add(linktype)
        t_ns = ts * per_tick if per_tick else ts * 1_000_000_000 // tsresol
        return t_ns + offset_ns, linktype, data, direction, name


# ---------------------------------------------------------------- link, IP and UDP headers
# This is the hot path of `mcp-capture check` on a big pcap (1,000,000 datagrams end to end):
# precompiled struct unpacking of the few header fields we need runs at about a million
# packets a second, where dissecting each packet with scapy (Ether()/IP()/UDP()) manages
# ~15k/s (docs/design.md, "Performance targets"); dpkt's packet classes would cost as much as
# its readers do. The readers above give bytes only.
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

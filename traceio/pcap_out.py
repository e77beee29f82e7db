"""Ethernet/IPv4 frames and the pcap or pcapng file that holds them, built with dpkt.

The writer behind ``mcp-capture export``: MCP datagrams as UDP packets (``captures.export``,
MCP-TRN-1) and Nsqd conversations as TCP segments (:mod:`traceio.tcp_pcap`, NSQD-*). dpkt
builds every layer (lengths, the IPv4 header checksum, the UDP and TCP checksums over the
pseudo-header) and writes the file (``dpkt.pcap.Writer``, ``dpkt.pcapng.Writer``), a few
microseconds a packet where scapy's packet objects took most of a millisecond.

Timestamps are integer nanoseconds, written without going through a float:

- pcap: 32-bit seconds and microseconds, rounded to the nearest microsecond (nanoseconds with
  ``nano=True``);
- pcapng: one interface without ``if_tsresol`` (microseconds), truncated to the microsecond.

A time the file's fields cannot hold, an address that is not an IPv4 literal, a port outside
0..65535 or a payload past what IPv4 carries is a :class:`FrameError` (one line).
"""

from __future__ import annotations

import socket
import sys
from decimal import Decimal
from functools import lru_cache
from pathlib import Path
from typing import BinaryIO

import dpkt

__all__ = ["FrameError", "PacketFile", "ipv4", "tcp_frame", "udp_frame"]

ETH_SRC = b"\x02\x00\x00\x00\x00\x01"
ETH_DST = b"\x02\x00\x00\x00\x00\x02"
#: the packets' IPv4 identification (the value scapy's packets carried)
IP_ID = 1
#: what IPv4's 16-bit total length leaves for a UDP payload, and for a TCP one (no options)
UDP_MAX = 65535 - 20 - 8
TCP_MAX = 65535 - 20 - 20
#: the files' snapshot lengths (those of the scapy writers before)
PCAP_SNAPLEN = 65535
PCAPNG_SNAPLEN = 262144
#: the largest time each file can hold (its seconds or microseconds fields)
PCAP_MAX_NS = (2**32 - 1) * 10**9
PCAPNG_MAX_NS = (2**64 - 1) * 1000

_EPB = dpkt.pcapng.EnhancedPacketBlockLE if sys.byteorder == "little" else dpkt.pcapng.EnhancedPacketBlock


class FrameError(ValueError):
    """What a frame or the file cannot carry (a one-line reason)."""


@lru_cache(maxsize=4096)
def ipv4(host: str) -> bytes:
    """The four bytes of a dotted-quad IPv4 address (never a name lookup)."""
    try:
        return socket.inet_pton(socket.AF_INET, host)
    except (OSError, TypeError, ValueError):
        raise FrameError(f"{host!r} is not an IPv4 address") from None


def _port(port: int) -> int:
    if not 0 <= port <= 0xFFFF:
        raise FrameError(f"port {port} is outside 0..65535")
    return port


def _ether(src: str, dst: str, proto: int, segment: dpkt.Packet) -> bytes:
    ip = dpkt.ip.IP(id=IP_ID, p=proto, src=ipv4(src), dst=ipv4(dst), data=segment)
    return bytes(dpkt.ethernet.Ethernet(src=ETH_SRC, dst=ETH_DST, type=dpkt.ethernet.ETH_TYPE_IP, data=ip))


def udp_frame(src: tuple[str, int], dst: tuple[str, int], payload: bytes) -> bytes:
    """Ethernet/IPv4/UDP carrying ``payload`` from ``src`` to ``dst`` ((host, port) each)."""
    if len(payload) > UDP_MAX:
        raise FrameError(f"a {len(payload)}-byte datagram is longer than IPv4/UDP carries ({UDP_MAX})")
    udp = dpkt.udp.UDP(sport=_port(src[1]), dport=_port(dst[1]), ulen=8 + len(payload), data=payload)
    return _ether(src[0], dst[0], dpkt.ip.IP_PROTO_UDP, udp)


#: scapy's flag letters, as traceio.tcp_pcap names them
_TCP_FLAGS = {"F": dpkt.tcp.TH_FIN, "S": dpkt.tcp.TH_SYN, "R": dpkt.tcp.TH_RST, "P": dpkt.tcp.TH_PUSH,
              "A": dpkt.tcp.TH_ACK}


def tcp_frame(src: tuple[str, int], dst: tuple[str, int], flags: str, seq: int, ack: int,
              payload: bytes = b"", window: int = 65535) -> bytes:
    """Ethernet/IPv4/TCP (no options): one segment with ``flags`` (letters of ``FSRPA``)."""
    if len(payload) > TCP_MAX:
        raise FrameError(f"a {len(payload)}-byte segment is longer than IPv4/TCP carries ({TCP_MAX})")
    bits = 0
    for letter in flags:
        bits |= _TCP_FLAGS[letter]
    tcp = dpkt.tcp.TCP(sport=_port(src[1]), dport=_port(dst[1]), seq=seq, ack=ack, flags=bits, win=window,
                       data=payload)
    return _ether(src[0], dst[0], dpkt.ip.IP_PROTO_TCP, tcp)


class PacketFile:
    """A pcapng (``path`` ending ``.pcapng``) or pcap file of Ethernet frames, created (with
    its header) on opening. ``nano``: a nanosecond pcap (pcapng stays in microseconds)."""

    def __init__(self, path: str | Path, nano: bool = False) -> None:
        path = Path(path)
        self.pcapng = path.suffix.lower() == ".pcapng"
        self.max_ns = PCAPNG_MAX_NS if self.pcapng else PCAP_MAX_NS
        self._f: BinaryIO = open(path, "wb")  # noqa: SIM115  # closed by close()
        try:
            if self.pcapng:
                self._ng = dpkt.pcapng.Writer(self._f, snaplen=PCAPNG_SNAPLEN, linktype=dpkt.pcap.DLT_EN10MB)
            else:
                self._pcap = dpkt.pcap.Writer(self._f, snaplen=PCAP_SNAPLEN, linktype=dpkt.pcap.DLT_EN10MB,
                                              nano=nano)
                self._unit = 1 if nano else 1000
                self._exp = -9 if nano else -6
        except BaseException:
            self._f.close()
            raise

    def write(self, frame: bytes, t_ns: int) -> None:
        """One frame stamped ``t_ns``; FrameError where the file's timestamp cannot hold it."""
        if not 0 <= t_ns <= self.max_ns:
            raise FrameError(f"{t_ns / 1e9:.0f} s is outside what a {'pcapng' if self.pcapng else 'pcap'} "
                             "file's timestamp holds")
        if self.pcapng:
            us = t_ns // 1000
            n = len(frame)
            epb = _EPB(ts_high=us >> 32, ts_low=us & 0xFFFFFFFF, caplen=n, pkt_len=n, pkt_data=frame)
            # dpkt stamps a block whose time fields are both 0 with the present time: ts=0 keeps it 0
            self._ng.writepkt(epb, ts=None if us else 0)
        else:
            ticks = (t_ns + self._unit // 2) // self._unit  # to the nearest microsecond (or ns)
            # dpkt splits ts into int(ts) seconds and the rounded fraction: a Decimal keeps it exact
            self._pcap.writepkt_time(frame, Decimal(ticks).scaleb(self._exp))

    def close(self) -> None:
        self._f.close()

    def __enter__(self) -> PacketFile:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

"""TCP conversations of a pcap or pcapng, reassembled: the stream side of ``traceio.reader``
for the Nsqd protocol (``--protocol nsqd``; issue 21 item 4).

Scapy dissects each packet's layers (every link type it knows: Ethernet, Linux cooked
SLL/SLL2, raw IP, BSD loopback; IPv4 and IPv6); :class:`TcpReassembler` orders each
direction's bytes by sequence number (mod 2^32): a retransmitted segment, or the part of one
that overlaps what was delivered, is dropped and counted; a segment ahead of a hole is held
until the hole fills. Memory is bounded whatever the file: at most :data:`MAX_HELD` bytes and
:data:`MAX_HELD_SEGMENTS` segments held per direction (then the hole is given up: a ``gap``
event, and delivery goes on after it), a segment further ahead than :data:`WINDOW` is not
this stream's (dropped, counted), and at most :data:`MAX_OPEN` conversations open at once
(the oldest is closed as a gap). Conversations are numbered 1, 2, ... in the order their
first packet appears; a SYN on the 4-tuple of one that ended starts a new one.

Events, in capture order: :class:`~traceio.reader.StreamEvent` (``open`` at the handshake or
first packet, ``close`` at a FIN reached in sequence or an RST, with who and how),
:class:`StreamData` (bytes delivered in order; ``tx`` client to backend, ``rx`` backend to
client) and :class:`StreamGap` (bytes of one direction missing from the capture: the
connection joined mid-stream, a hole never filled, a segment cut by the snap length).
The client is the side that sent the SYN; with no handshake in the capture, the side not on
the backend's port, or whose bytes are not what only a backend sends.
"""

from __future__ import annotations

import itertools
import logging
from collections import Counter
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from mcp_conform.traceio.reader import Capture, StreamEvent

__all__ = ["MAX_HELD", "MAX_HELD_SEGMENTS", "MAX_OPEN", "WINDOW", "StreamData", "StreamGap", "TcpReassembler",
           "TcpSegment", "tcp_events", "tcp_segments"]

MAX_HELD = 1 << 20  # bytes held ahead of a hole, per direction
MAX_HELD_SEGMENTS = 1024
WINDOW = 1 << 24  # a segment further ahead of the stream than this is not its (a forged seq)
MAX_OPEN = 65536  # conversations open at once
_MOD = 1 << 32
_HALF = 1 << 31
_FIN, _SYN, _RST, _ACK = 0x01, 0x02, 0x04, 0x10


class TcpSegment(NamedTuple):
    t_ns: int
    src: tuple[str, int]
    dst: tuple[str, int]
    seq: int
    flags: int
    payload: bytes


class StreamData(NamedTuple):
    t_ns: int
    conn: int
    direction: str  # "tx" client -> backend, "rx" backend -> client
    data: bytes


class StreamGap(NamedTuple):
    t_ns: int
    conn: int
    direction: str
    reason: str


def tcp_segments(cap: Capture, packets: int | None = None) -> Iterator[TcpSegment]:
    """The TCP segments of a pcap/pcapng capture (``Capture.counts`` tallies the rest);
    ``packets``: look at that many packets at most."""
    logger = logging.getLogger("scapy.runtime")
    level = logger.level
    logger.setLevel(logging.ERROR)  # scapy's warnings on a cut or bad file: the capture reports them
    try:
        yield from _segments(cap, packets)
    finally:
        logger.setLevel(level)


def _segments(cap: Capture, packets: int | None) -> Iterator[TcpSegment]:
    # scapy (~0.2 CPU s of imports) only where a pcap's packets are dissected: a tool that
    # merely imports this module for its record types (mcp-capture asking each protocol whether
    # a file is its own, an MCP capture's check among them) never loads it
    from scapy.config import conf
    from scapy.layers.inet import IP, TCP
    from scapy.layers.inet6 import IPv6

    counts = cap.counts
    layers = conf.l2types.num2layer
    for t_ns, linktype, data, _direction, _ifname in itertools.islice(cap.raw_packets(), packets):
        cls = layers.get(linktype)
        if cls is None:
            counts["not_tcp"] += 1
            continue
        try:
            pkt = cls(data)
        except Exception:  # noqa: BLE001 - scapy on hostile bytes: a packet it cannot dissect
            counts["bad_ip"] += 1
            continue
        tcp = pkt.getlayer(TCP)
        ip = pkt.getlayer(IP)
        ip6 = pkt.getlayer(IPv6) if ip is None else None
        if tcp is None or (ip is None and ip6 is None):
            counts["not_tcp"] += 1
            continue
        raw = tcp.original or b""
        if ip is not None:
            if ip.flags.MF or ip.frag:
                counts["tcp_fragment"] += 1
                continue
            seglen = (ip.len or 0) - (ip.ihl or 5) * 4
            src, dst = str(ip.src), str(ip.dst)
        else:
            assert ip6 is not None
            seglen = len(raw) - (len(ip6.original or b"") - 40 - (ip6.plen or 0))
            src, dst = str(ip6.src), str(ip6.dst)
        hdr = (tcp.dataofs or 5) * 4
        if seglen < hdr or hdr < 20:
            counts["bad_ip"] += 1
            continue
        if seglen > len(raw):  # the snap length cut it: its bytes are missing
            counts["snaplen_cut"] += 1
            continue
        yield TcpSegment(t_ns, (src, int(tcp.sport)), (dst, int(tcp.dport)), int(tcp.seq), int(tcp.flags),
                         bytes(raw[hdr:seglen]))


@dataclass
class _Half:
    """One direction of a conversation."""

    next: int | None = None  # the sequence number of the next byte to deliver
    held: dict[int, bytes] = field(default_factory=dict)
    held_bytes: int = 0
    fin_at: int | None = None
    closed: bool = False


@dataclass
class _Conv:
    index: int
    client: tuple[str, int]
    backend: tuple[str, int]
    isn: int | None
    halves: dict[str, _Half] = field(default_factory=lambda: {"tx": _Half(), "rx": _Half()})
    ended: bool = False


class TcpReassembler:
    """Segments in (capture order), events out (see the module docstring)."""

    def __init__(self, counts: Counter[str], backend_port: int | None = None,
                 backend_speaks: Any = None) -> None:
        self.counts = counts
        self.backend_port = backend_port
        self.backend_speaks = backend_speaks  # bytes -> whether only a backend sends them
        self.open: dict[tuple[Any, ...], _Conv] = {}
        self.n = 0

    def _key(self, a: tuple[str, int], b: tuple[str, int]) -> tuple[Any, ...]:
        return (a, b) if a <= b else (b, a)

    def _new(self, seg: TcpSegment, out: list[Any], client: tuple[str, int], backend: tuple[str, int],
             isn: int | None, *, joined: bool = True) -> _Conv:
        if len(self.open) >= MAX_OPEN:
            oldest = self.open.pop(next(iter(self.open)))
            self.counts["tcp_evicted"] += 1
            out.append(StreamGap(seg.t_ns, oldest.index, "rx", f"more than {MAX_OPEN} connections open at once: "
                                 "the oldest one's further bytes are not followed"))
        self.n += 1
        conv = _Conv(self.n, client, backend, isn)
        self.open[self._key(client, backend)] = conv
        out.append(StreamEvent(seg.t_ns, "open", conv.index, client, backend))
        if isn is None and joined:
            for d in ("tx", "rx"):
                out.append(StreamGap(seg.t_ns, conv.index, d, "the capture joined the connection mid-stream "
                                     "(no handshake): its frames cannot be told from its start"))
        return conv

    def feed(self, seg: TcpSegment) -> list[Any]:
        out: list[Any] = []
        key = self._key(seg.src, seg.dst)
        conv = self.open.get(key)
        syn = bool(seg.flags & _SYN)
        if syn and not seg.flags & _ACK:  # a client's SYN: a new conversation unless retransmitted
            if conv is None or conv.ended or (conv.isn is not None and conv.isn != seg.seq) or conv.client != seg.src:
                if conv is not None:
                    self._end(conv, seg.t_ns, out)
                conv = self._new(seg, out, seg.src, seg.dst, seg.seq)
                conv.halves["tx"].next = (seg.seq + 1) % _MOD
            else:
                self.counts["tcp_retransmitted"] += 1
            return out
        if conv is None or conv.ended:
            if not seg.payload and not syn:
                return out  # the last ACKs of a closed connection, or a stray one
            if syn:  # a SYN-ACK whose SYN the capture missed
                conv = self._new(seg, out, seg.dst, seg.src, None, joined=False)
            else:
                if self.backend_port in (seg.src[1], seg.dst[1]):
                    backend_first = seg.src[1] == self.backend_port
                elif self.backend_speaks is not None:
                    backend_first = bool(self.backend_speaks(seg.payload))
                else:
                    backend_first = seg.src[1] < seg.dst[1]
                client, backend = (seg.dst, seg.src) if backend_first else (seg.src, seg.dst)
                conv = self._new(seg, out, client, backend, None)
        direction = "tx" if seg.src == conv.client else "rx"
        half = conv.halves[direction]
        if syn:  # the backend's SYN-ACK
            if half.next is None:
                half.next = (seg.seq + 1) % _MOD
            return out
        if seg.flags & _RST:
            self._drain_all(conv, seg.t_ns, out)
            out.append(StreamEvent(seg.t_ns, "close", conv.index, conv.client, conv.backend,
                                   "client" if direction == "tx" else "backend", "rst"))
            conv.ended = True
            self.open.pop(key, None)
            return out
        if half.next is None:  # joined mid-stream: this direction starts here
            half.next = seg.seq
        if seg.payload:
            self._segment(conv, direction, half, seg.seq, seg.payload, seg.t_ns, out)
        if seg.flags & _FIN and half.fin_at is None:
            half.fin_at = (seg.seq + len(seg.payload)) % _MOD
        self._maybe_fin(conv, direction, half, seg.t_ns, out)
        if all(h.closed for h in conv.halves.values()):
            conv.ended = True
            self.open.pop(key, None)
        return out

    def _segment(self, conv: _Conv, direction: str, half: _Half, seq: int, data: bytes, t_ns: int,
                 out: list[Any]) -> None:
        assert half.next is not None
        delta = (seq - half.next) % _MOD
        if delta >= _HALF:  # starts before what was delivered: a retransmission, whole or in part
            behind = _MOD - delta
            if behind >= len(data):
                self.counts["tcp_retransmitted"] += 1
                return
            self.counts["tcp_overlap"] += 1
            seq, data, delta = half.next, data[behind:], 0
        if delta == 0:
            out.append(StreamData(t_ns, conv.index, direction, data))
            half.next = (half.next + len(data)) % _MOD
            self._drain(conv, direction, half, t_ns, out)
            return
        if delta > WINDOW:
            self.counts["tcp_out_of_window"] += 1
            return
        have = half.held.get(seq)
        if have is not None and len(have) >= len(data):
            self.counts["tcp_retransmitted"] += 1
            return
        self.counts["tcp_out_of_order"] += 1
        half.held_bytes += len(data) - (len(have) if have else 0)
        half.held[seq] = data
        if half.held_bytes > MAX_HELD or len(half.held) > MAX_HELD_SEGMENTS:
            self._give_up_hole(conv, direction, half, t_ns, out, f"more than {MAX_HELD} bytes or "
                               f"{MAX_HELD_SEGMENTS} segments after a hole")

    def _drain(self, conv: _Conv, direction: str, half: _Half, t_ns: int, out: list[Any]) -> None:
        """Deliver held segments the stream has reached."""
        progress = True
        while half.held and progress:
            progress = False
            for seq in list(half.held):
                assert half.next is not None
                delta = (seq - half.next) % _MOD
                if delta != 0 and delta < _HALF:
                    continue
                data = half.held.pop(seq)
                half.held_bytes -= len(data)
                behind = 0 if delta == 0 else _MOD - delta
                if behind < len(data):
                    out.append(StreamData(t_ns, conv.index, direction, data[behind:]))
                    half.next = (half.next + len(data) - behind) % _MOD
                else:
                    self.counts["tcp_retransmitted"] += 1
                progress = True

    def _give_up_hole(self, conv: _Conv, direction: str, half: _Half, t_ns: int, out: list[Any], why: str) -> None:
        """The bytes before the nearest held segment are not in the capture: a gap, then on."""
        assert half.next is not None
        nxt = half.next
        first = min(half.held, key=lambda s: (s - nxt) % _MOD)
        missing = (first - half.next) % _MOD
        self.counts["tcp_gap_bytes"] += missing
        out.append(StreamGap(t_ns, conv.index, direction, f"{missing} byte(s) missing from the capture ({why})"))
        half.next = first
        self._drain(conv, direction, half, t_ns, out)

    def _maybe_fin(self, conv: _Conv, direction: str, half: _Half, t_ns: int, out: list[Any]) -> None:
        if half.fin_at is not None and not half.closed and half.next == half.fin_at:
            half.closed = True
            out.append(StreamEvent(t_ns, "close", conv.index, conv.client, conv.backend,
                                   "client" if direction == "tx" else "backend", "fin"))

    def _drain_all(self, conv: _Conv, t_ns: int, out: list[Any]) -> None:
        for direction, half in conv.halves.items():
            while half.held:
                self._give_up_hole(conv, direction, half, t_ns, out, "never retransmitted before the connection ended")
            self._maybe_fin(conv, direction, half, t_ns, out)

    def _end(self, conv: _Conv, t_ns: int, out: list[Any]) -> None:
        self._drain_all(conv, t_ns, out)
        conv.ended = True

    def finish(self, t_ns: int) -> list[Any]:
        """The end of the capture: holes still open are gaps (their held bytes delivered)."""
        out: list[Any] = []
        for conv in list(self.open.values()):
            self._end(conv, t_ns, out)
        self.open.clear()
        return out


def tcp_events(cap: Capture, backend_port: int | None = None, backend_speaks: Any = None) -> Iterator[Any]:
    """The reassembled events of a pcap/pcapng capture (see the module docstring);
    ``backend_speaks(payload)``: whether a segment's bytes are the backend's (which side is
    which in a connection the capture joined mid-stream, off the backend's port)."""
    r = TcpReassembler(cap.counts, backend_port, backend_speaks)
    last = 0
    for seg in tcp_segments(cap):
        last = seg.t_ns
        yield from r.feed(seg)
    yield from r.finish(last)

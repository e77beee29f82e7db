"""TCP conversations written as a pcap or pcapng that Wireshark and tshark follow (issue 21).

:func:`write_tcp_pcap` takes a stream capture's records in time order — ``StreamEvent``
(``open``, ``close`` by client or backend with FIN or RST), ``StreamFrame`` (``tx`` one
write of the client, ``rx`` one frame of the backend) or ``traceio.tcp.StreamData`` — and
writes each connection as the packets TCP would have put on the wire, built and written with
dpkt (Ether/IPv4/TCP, :mod:`traceio.pcap_out`; a pcap in nanoseconds, a pcapng in
microseconds): the three-way handshake, each write as segments of at most :data:`MSS` bytes
with the peer's ACK, sequence and acknowledgement numbers that follow the bytes, and the
close as it happened (FIN and its ACK from each side that closed, or an RST after which the
connection says nothing more). Bytes with no open event (a capture written before
``/nsqd/conn``) open their connection first, between loopback ports. tshark's "Follow TCP
stream" (``-z follow,tcp,raw,N``) gives back each direction's bytes exactly.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mcp_conform.traceio.pcap_out import PacketFile, tcp_frame

__all__ = ["MSS", "write_tcp_pcap"]

MSS = 1460
_LOOPBACK = "127.0.0.1"
_STEP_NS = 1000  # packets generated at one instant are spread a microsecond apart


@dataclass
class _Side:
    addr: tuple[str, int]
    seq: int  # the next sequence number this side sends


@dataclass
class _Conn:
    client: _Side
    backend: _Side
    closed: set[str]
    reset: bool = False


class _Writer:
    def __init__(self, path: Path, backend_port: int) -> None:
        self.w = PacketFile(path, nano=True)  # pcap in nanoseconds; pcapng in microseconds
        self.backend_port = backend_port
        self.conns: dict[int, _Conn] = {}
        self.packets = 0
        self.last_ns = 0

    def _emit(self, t_ns: int, src: _Side, dst: _Side, flags: str, payload: bytes = b"") -> None:
        t_ns = max(t_ns, self.last_ns + _STEP_NS)
        self.last_ns = t_ns
        frame = tcp_frame(src.addr, dst.addr, flags, src.seq % (1 << 32),
                          dst.seq % (1 << 32) if "A" in flags else 0, payload, window=65535)
        self.w.write(frame, t_ns)
        self.packets += 1

    def open(self, t_ns: int, conn: int, client: Any, backend: Any) -> _Conn:
        c = self.conns.get(conn)
        if c is not None:
            return c
        client = tuple(client) if client and client[1] else (_LOOPBACK, 40000 + conn % 20000)
        backend = tuple(backend) if backend and backend[1] else (_LOOPBACK, self.backend_port)
        c = self.conns[conn] = _Conn(_Side(client, 1000 + 7919 * conn), _Side(backend, 500000 + 104729 * conn),
                                     set())
        self._emit(t_ns, c.client, c.backend, "S")
        c.client.seq += 1
        self._emit(t_ns, c.backend, c.client, "SA")
        c.backend.seq += 1
        self._emit(t_ns, c.client, c.backend, "A")
        return c

    def data(self, t_ns: int, conn: int, direction: str, data: bytes) -> None:
        c = self.open(t_ns, conn, None, None)
        src, dst = (c.client, c.backend) if direction == "tx" else (c.backend, c.client)
        who = "client" if direction == "tx" else "backend"
        if c.reset or who in c.closed or not data:
            return
        for i in range(0, len(data), MSS):
            chunk = data[i:i + MSS]
            self._emit(t_ns, src, dst, "PA", chunk)
            src.seq += len(chunk)
        self._emit(t_ns, dst, src, "A")

    def close(self, t_ns: int, conn: int, by: str, how: str) -> None:
        c = self.open(t_ns, conn, None, None)
        if c.reset or by in c.closed:
            return
        src, dst = (c.client, c.backend) if by == "client" else (c.backend, c.client)
        if how == "rst":
            self._emit(t_ns, src, dst, "RA")
            c.reset = True
            return
        self._emit(t_ns, src, dst, "FA")
        src.seq += 1
        c.closed.add(by)
        self._emit(t_ns, dst, src, "A")

    def finish(self) -> None:
        self.w.close()


def write_tcp_pcap(path: str | Path, records: Iterable[Any], backend_port: int) -> int:
    """Write the conversations of ``records`` (see the module docstring) to ``path`` (pcapng
    when it ends ``.pcapng``); the number of packets written. OSError for ``path``;
    ``traceio.pcap_out.FrameError`` for what a packet or the file cannot hold (a time past a
    pcap's 2^32 s, an address that is not IPv4)."""
    from mcp_conform.traceio.reader import StreamEvent, StreamFrame
    from mcp_conform.traceio.tcp import StreamData

    w = _Writer(Path(path), backend_port)
    try:
        for rec in records:
            kind = type(rec)
            if kind is StreamEvent:
                if rec.event == "open":
                    w.open(rec.t_ns, rec.conn, rec.client, rec.backend)
                else:
                    w.close(rec.t_ns, rec.conn, rec.by or "client", rec.how or "fin")
            elif kind is StreamFrame:
                w.data(rec.t_ns, rec.conn, rec.direction, rec.raw)
            elif kind is StreamData:
                w.data(rec.t_ns, rec.conn, rec.direction, rec.data)
    finally:
        w.finish()
    return w.packets

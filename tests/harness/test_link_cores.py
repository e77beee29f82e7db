"""The protocol is a parameter of the runner's link cores, not a copy of them: a protocol that
is none of ours (lines ending in a newline) runs on ``harness.link.Link`` (a reader thread,
UDP both ways on loopback) and on ``harness.stream_conn.StreamConn`` (a TCP connection read in
the caller's thread), its frames cut by its own framing and recorded in the order they went
and came; and ``harness.link_session.LinkSessionBase`` makes the link it declares
(``link_class``) and awaits its first sign."""

from __future__ import annotations

import os
import resource
import socket
import struct
import threading
from dataclasses import dataclass
from typing import Any

import pytest

from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.link import Link
from mcp_conform.harness.link_session import LinkSessionBase
from mcp_conform.harness.stream_conn import StreamConn


@dataclass(frozen=True)
class Line:
    t: float
    raw: bytes

    @property
    def name(self) -> str:
        return self.raw.split(b" ", 1)[0].decode()

    @property
    def bad(self) -> bool:
        return not self.raw.endswith(b"\n")


class LineFraming:
    """Each datagram or stream chunk cut at newlines; what has none is bad."""

    thread = "line-link"

    def __init__(self) -> None:
        self.records: list[tuple[str, bytes, str | None]] = []

    # harness.link.Framing
    def deframe(self, data: bytes, t: float) -> list[Line]:
        return [Line(t, part) for part in data.splitlines(keepends=True)]

    def record(self, recorder: Any, direction: str, raw: bytes, t_ns: int, name: str | None) -> None:
        recorder.append((direction, raw, name))



class LineStreamFraming(LineFraming):
    """The same lines as a connection's protocol (``harness.stream_conn.StreamFraming``)."""

    def deframe(self, data: bytes, t: float) -> list[Any]:  # type: ignore[override]
        return [(line, None if line.bad else line, {"name": None if line.bad else line.name})
                for line in super().deframe(data, t)]

    def sent(self, data: bytes) -> dict[str, Any]:
        return {"name": Line(0.0, data).name}


class Monitor:
    def __init__(self) -> None:
        self.frames: list[tuple[bytes, str]] = []

    def frame(self, t_ns: int, raw: bytes, direction: str) -> None:
        self.frames.append((raw, direction))


class LineLink(Link):
    def pack(self, msg: Any) -> tuple[bytes, str]:
        return f"{msg}\n".encode(), str(msg).split(" ", 1)[0]


def test_a_packet_protocol_of_its_own_runs_on_the_threaded_link() -> None:
    node = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    node.bind(("127.0.0.1", 0))
    node.settimeout(5.0)
    recorder: list[tuple[str, bytes, str | None]] = []
    monitor = Monitor()
    link = LineLink(LineFraming(), "udpout", node.getsockname(), recorder, monitor=monitor)
    try:
        link.send("PING 1")
        data, addr = node.recvfrom(100)
        assert data == b"PING 1\n"
        node.sendto(b"PONG 1\nPONG 2\nhalf", addr)
        assert link.wait_for(lambda: len(link.received()) == 3, 5.0)
        assert [r.name for r in link.received(name="PONG")] == ["PONG", "PONG"]
        assert link.received()[-1].bad
        assert recorder == [("rx", b"PING 1\n", "PING"), ("tx", b"PONG 1\n", "PONG"),
                            ("tx", b"PONG 2\n", "PONG"), ("tx", b"half", None)]
        assert [d for _, d in monitor.frames] == ["rx", "tx", "tx", "tx"]
        assert [name for _, name, _ in link.sent] == ["PING"]
    finally:
        link.close()
        node.close()


class Recorder:
    def __init__(self) -> None:
        self.records: list[tuple[Any, ...]] = []

    def stream_frame(self, direction: str, raw: bytes, **kw: Any) -> None:
        self.records.append(("frame", direction, raw, kw["name"]))

    def stream_event(self, event: str, **kw: Any) -> None:
        self.records.append(("event", event, kw.get("by"), kw.get("how")))


def test_a_stream_protocol_of_its_own_runs_on_the_pumped_connection() -> None:
    listener = socket.create_server(("127.0.0.1", 0))
    accepted: list[socket.socket] = []
    server = threading.Thread(target=lambda: accepted.append(listener.accept()[0]))
    server.start()
    rec = Recorder()
    log: list[tuple[float, bytes]] = []
    conn = StreamConn(LineStreamFraming(), "tcp", listener.getsockname(), rec,
                      sock=socket.create_connection(listener.getsockname()), log=log, index=1, protocol="lines")
    server.join(5.0)
    peer = accepted[0]
    try:
        assert conn.send(b"HELLO there\n", split=3, gap=0.001)
        got = b""
        peer.settimeout(5.0)
        while len(got) < 12:
            got += peer.recv(100)
        assert got == b"HELLO there\n" and len(log) == 1
        peer.sendall(b"WORLD 1\nnoise")
        peer.close()
        assert conn.wait_for(lambda: conn.closed_at is not None, 5.0)
        assert [f.name for f in conn.frames] == ["WORLD"]
        assert conn.framing_error is not None and conn.framing_error.raw == b"noise"
        assert rec.records == [("event", "open", None, None), ("frame", "tx", b"HELLO there\n", "HELLO"),
                               ("frame", "rx", b"WORLD 1\n", "WORLD"), ("frame", "rx", b"noise", None),
                               ("event", "close", "backend", "fin")]
    finally:
        conn.close()
        listener.close()



def test_the_pumped_connection_sees_a_reset_and_reads_a_descriptor_above_1023() -> None:
    """The core's read (``harness.link.Link._read_once``) polls its end: a connection whose
    descriptor is above select()'s 1023 (a run with many open) is read like any other, and the
    node's RST is the connection's reset, on the capture as the backend's."""
    soft, _ = resource.getrlimit(resource.RLIMIT_NOFILE)
    if soft < 1200:
        pytest.skip(f"the descriptor limit ({soft}) is below 1200")
    listener = socket.create_server(("127.0.0.1", 0))
    filler = [os.dup(listener.fileno()) for _ in range(1100)]  # the next descriptors are above 1023
    try:
        client = socket.create_connection(listener.getsockname())
        peer, _ = listener.accept()
        assert client.fileno() > 1023
        rec = Recorder()
        conn = StreamConn(LineStreamFraming(), "tcp", listener.getsockname(), rec, sock=client, index=2,
                          protocol="lines")
        peer.sendall(b"WORLD 2\n")
        assert conn.wait_for(lambda: bool(conn.frames), 5.0)
        assert [f.name for f in conn.frames] == ["WORLD"] and conn.closed_at is None
        peer.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        peer.close()  # an RST
        assert conn.wait_for(lambda: conn.closed_at is not None, 5.0)
        assert conn.reset and rec.records[-1] == ("event", "close", "backend", "rst")
        conn.close()
    finally:
        for fd in filler:
            os.close(fd)
        listener.close()

class LineSessionLink(LineLink):
    """The line protocol's link as a session makes it (``link_class``): its framing its own."""

    def __init__(self, transport: str, address: tuple[str, int], recorder: Any = None, **kw: Any) -> None:
        super().__init__(LineFraming(), transport, address, recorder, **kw)


class LineSession(LinkSessionBase):
    """A session of the line protocol on the core: its link, first sign and beat declared."""

    subject = "the line node"
    first_sign, first_rule, beat_thread = "HELLO", "LINE-1", "line-beat"
    link_class = LineSessionLink

    def beat_message(self, link: Any) -> str:
        return "BEAT"

    def identified(self, first: Any) -> None:
        self.node_name = first.raw.split()[1].decode()


class LineSpec:
    params = {"heartbeat_period_s": 0.05}


def test_a_session_makes_the_link_its_protocol_declares_and_awaits_its_first_sign() -> None:
    node = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    node.bind(("127.0.0.1", 0))
    node.settimeout(5.0)
    recorder: list[tuple[str, bytes, str | None]] = []
    cfg = RunConfig(target=("udpout:127.0.0.1", node.getsockname()[1]), timeout=5.0,
                    extra={"startup_timeout": 5.0})
    session = LineSession(cfg, recorder, LineSpec(), Monitor(), scheme="tcp", embedded=None)

    def answer() -> None:  # the node answers the runner's first beat with its first sign
        data, addr = node.recvfrom(100)
        if data == b"BEAT\n":
            node.sendto(b"HELLO seven\n", addr)
    t = threading.Thread(target=answer)
    t.start()
    try:
        session.start()
        assert isinstance(session.link, LineSessionLink) and session.link.transport == "udpout"
        assert session.node_name == "seven" and session.first_heartbeat is not None
        assert session.url == f"udpout:127.0.0.1:{node.getsockname()[1]}"
        assert recorder[:2] == [("rx", b"BEAT\n", "BEAT"), ("tx", b"HELLO seven\n", "HELLO")]
    finally:
        t.join(5.0)
        session.close()
        node.close()

#!/usr/bin/env python3
"""A plain, correct, single-threaded MCP drone: one UDP socket, one loop, stdlib only.

Written to prove the fuzzer's oracles against the simplest honest node there is (issue 36):
no receiver thread, no large receive buffer. It reads its socket only in its main loop, so a
burst larger than the kernel's receive buffer loses datagrams before the node ever sees them
— which a manager's retransmission every --rto covers (MCP-ACK-1's observation, D-6).
``--rcvbuf BYTES`` makes that buffer small (the kernel doubles the value and keeps a floor).

It sends Mission_Ready to ID 0 every --rto until ACKed (MCP-FLOW-1, MCP-RTX-1), ACKs every
well-formed unicast to its ID that is not an ACK, copies included (MCP-ACK-1/2/3), never a
broadcast, an ACK, a message to another ID or a malformed datagram (MCP-ACK-4/5/6, ROB-1..4),
discards a copy of the last (src, seq) delivered (MCP-DUP-1/2/3, 0 after 65535 is new,
MCP-SEQ-3), and on End_Mission keeps ACKing for 2 x rto, then exits 0. With ``--mavlink
tcp:HOST:PORT`` it writes each delivered Mav_Passthrough frame to that TCP autopilot once
(MCP-PAY-8) and reads (and drops) what the autopilot sends; it does not wait for a fix.

``--fault no-ack-wp-on``: WP_On is delivered but never ACKed (MCP-ACK-1), every copy.
``--deaf-after-big S``: after a datagram larger than 8192 bytes the node does not read for
S seconds (a correct node busy for a while: D-6). ``--drops-file FILE``: on exit, append how
many datagrams the kernel dropped from its full receive buffer (Linux /proc/net/udp's
``drops`` of its socket; -1 where unknown), so a test can tell a burst did overflow it.

Same command line as tests/conformance/nodes/sample_node.py, so ``mcp-fuzz --spawn`` runs it:

    python tests/fuzz/nodes/plain_node.py --id 1 --bind 127.0.0.1:7890 \
        --send-to 127.0.0.1:7889 [--mavlink tcp:127.0.0.1:5760] [--rto 5] [--rcvbuf BYTES] \
        [--deaf-after-big S] [--drops-file FILE] [--fault no-ack-wp-on]
"""

from __future__ import annotations

import argparse
import random
import select
import signal
import socket
import sys
import time
from pathlib import Path
from typing import Any

_ROOT = Path(__file__).resolve().parents[3]
if str(_ROOT) not in sys.path:  # run as a script: make the project's ``spec`` importable
    sys.path.insert(0, str(_ROOT))

from mcp_conform.spec.codec import (  # noqa: E402
    BROADCAST_ID,
    MANAGER_ID,
    Action,
    DecodeError,
    Message,
    decode,
    encode,
)

FAULTS = {"no-ack-wp-on": ("MCP-ACK-1", "WP_On is delivered but never ACKed, no copy of it")}
BIG = 8192
POLL = 0.05
RECV_MAX = 65535


def log(text: str) -> None:
    sys.stderr.write(f"[plain_node {time.monotonic():.3f}] {text}\n")
    sys.stderr.flush()


def hostport(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host or "0.0.0.0", int(port)


class PlainNode:
    def __init__(self, args: argparse.Namespace) -> None:
        self.id: int = args.id
        self.rto: float = args.rto
        self.send_to: tuple[str, int] = args.send_to
        self.faults: set[str] = set(args.fault)
        self.deaf_after_big: float = args.deaf_after_big
        self.seq = random.randrange(65536)
        self.last: dict[int, int] = {}  # src -> seq of the last message delivered from it
        self.ready: bytes | None = None  # Mission_Ready awaiting its ACK
        self.ready_seq = -1
        self.next_copy = 0.0
        self.ended_at: float | None = None
        self.stop = False
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        if args.rcvbuf is not None:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, args.rcvbuf)
        self.sock.bind(args.bind)
        self.autopilot: socket.socket | None = None
        if args.mavlink:
            self.autopilot = socket.create_connection(tcp_address(args.mavlink), timeout=5.0)
            self.autopilot.setblocking(False)
        rcv = self.sock.getsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF)
        log(f"id {self.id} on {self.sock.getsockname()}, SO_RCVBUF {rcv}, faults {sorted(self.faults)}")

    def next_seq(self) -> int:
        self.seq = (self.seq + 1) & 0xFFFF
        return self.seq

    def send(self, dst: int, action: Action, payload: Any = None) -> bytes:
        data = encode(Message(dst, self.id, self.next_seq(), action, payload))
        self.sock.sendto(data, self.send_to)
        return data

    def run(self) -> int:
        self.ready = self.send(MANAGER_ID, Action.MISSION_READY)
        self.ready_seq = self.seq
        self.next_copy = time.monotonic() + self.rto
        while not self.stop:
            now = time.monotonic()
            if self.ended_at is not None and now >= self.ended_at + 2 * self.rto:
                log("mission over: exiting")
                return 0
            if self.ready is not None and now >= self.next_copy:
                self.sock.sendto(self.ready, self.send_to)  # the same bytes (MCP-SEQ-2)
                self.next_copy = now + self.rto
            socks = [self.sock] + ([self.autopilot] if self.autopilot is not None else [])
            readable, _, _ = select.select(socks, [], [], POLL)
            if self.autopilot is not None and self.autopilot in readable:
                self.drain_autopilot()
            if self.sock in readable:
                data, _addr = self.sock.recvfrom(RECV_MAX)
                self.on_datagram(data)
                if len(data) > BIG and self.deaf_after_big > 0:
                    log(f"{len(data)} B: busy for {self.deaf_after_big} s")
                    time.sleep(self.deaf_after_big)
        return 0

    def drain_autopilot(self) -> None:
        assert self.autopilot is not None
        try:
            if not self.autopilot.recv(65536):
                self.autopilot.close()
                self.autopilot = None
        except BlockingIOError:
            pass
        except OSError:
            self.autopilot = None

    def on_datagram(self, data: bytes) -> None:
        try:
            msg = decode(data)
        except DecodeError:
            return  # discarded silently (MCP-ROB-1..4)
        if msg.action == Action.ACK:
            if self.ready is not None and msg.src == MANAGER_ID and msg.payload == self.ready_seq:
                self.ready = None
            return  # never ACKed (MCP-ACK-6)
        if msg.src in (self.id, BROADCAST_ID):
            return  # our own looped-back datagram, or no sender to answer
        if msg.dst == self.id:
            if not (msg.action == Action.WP_ON and "no-ack-wp-on" in self.faults):
                self.send(msg.src, Action.ACK, msg.seq)
        elif msg.dst != BROADCAST_ID:
            return  # another drone's (MCP-ACK-5)
        if self.last.get(msg.src) == msg.seq:
            return  # a duplicate: ACKed again, not delivered again (MCP-DUP-1)
        self.last[msg.src] = msg.seq
        self.deliver(msg)

    def deliver(self, msg: Message) -> None:
        if self.ended_at is not None:
            return
        if msg.action == Action.END_MISSION:
            self.ended_at = time.monotonic()
            log("End_Mission: still ACKing for 2 x rto")
        elif msg.action == Action.MAV_PASSTHROUGH and self.autopilot is not None:
            try:
                self.autopilot.sendall(msg.payload)
            except OSError as exc:
                log(f"autopilot write failed: {exc}")


def kernel_drops(sock: socket.socket) -> int:
    """Datagrams the kernel dropped for ``sock`` (its inode's line of /proc/net/udp), or -1."""
    import os

    try:
        inode = str(os.fstat(sock.fileno()).st_ino)
        for line in Path("/proc/net/udp").read_text().splitlines()[1:]:
            fields = line.split()
            if len(fields) > 12 and fields[9] == inode:
                return int(fields[-1])
    except (OSError, ValueError):
        pass
    return -1


def tcp_address(url: str) -> tuple[str, int]:
    scheme, _, rest = url.partition(":")
    if scheme != "tcp":
        raise ValueError(f"--mavlink {url!r}: only tcp:HOST:PORT")
    return hostport(rest)


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--id", type=int, required=True)
    p.add_argument("--bind", type=hostport, required=True, metavar="HOST:PORT")
    p.add_argument("--send-to", type=hostport, required=True, metavar="HOST:PORT")
    p.add_argument("--mavlink", default=None, metavar="tcp:HOST:PORT")
    p.add_argument("--rto", type=float, default=5.0)
    p.add_argument("--rcvbuf", type=int, default=None, metavar="BYTES",
                   help="SO_RCVBUF of the socket (default: the system's)")
    p.add_argument("--deaf-after-big", type=float, default=0.0, metavar="S")
    p.add_argument("--drops-file", default=None, metavar="FILE")
    p.add_argument("--fault", action="append", default=[], choices=sorted(FAULTS))
    args = p.parse_args(argv)
    if not 1 <= args.id <= 0xFFFE or not args.rto > 0:
        p.error("--id must be 1..65534 and --rto positive")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        node = PlainNode(args)
    except (OSError, ValueError) as exc:
        log(f"cannot start: {exc}")
        return 2

    def on_signal(_signum: int, _frame: Any) -> None:
        node.stop = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        return node.run()
    finally:
        if args.drops_file:
            with open(args.drops_file, "a", encoding="utf-8") as f:
                f.write(f"{kernel_drops(node.sock)}\n")
        node.sock.close()


if __name__ == "__main__":
    sys.exit(main())

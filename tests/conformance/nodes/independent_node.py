#!/usr/bin/env python3
"""A second independent drone-role MCP node: one thread, one ``select`` loop.

Written from MCP-REQUIREMENTS.md and spec/mcp.yaml alone, without ``reference_impl`` and
without the sample node's threads: the shape of a plain embedded application (issue 35). One
loop waits in ``select`` on the node's UDP socket and its TCP (or UDP) autopilot link, and
does everything in turn: it ACKs every well-formed unicast to its ID (MCP-ACK-1, every copy;
never a broadcast, an ACK or another ID's message, MCP-ACK-4/5/6), discards duplicates per
source as MCP-DUP-1 words it (the seq last delivered from that src; ``--dup-window N``
remembers the last N, so a late copy of an older one is not delivered again either, which
MCP-DUP-4 leaves open), drops malformed datagrams silently (MCP-ROB-1..4), retransmits its own
Mission_Ready every ``--rto`` with the same seq and bytes until the ACK from ID 0 naming its
seq (MCP-RTX-1/2, MCP-SEQ-2), sends it only once the autopilot reports a 3D fix (MCP-BLK-5),
sets GUIDED, arms and takes off only after Start_Mission (MCP-BLK-4), commands RTL on
End_Mission (MCP-BLK-7), and writes each delivered Mav_Passthrough frame to the autopilot
with pymavlink's ``write``, as it came (MCP-PAY-8). The wire format is ``spec.codec``'s; the
autopilot is pymavlink's ``mavutil.mavlink_connection``.

    python tests/conformance/nodes/independent_node.py --id 1 --bind 127.0.0.1:7890 \
        --send-to 127.0.0.1:7889 [--mavlink tcp:127.0.0.1:5760] [--rto 5] [--retries 1000] \
        [--no-passthrough] [--dup-window N] [--linger S] [--record FILE]

The sample node's other options (``--ack-mode``, ``--reply-to-source``, ``--rtl-refused``,
``--busy-start``, ``--read-delay``, ``--fault``) are not offered: this node has one
behaviour, the correct one. Every event is one line on stderr. Exit codes: 0 after
End_Mission (once it has kept ACKing for ``--linger``, default 2 x rto) or on
SIGTERM/SIGINT; 2 on a usage, bind or autopilot-connection error.
"""

from __future__ import annotations

import argparse
import json
import select
import signal
import socket
import struct
import sys
import time
from collections import deque
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
    build_datagram,
    decode,
)

POLL = 0.05  # longest select() wait: signals and timers are looked at this often
FIX_3D = 3  # GPS_RAW_INT.fix_type (MAVLink GPS_FIX_TYPE_3D_FIX)
TAKEOFF_ALT = 10.0
GUIDED = 4  # ArduCopter custom mode numbers (ArduCopter/mode.h)
COMMAND_TIMEOUT = 1.0  # a MAVLink command unanswered this long is sent again
COMMAND_TRIES = 3

_t0 = time.monotonic()


def log(text: str) -> None:
    try:
        sys.stderr.write(f"[independent_node {time.monotonic() - _t0:8.3f}] {text}\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def hostport(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host or "0.0.0.0", int(port)


class Node:
    """The whole node: its state, and one step of its loop per ``select`` wake-up."""

    def __init__(self, args: argparse.Namespace) -> None:
        self.id: int = args.id
        self.rto: float = args.rto
        self.retries: int = args.retries
        self.send_to: tuple[str, int] = args.send_to
        self.passthrough = not args.no_passthrough
        self.dup_window: int = args.dup_window
        self.linger = 2 * self.rto if args.linger is None else args.linger
        self.record_path: str | None = args.record
        self.stopped = False
        self.seq = int.from_bytes(struct.pack("!d", time.time())[-2:], "big")  # arbitrary (MCP-SEQ-4)
        # Mission_Ready in flight: (seq, bytes, copies sent, next copy due); None once ACKed
        self.ready: tuple[int, bytes, int, float] | None = None
        self.ready_sent = False
        self.last: dict[int, int] = {}  # src -> last delivered seq
        self.recent: dict[int, deque[int]] = {}  # src -> the last dup_window seqs delivered
        self.deliveries: list[list[Any]] = []
        self.started = False
        self.ended_at: float | None = None
        self.outcome = "running"
        # MAVLink work in order: (label, command id, send function), one in flight at a time
        self.jobs: deque[tuple[str, int, Any]] = deque()
        self.job_sent: tuple[float, int] | None = None  # (when, tries) of the job in flight
        self.fix = False

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        self.sock.bind(args.bind)
        self.sock.setblocking(False)
        self.master: Any = None
        if args.mavlink:
            from pymavlink import mavutil

            self.mav = mavutil.mavlink
            self.master = mavutil.mavlink_connection(args.mavlink, source_system=255, source_component=190,
                                                     autoreconnect=False, retries=2)
            log(f"connected to the autopilot at {args.mavlink}")
        else:
            self.fix = True  # no autopilot: the fix counts as present
        host, port = self.sock.getsockname()[:2]
        log(f"id {self.id} listening on {host}:{port}, sending to {self.send_to[0]}:{self.send_to[1]}, rto {self.rto}")

    # ------------------------------------------------------------------ MCP out
    def next_seq(self) -> int:
        self.seq = (self.seq + 1) & 0xFFFF
        return self.seq

    def sendto(self, data: bytes) -> None:
        try:
            self.sock.sendto(data, self.send_to)
        except OSError as exc:
            log(f"send failed: {exc}")

    def ack(self, msg: Message) -> None:
        """The ACK of ``msg``: to its src, naming its seq big-endian (MCP-ACK-2/3); it takes
        a number of its own (D-5)."""
        self.sendto(build_datagram(msg.src, self.id, self.next_seq(), Action.ACK, struct.pack("!H", msg.seq)))

    def send_ready(self, now: float) -> None:
        """Mission_Ready, first copy or a retransmission (same seq, same bytes)."""
        if self.ready is None:
            seq = self.next_seq()
            self.ready = (seq, build_datagram(MANAGER_ID, self.id, seq, Action.MISSION_READY), 0, now)
            self.ready_sent = True
        seq, data, copies, _ = self.ready
        if copies > self.retries:
            log(f"Mission_Ready seq {seq}: no ACK after {copies} copies, giving up")
            self.ready = None
            return
        self.sendto(data)
        log(f"sent MISSION_READY seq {seq} (copy {copies + 1})")
        self.ready = (seq, data, copies + 1, now + self.rto)

    # ------------------------------------------------------------------ MCP in
    def on_datagram(self, data: bytes) -> None:
        try:
            msg = decode(data)
        except DecodeError as exc:
            log(f"malformed datagram ({len(data)} bytes) dropped: {exc}")
            return
        if msg.action == Action.ACK:
            if msg.dst == self.id:
                self.on_ack(msg)
            return  # an ACK is never ACKed (MCP-ACK-6)
        if msg.dst == BROADCAST_ID:
            self.accept(msg)  # delivered, never ACKed (MCP-ACK-4)
            return
        if msg.dst != self.id:
            return  # another ID's: neither ACKed nor acted on (MCP-ACK-5)
        self.ack(msg)
        self.accept(msg)

    def on_ack(self, msg: Message) -> None:
        if self.ready is not None and msg.src == MANAGER_ID and msg.payload == self.ready[0]:
            log(f"MISSION_READY seq {self.ready[0]} ACKed")
            self.ready = None

    def accept(self, msg: Message) -> None:
        """Duplicate discard per src, then delivery."""
        recent = self.recent.setdefault(msg.src, deque(maxlen=self.dup_window))
        if self.last.get(msg.src) == msg.seq or msg.seq in recent:
            log(f"duplicate {msg.action.name} seq {msg.seq} from {msg.src}: not delivered")
            return
        self.last[msg.src] = msg.seq
        recent.append(msg.seq)
        if self.ended_at is not None:
            return
        self.deliveries.append([msg.action.name, msg.src, msg.seq])
        log(f"delivered {msg.action.name} seq {msg.seq} from {msg.src}")
        self.handle(msg)

    def handle(self, msg: Message) -> None:
        a = msg.action
        if a == Action.START_MISSION and not self.started:
            self.started = True
            if self.master is not None:
                c = self.master
                self.jobs += [("mode GUIDED", self.mav.MAV_CMD_DO_SET_MODE, lambda: c.set_mode_apm(GUIDED)),
                              ("arm", self.mav.MAV_CMD_COMPONENT_ARM_DISARM, c.arducopter_arm),
                              ("takeoff", self.mav.MAV_CMD_NAV_TAKEOFF, lambda: c.mav.command_long_send(
                                  c.target_system, c.target_component, self.mav.MAV_CMD_NAV_TAKEOFF, 0,
                                  0, 0, 0, 0, 0, 0, TAKEOFF_ALT))]
        elif a == Action.END_MISSION:
            self.ended_at = time.monotonic()
            if self.master is not None:
                self.jobs.append(("RTL", self.mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, self.master.set_mode_rtl))
            log(f"End_Mission: still ACKing for {self.linger:.2f} s")
        elif a == Action.MAV_PASSTHROUGH:
            if not self.passthrough or self.master is None:
                log(f"Mav_Passthrough of {len(msg.payload)} bytes: not forwarded")
                return
            self.master.write(msg.payload)
            log(f"wrote a {len(msg.payload)}-byte passthrough frame to the autopilot")

    # ------------------------------------------------------------------ autopilot
    def on_autopilot(self) -> None:
        while True:
            m = self.master.recv_match(blocking=False)
            if m is None:
                return
            kind = m.get_type()
            if kind == "GPS_RAW_INT" and m.fix_type >= FIX_3D and not self.fix:
                log(f"GPS 3D fix (fix_type {m.fix_type})")
                self.fix = True
            elif kind == "COMMAND_ACK" and self.jobs and int(m.command) == self.jobs[0][1]:
                label = self.jobs.popleft()[0]
                ok = m.result == self.mav.MAV_RESULT_ACCEPTED
                log(f"autopilot: {label} {'accepted' if ok else f'refused (result {m.result})'}")
                self.job_sent = None
                if label == "arm" and not ok:  # no takeoff without arming
                    while self.jobs and self.jobs[0][0] == "takeoff":
                        self.jobs.popleft()

    def run_jobs(self, now: float) -> None:
        if not self.jobs:
            return
        label, _, send = self.jobs[0]
        if self.job_sent is not None and now < self.job_sent[0] + COMMAND_TIMEOUT:
            return
        tries = 0 if self.job_sent is None else self.job_sent[1]
        if tries >= COMMAND_TRIES:
            log(f"autopilot: {label}: no COMMAND_ACK")
            self.jobs.popleft()
            self.job_sent = None
            return
        send()
        self.job_sent = (now, tries + 1)

    # ------------------------------------------------------------------ the loop
    def run(self) -> int:
        if self.master is not None:
            log("waiting for a 3D GPS fix")
        while not self.stopped:
            now = time.monotonic()
            if self.ended_at is not None and now >= self.ended_at + self.linger and not self.jobs:
                log("mission over: exiting")
                self.outcome = "end_mission"
                return 0
            if self.fix and not self.ready_sent:
                self.send_ready(now)
            elif self.ready is not None and now >= self.ready[3]:
                self.send_ready(now)
            self.run_jobs(now)
            wait = POLL if self.ready is None else max(0.0, min(POLL, self.ready[3] - now))
            fds = [self.sock] + ([self.master.fd] if self.master is not None else [])
            try:
                readable, _, _ = select.select(fds, [], [], wait)
            except InterruptedError:
                continue
            if self.master is not None and self.master.fd in readable:
                self.on_autopilot()
            if self.sock in readable:
                while True:
                    try:
                        data, _ = self.sock.recvfrom(65535)
                    except (BlockingIOError, InterruptedError):
                        break
                    except OSError as exc:  # e.g. an ICMP error of an earlier send
                        log(f"receive error: {exc}")
                        break
                    self.on_datagram(data)
        return 0

    def close(self) -> None:
        if self.record_path:
            if self.outcome == "running" and self.ended_at is not None:
                self.outcome = "end_mission"
            try:
                Path(self.record_path).write_text(json.dumps(
                    {"role": "drone", "id": self.id, "outcome": self.outcome, "deliveries": self.deliveries}) + "\n")
            except OSError as exc:
                log(f"cannot write the record: {exc}")
        if self.master is not None:
            try:
                self.master.close()
            except Exception:  # noqa: BLE001
                pass
        self.sock.close()


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--id", type=int, required=True, help="this drone's MCP ID (1..65534)")
    p.add_argument("--bind", type=hostport, required=True, metavar="HOST:PORT")
    p.add_argument("--send-to", type=hostport, required=True, metavar="HOST:PORT")
    p.add_argument("--mavlink", default=None, metavar="URL",
                   help="pymavlink connection string; without it there is no autopilot and the fix counts as present")
    p.add_argument("--rto", type=float, default=5.0, help="retransmission timeout, s (default 5)")
    p.add_argument("--retries", type=int, default=1000, help="retransmissions before giving up (default 1000)")
    p.add_argument("--no-passthrough", action="store_true", help="ACK Mav_Passthrough but do not forward it")
    p.add_argument("--dup-window", type=int, default=1, metavar="N",
                   help="seqs remembered per src for duplicate discard (default 1: the last delivered, MCP-DUP-1)")
    p.add_argument("--linger", type=float, default=None, metavar="S",
                   help="seconds to keep ACKing after End_Mission (default 2 x rto)")
    p.add_argument("--record", default=None, metavar="FILE",
                   help="write the delivery log (JSON: deliveries as [action, src, seq]) on exit")
    args = p.parse_args(argv)
    if not 1 <= args.id <= 0xFFFE:
        p.error("--id must be 1..65534")
    if not args.rto > 0:
        p.error("--rto must be positive")
    if args.dup_window < 1:
        p.error("--dup-window must be at least 1")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        node = Node(args)
    except OSError as exc:
        log(f"cannot start: {exc}")
        return 2
    except Exception as exc:  # noqa: BLE001 - pymavlink raises anything on a failed connect
        log(f"cannot connect to the autopilot at {args.mavlink}: {exc!r}")
        return 2

    def on_signal(signum: int, _frame: Any) -> None:
        node.stopped = True

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        return node.run()
    finally:
        node.close()


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env python3
"""An independent Mission Manager, written after the description's ``mission_manager.py``.

It does not import ``reference_impl``: it exists to prove ``mcp-conform --role manager``
against a manager it has never seen. It uses ``spec.codec`` for the wire format and
pymavlink (through ``spec.mission``) for the waypoint file, and follows the description's
steps: "1. Waits for 'Mission Ready' messages from all UAVs 2. Sends 'Start Mission'
message to each UAV 3. Executes the challenge based on the challenge number", then
End_Mission to each drone. Every unicast blocks until ACKed, retransmitted every ``--rto``
up to ``--retries`` times; a drone that never ACKs is dropped from the rest of the mission.

Without ``--fault`` the manager is correct. Each ``--fault NAME`` breaks exactly one rule
(``FAULTS``); everything else stays the same.

    python tests/conformance/nodes/sample_manager.py --challenge 1 --drones 1,2,3 \
        --waypoints FILE [--obstacles FILE] --bind 127.0.0.1:7889 --send-to 127.255.255.255:7890 \
        [--rto 5] [--retries 1000] [--ack-socket same|other] [--ack-to send-to|source] [--fault NAME ...]

Correct variants: ``--send-to`` a broadcast address (the description's way: unicasts go
to the broadcast address); ``--ack-socket other`` (ACKs leave from a second socket, on
another source port); ``--ack-to source`` (ACKs go to the source address of the datagram
they answer); ``--rto 5`` (the description's timeout). One line per event on
stderr. Exit 0 after End_Mission to every drone, 1 when a drone was dropped, 2 on a usage
or bind error; SIGTERM/SIGINT end it with 0.
"""

from __future__ import annotations

import argparse
import signal
import socket
import struct
import sys
import threading
import time
from pathlib import Path
from typing import Any

_ROOT = Path(__file__).resolve().parents[3]
if str(_ROOT) not in sys.path:  # run as a script: make the project's ``spec`` importable
    sys.path.insert(0, str(_ROOT))

from mcp_conform.spec.codec import (  # noqa: E402
    ITEM,
    MANAGER_ID,
    Action,
    DecodeError,
    Message,
    build_datagram,
    decode,
    encode,
)
from mcp_conform.spec.mission import load_waypoints  # noqa: E402

#: fault name -> (rule it violates, what it does)
FAULTS: dict[str, tuple[str, str]] = {
    "start-early": ("MCP-BLK-2", "starts once every drone but one is ready"),
    "count-duplicates": ("MCP-BLK-2", "counts Mission_Ready messages, not drones"),
    "dup-seq-only": ("MCP-DUP-3", "counts delivered Mission_Readys, its duplicate discard keyed by seq alone across "
                                  "drones (a copy after another drone's is delivered again: a clean link hides it)"),
    "no-wait-start-ack": ("MCP-BLK-3", "sends a drone its challenge command while its Start_Mission is unACKed"),
    "wrong-seq-ack": ("MCP-RTX-2", "any ACK from the destination ends the retransmission, whatever its seq"),
    "rtx-new-seq": ("MCP-SEQ-2", "each retransmission takes a new seq (an ACK of any of them ends it)"),
    "give-up-after-two": ("MCP-RTX-1", "sends each unicast twice at most, then drops the drone"),
    "wrong-count": ("MCP-PAY-3", "WP_List/Obstacles_List count is one more than the items"),
    "le-count": ("MCP-PAY-3", "WP_List/Obstacles_List count packed little-endian"),
    "out-of-order": ("MCP-FLOW-4", "WP_List carries the waypoints in reverse order"),
    "field-changed": ("MCP-FLOW-4", "WP_List's second waypoint is 1 m higher than the file's"),
    "wp-off-first": ("MCP-FLOW-5", "challenge 2: a WP_Off before the first WP_On to each drone"),
    "after-end": ("MCP-BLK-6", "a WP_Off to the first drone after its End_Mission"),
    "ack-ack": ("MCP-ACK-6", "ACKs the ACKs addressed to it"),
    "no-ready-ack": ("MCP-ACK-1", "never ACKs a Mission_Ready (counts it, and goes on with the mission)"),
}

_U16BE = struct.Struct("!H")
_U16LE = struct.Struct("<H")


def log(text: str) -> None:
    print(f"{time.monotonic():.3f} manager: {text}", file=sys.stderr, flush=True)


def hostport(text: str) -> tuple[str, int]:
    host, _, port = text.rpartition(":")
    return host, int(port)


class SampleManager:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.faults = set(args.fault)
        self.drones = tuple(int(x) for x in args.drones.split(","))
        self.waypoints = load_waypoints(args.waypoints)
        self.obstacles = load_waypoints(args.obstacles) if args.obstacles else self.waypoints
        self.send_to = hostport(args.send_to)
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        if args.read_delay:  # a backlog to read slowly: the reference manager's 4 MB buffer
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        self.sock.bind(hostport(args.bind))
        self.sock.settimeout(0.05)
        self.ack_sock = self.sock
        if args.ack_socket == "other":
            self.ack_sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            self.ack_sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
            self.ack_sock.bind(("127.0.0.1", 0))
        self.seq = 0x2000
        self.lock = threading.Lock()
        self.ready: list[int] = []  # drones (or, with count-duplicates, messages)
        self.last_ready_seq: int | None = None  # dup-seq-only: the last delivered, whoever sent it
        self.ready_event = threading.Event()
        self.acks: list[Message] = []  # every ACK received, in order (each waiter scans its own part)
        self.acked: set[tuple[int, int]] = set()  # (src, seq) of the messages it ACKed
        self.ack_cond = threading.Condition()
        self.stop = threading.Event()
        self.dropped: set[int] = set()
        self.sent: list[list[Any]] = []  # [action, drone] of each command, for --record

    # ------------------------------------------------------------------ wire
    def next_seq(self) -> int:
        with self.lock:
            s = self.seq
            self.seq = (self.seq + 1) & 0xFFFF
            return s

    def receive_loop(self) -> None:
        need = len(self.drones) - (1 if "start-early" in self.faults else 0)
        while not self.stop.is_set():
            try:
                data, addr = self.sock.recvfrom(65535)
            except (TimeoutError, OSError):
                continue
            try:
                msg = decode(data)
            except DecodeError:
                if self.args.read_delay:  # a slow reader (correct): each malformed datagram costs it time
                    time.sleep(self.args.read_delay)
                continue  # discarded without ACK
            if msg.dst != MANAGER_ID:
                continue
            if msg.action == Action.ACK:
                with self.ack_cond:
                    self.acks.append(msg)
                    self.ack_cond.notify_all()
                if "ack-ack" not in self.faults:
                    continue
            if not (msg.action == Action.MISSION_READY and "no-ready-ack" in self.faults):
                ack = encode(Message(msg.src, MANAGER_ID, self.next_seq(), Action.ACK, msg.seq))
                to = addr if self.args.ack_to == "source" else self.send_to
                if self.args.copy_ack_delay and (msg.src, msg.seq) in self.acked:  # a copy: late
                    threading.Timer(self.args.copy_ack_delay, self.ack_sock.sendto, (ack, to)).start()
                else:
                    self.ack_sock.sendto(ack, to)
                self.acked.add((msg.src, msg.seq))
            if msg.action == Action.MISSION_READY:
                with self.lock:
                    if "count-duplicates" in self.faults:
                        self.ready.append(msg.src)
                    elif "dup-seq-only" in self.faults:
                        if msg.seq != self.last_ready_seq:
                            self.last_ready_seq = msg.seq
                            self.ready.append(msg.src)
                    elif msg.src in self.drones and msg.src not in self.ready:
                        self.ready.append(msg.src)
                    if len(self.ready) >= need:
                        self.ready_event.set()

    def _acked(self, dst: int, seqs: set[int], until: float, since: int) -> bool:
        """An ACK from ``dst`` naming one of ``seqs`` among the ACKs from index ``since``."""
        with self.ack_cond:
            while True:
                for ack in self.acks[since:]:
                    if ack.src == dst and ("wrong-seq-ack" in self.faults or ack.payload in seqs):
                        return True
                left = until - time.monotonic()
                if left <= 0:
                    return False
                self.ack_cond.wait(left)

    def unicast(self, dst: int, action: Action, payload: Any = None, raw: Any = None) -> bool:
        """Send and block until ACKed (or retries run out: the drone is dropped)."""
        if dst in self.dropped:
            return False
        self.sent.append([action.name, dst])
        with self.ack_cond:
            since = len(self.acks)  # only ACKs that arrive after sending count
        seq = self.next_seq()
        data = raw(seq) if callable(raw) else encode(Message(dst, MANAGER_ID, seq, action, payload))
        retries = 1 if "give-up-after-two" in self.faults else self.args.retries
        seqs = {seq}
        self.sock.sendto(data, self.send_to)
        log(f"sent {action.name} seq {seq} to {dst}")
        for _ in range(retries):
            if self._acked(dst, seqs, time.monotonic() + self.args.rto, since):
                return True
            if "rtx-new-seq" in self.faults:
                seq = self.next_seq()
                seqs.add(seq)
                data = encode(Message(dst, MANAGER_ID, seq, action, payload))
            self.sock.sendto(data, self.send_to)
        if self._acked(dst, seqs, time.monotonic() + self.args.rto, since):
            return True
        log(f"drone {dst} never ACKed {action.name}: dropped")
        self.dropped.add(dst)
        return False

    # ------------------------------------------------------------------ payloads
    def list_datagram(self, action: Action, dst: int, items: tuple[Any, ...]) -> Any:
        def build(seq: int) -> bytes:
            its = list(items)
            if action == Action.WP_LIST and "out-of-order" in self.faults:
                its.reverse()
            if action == Action.WP_LIST and "field-changed" in self.faults and len(its) > 1:
                its[1] = its[1]._replace(z=its[1].z + 1.0)
            count = len(its) + (1 if "wrong-count" in self.faults else 0)
            head = (_U16LE if "le-count" in self.faults else _U16BE).pack(count)
            return build_datagram(dst, MANAGER_ID, seq, int(action), head + b"".join(ITEM.pack(*it) for it in its))
        return build

    # ------------------------------------------------------------------ mission
    def challenge(self, d: int) -> None:
        c = self.args.challenge
        if c == 1:
            self.unicast(d, Action.WP_LIST, raw=self.list_datagram(Action.WP_LIST, d, self.waypoints))
        elif c == 3:
            self.unicast(d, Action.OBSTACLES_LIST, raw=self.list_datagram(Action.OBSTACLES_LIST, d, self.obstacles))

    def run(self) -> int:
        rx = threading.Thread(target=self.receive_loop, daemon=True)
        rx.start()
        log(f"listening on {self.args.bind}, sending to {self.args.send_to}, drones {self.drones}")
        while not self.ready_event.wait(0.1):
            if self.stop.is_set():
                return 0
        log(f"ready: {self.ready}")
        if "no-wait-start-ack" in self.faults:
            for d in self.drones:
                t = threading.Thread(target=self.unicast, args=(d, Action.START_MISSION))
                t.start()
                time.sleep(0.02)
                self.challenge(d)
                t.join()
        else:
            for d in self.drones:
                self.unicast(d, Action.START_MISSION)
            if self.args.challenge == 2:
                for wp in self.waypoints:
                    for d in self.drones:
                        if "wp-off-first" in self.faults and wp is self.waypoints[0]:
                            self.unicast(d, Action.WP_OFF)
                        self.unicast(d, Action.WP_ON, wp)
                    for d in self.drones:
                        self.unicast(d, Action.WP_OFF)
            else:
                for d in self.drones:
                    self.challenge(d)
        for d in self.drones:
            self.unicast(d, Action.END_MISSION)
        if "after-end" in self.faults:
            self.unicast(self.drones[0], Action.WP_OFF)
        log(f"mission complete; dropped {sorted(self.dropped)}")
        self.stop.set()
        return 1 if self.dropped else 0


def main() -> int:
    p = argparse.ArgumentParser(description="An independent MCP Mission Manager with fault knobs.")
    p.add_argument("--challenge", type=int, choices=(1, 2, 3), required=True)
    p.add_argument("--drones", required=True)
    p.add_argument("--waypoints", required=True)
    p.add_argument("--obstacles")
    p.add_argument("--bind", required=True)
    p.add_argument("--send-to", required=True)
    p.add_argument("--rto", type=float, default=5.0)
    p.add_argument("--retries", type=int, default=1000)
    p.add_argument("--ack-socket", choices=("same", "other"), default="same")
    p.add_argument("--ack-to", choices=("send-to", "source"), default="send-to",
                   help="where ACKs go: --send-to, or the source address of the datagram ACKed")
    p.add_argument("--record", default=None, metavar="FILE",
                   help="write what it sent (JSON: sent as [action, drone], ready, outcome) on exit")
    p.add_argument("--fault", action="append", default=[], choices=sorted(FAULTS))
    p.add_argument("--copy-ack-delay", type=float, default=0.0, metavar="S",
                   help="the ACK of a copy of a message it already ACKed leaves S seconds late (correct: "
                        "ACKed again, however late; receiving is not blocked)")
    p.add_argument("--read-delay", type=float, default=0.0, metavar="S",
                   help="seconds each malformed datagram costs it to read (a slow but correct reader)")
    args = p.parse_args()
    try:
        mgr = SampleManager(args)
    except OSError as exc:
        print(f"sample_manager: error: {exc}", file=sys.stderr)
        return 2

    def stop(signum: int, frame: Any) -> None:
        mgr.stop.set()
        raise SystemExit(0)
    signal.signal(signal.SIGTERM, stop)
    code = None
    try:
        code = mgr.run()
        return code
    except KeyboardInterrupt:
        return 0
    finally:
        if args.record:
            import json

            outcome = ("end_mission" if code == 0 else "drone_failed" if mgr.dropped else "stopped")
            Path(args.record).write_text(json.dumps({"role": "manager", "outcome": outcome, "sent": mgr.sent,
                                                     "ready": list(mgr.ready),
                                                     "failed": sorted(mgr.dropped)}) + "\n")


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env python3
"""An independent drone-role MCP node, written after the description's sample program.

It does not import ``reference_impl``: it exists to prove the conformance runner against a
node it has never seen. It uses ``spec.codec`` for the wire format and pymavlink for the
autopilot, and follows the description's "Main module" steps: connect to the autopilot,
wait for a 3D GPS fix, send Mission_Ready to ID 0 (retransmitted until ACKed), then
receive messages until End_Mission, arming and taking off only on Start_Mission.

Without ``--fault`` the node is correct. Each ``--fault NAME`` breaks exactly one rule of
MCP-REQUIREMENTS (see ``FAULTS``); everything else the node does stays the same.

    python tests/conformance/nodes/sample_node.py --id 1 --bind 127.0.0.1:7890 \
        --send-to 127.0.0.1:7889 [--mavlink tcp:127.0.0.1:5760] [--rto 5] [--retries 1000] \
        [--ack-mode thread|recv-loop] [--reply-to-source] [--no-passthrough] [--rtl-refused] \
        [--busy-start S] [--fault NAME ...]

Every event is one line on stderr. Exit codes: 0 after End_Mission (once it has kept
ACKing for 2 x rto) or on SIGTERM/SIGINT; 2 on a usage or autopilot-connection error;
3 and 4 only for the ``crash-on-short`` and ``crash-on-big`` faults.
"""

from __future__ import annotations

import argparse
import os
import queue
import random
import signal
import socket
import struct
import sys
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any

_ROOT = Path(__file__).resolve().parents[3]
if str(_ROOT) not in sys.path:  # run as a script: make the project's ``spec`` importable
    sys.path.insert(0, str(_ROOT))

from mcp_conform.spec.codec import (  # noqa: E402
    BROADCAST_ID,
    HEADER_SIZE,
    MANAGER_ID,
    PREAMBLE,
    Action,
    DecodeError,
    Message,
    build_datagram,
    decode,
    peek_header,
)

#: fault name -> (rule it violates, what it does)
FAULTS: dict[str, tuple[str, str]] = {
    "bad-preamble": ("MCP-HDR-1", "every datagram it sends has preamble last byte 0x02"),
    "header-little-endian": ("MCP-HDR-2", "every datagram it sends has its header fields dst, src, seq and "
                                          "action little-endian ('<4H')"),
    "mission-ready-wrong-src": ("MCP-HDR-4", "Mission_Ready's src is id+1 (ACKs keep the right src)"),
    "send-action-9": ("MCP-HDR-3", "after Start_Mission, sends one 17-byte datagram with action 9 to ID 0"),
    "send-wp-list": ("MCP-HDR-5", "after Start_Mission, sends one WP_List (count 0) unicast to ID 0"),
    "ack-broadcast": ("MCP-ACK-4", "ACKs broadcast messages"),
    "ack-other-id": ("MCP-ACK-5", "ACKs unicasts addressed to any ID (with its own src)"),
    "ack-ack": ("MCP-ACK-6", "ACKs ACKs addressed to it"),
    "ack-little-endian": ("MCP-ACK-2", "ACK payload packed little-endian ('<H')"),
    "ack-wrong-dst": ("MCP-ACK-3", "ACK dst is 0x0FFF"),
    "ack-to-manager": ("MCP-ACK-3", "ACK dst is always 0, the manager's ID, whatever the message's src "
                                    "(right only for the manager's messages)"),
    "ack-own-seq": ("MCP-ACK-2", "ACK payload is the node's own sequence number (the ACK's own seq, big-endian)"),
    "ack-previous-seq": ("MCP-ACK-2", "ACK payload is the seq of the message it ACKed before (0 at first)"),
    "ack-zero": ("MCP-ACK-2", "ACK payload is always 00 00"),
    "ack-first-copy-only": ("MCP-ACK-1", "a duplicate copy is neither delivered nor ACKed"),
    "ack-copies-wrong-seq": ("MCP-ACK-2", "a retransmitted copy is ACKed with the seq plus 1 (the first copy right)"),
    "slow-ack": ("MCP-ACK-7", "every ACK leaves 300 ms late (receiving is not blocked)"),
    "seq-no-wrap": ("MCP-SEQ-3", "a seq <= the last delivered from that src (plain integers) is a duplicate"),
    "rtx-new-seq": ("MCP-SEQ-2", "each retransmission takes a new seq (an ACK of any of them stops it)"),
    "no-dup-discard": ("MCP-DUP-1", "duplicates are delivered again"),
    "dup-by-content": ("MCP-DUP-2", "a message equal in action and payload to the previous one from that "
                                    "src is discarded whatever its seq"),
    "dup-ignores-src": ("MCP-DUP-3", "one global last-seq instead of one per src"),
    "rtx-stop-on-any-ack": ("MCP-RTX-2", "any ACK addressed to it stops the retransmission"),
    "rtx-none": ("MCP-RTX-1", "Mission_Ready is sent once, never retransmitted"),
    "rtx-storm": ("MCP-RTX-3", "retransmits every 10 ms (bounded by --retries)"),
    "arm-early": ("MCP-BLK-4", "arms as soon as the fix is present, before Mission_Ready"),
    "arm-before-fix": ("MCP-BLK-4", "asks the autopilot to arm right after connecting, before the fix "
                                    "(refused: PreArm: Need 3D Fix)"),
    "arm-before-start": ("MCP-BLK-4", "asks the autopilot to arm once Mission_Ready is ACKed, before "
                                      "Start_Mission (accepted)"),
    "ready-without-fix": ("MCP-BLK-5", "sends Mission_Ready without waiting for the GPS fix"),
    "no-rtl": ("MCP-BLK-7", "no RTL on End_Mission"),
    "ready-bad-payload": ("MCP-PAY-2", "Mission_Ready carries 4 bytes"),
    "passthrough-twice": ("MCP-PAY-8", "each delivered Mav_Passthrough frame is written twice"),
    "passthrough-truncated": ("MCP-PAY-8", "each delivered Mav_Passthrough frame is written without its "
                                           "last 3 bytes"),
    "passthrough-corrupt": ("MCP-PAY-8", "each delivered Mav_Passthrough frame is written with one payload "
                                         "bit flipped (CRC unchanged)"),
    "crash-on-short": ("MCP-ROB-1", "exits with code 3 on a datagram shorter than 17 bytes"),
    "ack-bad-preamble": ("MCP-ROB-2", "ignores the preamble when parsing, and ACKs"),
    "ack-unknown-action": ("MCP-ROB-3", "ACKs action codes above 8"),
    "ack-bad-length": ("MCP-ROB-4", "ACKs unicasts whose payload does not fit their action"),
    "crash-on-big": ("MCP-ROB-6", "exits with code 4 on a datagram larger than 8192 bytes"),
    "hang-on-big": ("MCP-ROB-6", "stops receiving for 30 s after a datagram larger than 8192 bytes"),
    "flood-hang": ("MCP-ROB-7", "after 5000 malformed datagrams stops ACKing for 30 s"),
    "ready-to-wrong-id": ("MCP-FLOW-1", "Mission_Ready's dst is 5 instead of 0"),
    "source-port-filter": ("MCP-TRN-2", "drops datagrams whose source address is not --send-to"),
    # faults a clean link hides and a bad one shows (mcp-soak, issue 22)
    "dup-forgets-on-reorder": ("MCP-DUP-1", "remembers only the last seq per src: a late copy of an older "
                                            "message, overtaken by a newer one, is delivered again"),
    "dup-key-content": ("MCP-DUP-1", "a duplicate is a message whose action and payload equal the last "
                                     "delivered from that src (seq never looked at): a late copy of an older "
                                     "one is delivered again"),
    "rtx-gives-up": ("MCP-RTX-1", "each unicast is sent twice at most, then given up (Mission_Ready too): fewer than MCP-RTX-1's 3 copies"),
    "ack-before-accept": ("MCP-ACK-1", "ACKs a command as it arrives, but drops it unread while its own "
                                       "Mission_Ready is unACKed (the ACK promised a delivery)"),
}

BAD_PREAMBLE = PREAMBLE[:-1] + b"\x02"
RECV_BUFFER = 65535
POLL = 0.05
FIX_3D = 3
TAKEOFF_ALT = 10.0
GUIDED, RTL = 4, 6  # ArduCopter custom modes
SLOW_ACK_DELAY = 0.3
STORM_INTERVAL = 0.01
FLOOD_HANG_AFTER = 5000
FLOOD_HANG_FOR = 30.0
CRASH_BIG_ABOVE = 8192
DUP_WINDOW = 64  # seqs remembered per src for duplicate discard
GIVE_UP_AFTER = 2  # copies of a unicast under the rtx-gives-up fault (MCP-RTX-1 asks for 3)

_log_lock = threading.Lock()
_t0 = time.monotonic()


def log(text: str) -> None:
    with _log_lock:
        try:
            sys.stderr.write(f"[sample_node {time.monotonic() - _t0:8.3f}] {text}\n")
            sys.stderr.flush()
        except (OSError, ValueError):
            pass


def hostport(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT, got {text!r}")
    return host or "0.0.0.0", int(port)


# ============================================================== autopilot (pymavlink)
class LinkLost(Exception):
    """The autopilot closed the TCP connection."""


def _link_lost(*_args: Any) -> None:
    raise LinkLost("the autopilot closed the connection")


class Autopilot:
    """One worker thread owns the pymavlink connection: it reads telemetry (fix, heartbeat,
    COMMAND_ACK) between jobs and runs the jobs in order (start, arm, forward, rtl)."""

    def __init__(self, url: str) -> None:
        from pymavlink import mavutil

        self.mavutil = mavutil
        self.mav = mavutil.mavlink
        self.conn = mavutil.mavlink_connection(url, source_system=255, source_component=190,
                                               autoreconnect=False, retries=2)
        # pymavlink prints and spins on EOF when the peer goes away: make it one exception.
        for hook in ("handle_eof", "handle_disconnect"):
            if hasattr(self.conn, hook):
                setattr(self.conn, hook, _link_lost)
        self.fix = threading.Event()
        self.lost = False
        self.acks: dict[int, int] = {}
        self.jobs: queue.Queue[tuple[str, Any, threading.Event]] = queue.Queue()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, name="autopilot", daemon=True)
        self.thread.start()

    def submit(self, kind: str, arg: Any = None) -> threading.Event:
        done = threading.Event()
        self.jobs.put((kind, arg, done))
        return done

    def close(self) -> None:
        self.stop.set()
        self.thread.join(timeout=3.0)
        try:
            self.conn.close()
        except Exception:  # noqa: BLE001
            pass

    # ---------------------------------------------------------------- worker
    def _run(self) -> None:
        while not self.stop.is_set():
            try:
                kind, arg, done = self.jobs.get_nowait()
            except queue.Empty:
                self._pump(POLL)
                continue
            try:
                if self.lost:
                    log(f"autopilot link lost: job {kind} not done")
                else:
                    getattr(self, "_job_" + kind)(arg)
            except LinkLost as exc:
                self.lost = True
                log(f"autopilot link lost: {exc}")
            except Exception as exc:  # noqa: BLE001 - a MAVLink failure must not stop the node
                log(f"autopilot job {kind} failed: {exc!r}")
            finally:
                done.set()
        while True:
            try:
                self.jobs.get_nowait()[2].set()
            except queue.Empty:
                break

    def _pump(self, wait: float) -> None:
        if self.lost:
            self.stop.wait(wait)
            return
        try:
            msg = self.conn.recv_match(blocking=True, timeout=wait)
            while msg is not None:
                self._observe(msg)
                msg = self.conn.recv_match(blocking=False)
        except LinkLost as exc:
            self.lost = True
            log(f"autopilot link lost: {exc}")
        except Exception as exc:  # noqa: BLE001
            log(f"autopilot read error: {exc!r}")
            self.stop.wait(0.2)

    def _observe(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "GPS_RAW_INT":
            if msg.fix_type >= FIX_3D and not self.fix.is_set():
                log(f"GPS 3D fix (fix_type {msg.fix_type})")
                self.fix.set()
        elif kind == "COMMAND_ACK":
            self.acks[int(msg.command)] = int(msg.result)

    def _wait_ack(self, command: int, timeout: float) -> int | None:
        deadline = time.monotonic() + timeout
        while command not in self.acks and not self.stop.is_set():
            left = deadline - time.monotonic()
            if left <= 0:
                break
            self._pump(min(POLL, left))
        return self.acks.get(command)

    def _command(self, command: int, send: Any, label: str) -> bool:
        for _ in range(3):
            self.acks.pop(command, None)
            send()
            result = self._wait_ack(command, 1.0)
            if result is not None:
                ok = result == self.mav.MAV_RESULT_ACCEPTED
                log(f"autopilot: {label} {'accepted' if ok else f'refused (result {result})'}")
                return ok
        log(f"autopilot: {label}: no COMMAND_ACK")
        return False

    def _job_start(self, _arg: Any) -> None:
        """Start_Mission: GUIDED, arm, take off to 10 m (the description's step 6)."""
        c = self.conn
        self._command(self.mav.MAV_CMD_DO_SET_MODE, lambda: c.set_mode_apm(GUIDED), "mode GUIDED")
        if self._job_arm(None):
            self._command(self.mav.MAV_CMD_NAV_TAKEOFF, lambda: c.mav.command_long_send(
                c.target_system, c.target_component, self.mav.MAV_CMD_NAV_TAKEOFF, 0,
                0, 0, 0, 0, 0, 0, TAKEOFF_ALT), f"takeoff to {TAKEOFF_ALT:.0f} m")

    def _job_arm(self, _arg: Any) -> bool:
        return self._command(self.mav.MAV_CMD_COMPONENT_ARM_DISARM, self.conn.arducopter_arm, "arm")

    def _job_noop(self, _arg: Any) -> None:
        """A marker: done once every job queued before it is done."""

    def _job_forward(self, frame: bytes) -> None:
        self.conn.write(frame)
        log(f"autopilot: wrote a {len(frame)}-byte passthrough frame")

    def _job_rtl_refused(self, _arg: Any) -> None:
        """RTL asked for with a SET_MODE whose base_mode lacks the custom-mode flag: the
        autopilot refuses it (ArduPilot maps only custom modes); no retry."""
        c = self.conn
        self._command(11, lambda: c.mav.set_mode_send(c.target_system, 0, RTL), "mode RTL (no custom-mode flag)")

    def _job_rtl(self, _arg: Any) -> None:
        if not self._command(self.mav.MAV_CMD_NAV_RETURN_TO_LAUNCH, self.conn.set_mode_rtl, "RTL"):
            self._command(self.mav.MAV_CMD_DO_SET_MODE, lambda: self.conn.set_mode_apm(RTL), "mode RTL")


# ============================================================== the MCP node
class Waiter:
    """A unicast message of ours awaiting its ACK."""

    def __init__(self, seq: int, ack_src: int, action: int) -> None:
        self.seqs = {seq}
        self.ack_src = ack_src
        self.action = action
        self.event = threading.Event()


class Node:
    def __init__(self, args: argparse.Namespace) -> None:
        self.id: int = args.id
        self.faults: set[str] = set(args.fault)
        self.rto: float = args.rto
        self.retries: int = args.retries
        self.send_to = args.send_to
        self.recv_loop = args.ack_mode == "recv-loop"
        self.reply_to_source: bool = args.reply_to_source
        self.passthrough = not args.no_passthrough
        self.rtl_refused: bool = args.rtl_refused
        self.read_delay = args.read_delay
        self.busy_start = args.busy_start if args.busy_start is not None else (1.0 if self.recv_loop else 0.0)
        self.mavlink_url: str | None = args.mavlink
        self.stop = threading.Event()
        self.preamble = BAD_PREAMBLE if "bad-preamble" in self.faults else PREAMBLE

        self._seq = random.randrange(65536)  # arbitrary initial number (MCP-SEQ-4)
        self._seq_lock = threading.Lock()
        self._waiters: list[Waiter] = []
        self._waiters_lock = threading.Lock()
        self.last_seq: dict[Any, int] = {}  # per src (one global key under dup-ignores-src)
        self.last_content: dict[int, tuple[int, bytes]] = {}
        #: the last DUP_WINDOW seqs delivered per src: a late copy of an older one is a
        #: duplicate too (MCP-DUP-4 leaves it open; exactly-once on a reordering link needs it)
        self.recent: dict[Any, deque[int]] = {}
        #: set by the thread that reads datagrams as the ACK arrives (the sending thread learns
        #: it a scheduling delay later: the ack-before-accept fault read that and raced)
        self.ready_acked = False
        self.linger: float | None = args.linger
        self.record_path: str | None = args.record
        self.deliveries: list[list[Any]] = []
        self.outcome = "running"
        self.inbox: queue.Queue[Message] = queue.Queue()
        self.malformed = 0
        self.deaf_until = 0.0
        self.previous_acked = 0  # ack-previous-seq: the seq its last ACK acknowledged
        self.started = False
        self.ended = False
        self.autopilot: Autopilot | None = None
        self._delayed: queue.Queue[tuple[float, bytes, Any]] = queue.Queue()
        self._threads: list[threading.Thread] = []

        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_BROADCAST, 1)
        try:
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        except OSError:
            pass
        self.sock.bind(args.bind)
        self.sock.settimeout(POLL)
        host, port = self.sock.getsockname()[:2]
        log(f"id {self.id} listening on {host}:{port}, sending to {self.send_to[0]}:{self.send_to[1]}, "
            f"ack-mode {args.ack_mode}, rto {self.rto}, faults {sorted(self.faults) or 'none'}")

    # ---------------------------------------------------------------- sending
    def next_seq(self) -> int:
        with self._seq_lock:
            self._seq = (self._seq + 1) & 0xFFFF
            return self._seq

    def datagram(self, dst: int, src: int, seq: int, action: int, payload: bytes = b"") -> bytes:
        if "header-little-endian" in self.faults:
            return self.preamble + struct.pack("<4H", dst, src, seq, int(action)) + payload
        return build_datagram(dst, src, seq, action, payload, preamble=self.preamble)

    def sendto(self, data: bytes, addr: Any) -> None:
        try:
            self.sock.sendto(data, addr)
        except OSError as exc:
            log(f"send to {addr} failed: {exc}")

    def send_ack(self, dst: int, acked_seq: int, addr: Any, copy: bool = False) -> None:
        seq = self.next_seq()  # ACKs take a number too (D-5)
        named = acked_seq
        if copy and "ack-copies-wrong-seq" in self.faults:
            named = (acked_seq + 1) & 0xFFFF
        elif "ack-own-seq" in self.faults:
            named = seq
        elif "ack-previous-seq" in self.faults:
            named, self.previous_acked = self.previous_acked, acked_seq
        elif "ack-zero" in self.faults:
            named = 0
        payload = struct.pack("<H" if "ack-little-endian" in self.faults else "!H", named)
        if "ack-wrong-dst" in self.faults:
            dst = 0x0FFF
        elif "ack-to-manager" in self.faults:
            dst = MANAGER_ID
        data = self.datagram(dst, self.id, seq, Action.ACK, payload)
        target = addr if self.reply_to_source else self.send_to
        log(f"ACK seq {acked_seq} to ID {dst} (own seq {seq})")
        if "slow-ack" in self.faults:
            self._delayed.put((time.monotonic() + SLOW_ACK_DELAY, data, target))
        else:
            self.sendto(data, target)

    def _delay_line(self) -> None:
        while True:
            try:
                due, data, addr = self._delayed.get(timeout=POLL)
            except queue.Empty:
                if self.stop.is_set():
                    return
                continue
            time.sleep(max(0.0, due - time.monotonic()))
            self.sendto(data, addr)

    def send_unicast(self, action: int, payload: bytes, dst: int, *, src: int | None = None,
                     ack_src: int | None = None) -> bool:
        """Send and retransmit every rto with the same seq and bytes until the right ACK."""
        src = self.id if src is None else src
        seq = self.next_seq()
        waiter = Waiter(seq, dst if ack_src is None else ack_src, action)
        with self._waiters_lock:
            self._waiters.append(waiter)
        interval = STORM_INTERVAL if "rtx-storm" in self.faults else self.rto
        name = Action(action).name
        try:
            data = self.datagram(dst, src, seq, action, payload)
            retries = min(self.retries, GIVE_UP_AFTER - 1) if "rtx-gives-up" in self.faults else self.retries
            for copy in range(1 + max(0, retries)):
                if copy and "rtx-new-seq" in self.faults:
                    seq = self.next_seq()
                    with self._waiters_lock:
                        waiter.seqs.add(seq)
                    data = self.datagram(dst, src, seq, action, payload)
                self.sendto(data, self.send_to)
                log(f"sent {name} seq {seq} to ID {dst} (copy {copy + 1})")
                if "rtx-none" in self.faults:
                    log(f"{name}: not retransmitting (fault rtx-none)")
                    return False
                if self.wait_for(waiter.event, interval):
                    log(f"{name} seq {seq} ACKed")
                    return True
                if self.stop.is_set():
                    return False
            log(f"{name}: no ACK after {retries} retries, giving up")
            return False
        finally:
            with self._waiters_lock:
                self._waiters.remove(waiter)

    # ---------------------------------------------------------------- receiving
    def pump(self, deadline: float, until: Any = None) -> None:
        """Receive and process datagrams until ``deadline`` or ``until()`` holds."""
        while not self.stop.is_set():
            if until is not None and until():
                return
            left = deadline - time.monotonic()
            if left <= 0:
                return
            self.sock.settimeout(min(POLL, left))
            try:
                data, addr = self.sock.recvfrom(RECV_BUFFER)
            except (TimeoutError, BlockingIOError, InterruptedError):
                continue
            except OSError as exc:
                if self.stop.is_set():
                    return
                log(f"receive error: {exc}")
                continue
            self.on_datagram(data, addr)

    def wait_for(self, event: threading.Event, timeout: float) -> bool:
        """Wait for an event set by datagram processing (thread mode: the receiver thread;
        recv-loop mode: processing happens here, inside the wait)."""
        deadline = time.monotonic() + timeout
        if self.recv_loop:
            self.pump(deadline, event.is_set)
            return event.is_set()
        while not self.stop.is_set():
            left = deadline - time.monotonic()
            if left <= 0 or event.wait(min(POLL, left)):
                break
        return event.is_set()

    def _receiver(self) -> None:
        self.pump(float("inf"))

    def recv_message(self, timeout: float) -> Message | None:
        if self.recv_loop and self.inbox.empty():
            self.pump(time.monotonic() + timeout, lambda: not self.inbox.empty())
            timeout = 0
        try:
            return self.inbox.get(timeout=timeout) if timeout > 0 else self.inbox.get_nowait()
        except queue.Empty:
            return None

    def on_datagram(self, data: bytes, addr: Any) -> None:
        n = len(data)
        if "source-port-filter" in self.faults and tuple(addr[:2]) != tuple(self.send_to):
            log(f"dropped a {n}-byte datagram from {addr[0]}:{addr[1]} (fault source-port-filter)")
            return
        if "crash-on-short" in self.faults and n < HEADER_SIZE:
            log(f"crashing on a {n}-byte datagram (fault crash-on-short)")
            os._exit(3)
        if "crash-on-big" in self.faults and n > CRASH_BIG_ABOVE:
            log(f"crashing on a {n}-byte datagram (fault crash-on-big)")
            os._exit(4)
        if "hang-on-big" in self.faults and n > CRASH_BIG_ABOVE:
            self.deaf_until = time.monotonic() + FLOOD_HANG_FOR
            log(f"hanging for {FLOOD_HANG_FOR:.0f} s after a {n}-byte datagram (fault hang-on-big)")
            return
        if self.deaf_until and time.monotonic() < self.deaf_until:
            return
        try:
            msg = decode(data)
        except DecodeError as exc:
            self.on_malformed(data, addr, exc)
            if self.read_delay:  # a slow reader (correct): each malformed datagram costs it time
                time.sleep(self.read_delay)
            return
        if msg.action == Action.ACK:
            if msg.dst == self.id or ("mission-ready-wrong-src" in self.faults and msg.dst == self.id + 1):
                self.on_ack(msg)
                if "ack-ack" in self.faults and msg.dst == self.id:
                    self.send_ack(msg.src, msg.seq, addr)
            return
        if msg.dst == BROADCAST_ID:
            if "ack-broadcast" in self.faults:
                self.send_ack(msg.src, msg.seq, addr)
            self.offer(msg, data, broadcast=True)
            return
        if msg.dst != self.id:
            if "ack-other-id" in self.faults:
                self.send_ack(msg.src, msg.seq, addr)
            return
        if "ack-before-accept" in self.faults and not self.ready_acked:
            self.send_ack(msg.src, msg.seq, addr)
            log(f"{msg.action.name} seq {msg.seq} ACKed but dropped: Mission_Ready not ACKed yet "
                "(fault ack-before-accept)")
            return
        dup = self.is_duplicate(msg, data)
        if dup and "ack-first-copy-only" in self.faults:
            log(f"duplicate {msg.action.name} seq {msg.seq} from {msg.src}: not ACKed (fault ack-first-copy-only)")
            return
        self.send_ack(msg.src, msg.seq, addr, copy=dup)
        if dup:
            log(f"duplicate {msg.action.name} seq {msg.seq} from {msg.src}: not delivered")
            return
        self.offer(msg, data)

    def on_malformed(self, data: bytes, addr: Any, exc: DecodeError) -> None:
        self.malformed += 1
        if self.malformed <= 20 or self.malformed % 1000 == 0:
            log(f"malformed datagram #{self.malformed} ({len(data)} bytes): {exc}")
        if "flood-hang" in self.faults and self.malformed == FLOOD_HANG_AFTER:
            self.deaf_until = time.monotonic() + FLOOD_HANG_FOR
            log(f"hanging for {FLOOD_HANG_FOR:.0f} s after {FLOOD_HANG_AFTER} malformed datagrams (fault flood-hang)")
        header = None
        if exc.rule == "MCP-ROB-2" and "ack-bad-preamble" in self.faults:
            try:
                fixed = decode(PREAMBLE + bytes(data[len(PREAMBLE):]))
            except DecodeError:
                fixed = None
            if fixed is not None:
                header = (fixed.dst, fixed.src, fixed.seq, int(fixed.action))
        elif exc.rule == "MCP-ROB-3" and "ack-unknown-action" in self.faults:
            header = peek_header(data)
        elif exc.rule == "MCP-ROB-4" and "ack-bad-length" in self.faults:
            header = peek_header(data)
        if header is not None:
            dst, src, seq, action = header
            if dst == self.id and action != Action.ACK:
                log(f"ACKing a malformed datagram ({exc.rule} fault)")
                self.send_ack(src, seq, addr)

    def on_ack(self, msg: Message) -> None:
        with self._waiters_lock:
            waiters = list(self._waiters)
        for w in waiters:
            if "rtx-stop-on-any-ack" in self.faults or (msg.src == w.ack_src and msg.payload in w.seqs):
                if w.action == Action.MISSION_READY:
                    self.ready_acked = True
                w.event.set()
                return
        log(f"ignored ACK of seq {msg.payload} from ID {msg.src}")

    def _dup_key(self, msg: Message) -> Any:
        return "all" if "dup-ignores-src" in self.faults else msg.src

    def is_duplicate(self, msg: Message, data: bytes) -> bool:
        if "no-dup-discard" in self.faults:
            return False
        if "dup-key-content" in self.faults:
            return self.last_content.get(msg.src) == (int(msg.action), bytes(data[HEADER_SIZE:]))
        last = self.last_seq.get(self._dup_key(msg))
        if last is not None:
            if "seq-no-wrap" in self.faults:
                if msg.seq <= last:
                    return True
            elif msg.seq == last:
                return True
        recent = self.recent.get(self._dup_key(msg))
        if recent is not None and msg.seq in recent and not (
                self.faults & {"dup-forgets-on-reorder", "seq-no-wrap"}):
            return True
        if "dup-by-content" in self.faults:
            return self.last_content.get(msg.src) == (int(msg.action), bytes(data[HEADER_SIZE:]))
        return False

    def offer(self, msg: Message, data: bytes, broadcast: bool = False) -> None:
        """Duplicate check for broadcasts, then remember and deliver."""
        if broadcast and self.is_duplicate(msg, data):
            log(f"duplicate broadcast {msg.action.name} seq {msg.seq} from {msg.src}: not delivered")
            return
        self.last_seq[self._dup_key(msg)] = msg.seq
        self.recent.setdefault(self._dup_key(msg), deque(maxlen=DUP_WINDOW)).append(msg.seq)
        self.last_content[msg.src] = (int(msg.action), bytes(data[HEADER_SIZE:]))
        if self.ended:
            log(f"{msg.action.name} seq {msg.seq} after End_Mission: ignored")
            return
        self.deliveries.append([msg.action.name, msg.src, msg.seq])  # the delivery log (--record)
        self.inbox.put(msg)

    # ---------------------------------------------------------------- handlers
    def handle(self, msg: Message) -> None:
        a = msg.action
        log(f"delivered {a.name} seq {msg.seq} from ID {msg.src}")
        if a == Action.START_MISSION:
            self.handle_start_mission()
        elif a == Action.END_MISSION:
            self.handle_end_mission()
        elif a in (Action.WP_LIST, Action.OBSTACLES_LIST):
            what = "waypoint" if a == Action.WP_LIST else "obstacle"
            for i, item in enumerate(msg.payload):
                log(f"{what} ({i}): lat {item.x:f} lon {item.y:f} alt {item.z:f}")
            log(f"{a.name}: {len(msg.payload)} {what}s")
        elif a == Action.WP_ON:
            p = msg.payload
            log(f"WP_On: lat {p.x:f} lon {p.y:f} alt {p.z:f}")
        elif a == Action.WP_OFF:
            log("WP_Off: the active waypoint is now inactive")
        elif a == Action.MAV_PASSTHROUGH:
            self.handle_mav_passthrough(msg.payload)
        else:
            log(f"{a.name}: nothing to do")

    def handle_start_mission(self) -> None:
        if self.started:
            log("Start_Mission again: already flying")
            return
        self.started = True
        if self.autopilot is not None:
            self.autopilot.submit("start")
        else:
            log("no autopilot: would set GUIDED, arm and take off")
        if self.busy_start > 0:
            log(f"climbing: busy for {self.busy_start:.2f} s")
            self.stop.wait(self.busy_start)
        if "send-action-9" in self.faults:
            self.sendto(self.datagram(MANAGER_ID, self.id, self.next_seq(), 9), self.send_to)
            log("sent a datagram with action code 9 to ID 0 (fault send-action-9)")
        if "send-wp-list" in self.faults:
            t = threading.Thread(target=self.send_unicast, args=(Action.WP_LIST, b"\x00\x00", MANAGER_ID),
                                 name="wp-list", daemon=True)
            t.start()
            self._threads.append(t)

    def handle_end_mission(self) -> None:
        self.ended = True
        if "no-rtl" in self.faults:
            log("End_Mission: no RTL (fault no-rtl)")
        elif self.autopilot is not None:
            self.autopilot.submit("rtl_refused" if self.rtl_refused else "rtl")
        else:
            log("no autopilot: would RTL")

    def handle_mav_passthrough(self, frame: bytes) -> None:
        if not self.passthrough:
            log(f"Mav_Passthrough of {len(frame)} bytes: not forwarded (--no-passthrough)")
            return
        if self.autopilot is None:
            log(f"Mav_Passthrough of {len(frame)} bytes: no autopilot")
            return
        if "passthrough-truncated" in self.faults:
            frame = frame[:-3]
        elif "passthrough-corrupt" in self.faults and len(frame) > 12:
            frame = frame[:11] + bytes([frame[11] ^ 0x01]) + frame[12:]  # a payload byte
        for _ in range(2 if "passthrough-twice" in self.faults else 1):
            self.autopilot.submit("forward", frame)

    # ---------------------------------------------------------------- main
    def run(self) -> int:
        if "slow-ack" in self.faults:
            self._start(self._delay_line, "slow-ack")
        if not self.recv_loop:
            self._start(self._receiver, "receiver")
        if self.mavlink_url:
            try:
                self.autopilot = Autopilot(self.mavlink_url)
            except Exception as exc:  # noqa: BLE001 - pymavlink raises anything
                log(f"cannot connect to the autopilot at {self.mavlink_url}: {exc!r}")
                return 2
            log(f"connected to the autopilot at {self.mavlink_url}")
        if "arm-before-fix" in self.faults and self.autopilot is not None:
            log("asking the autopilot to arm before the fix (fault arm-before-fix)")
            self.autopilot.submit("arm").wait(5.0)
        if "ready-without-fix" in self.faults:
            log("not waiting for the GPS fix (fault ready-without-fix)")
        elif self.autopilot is not None:
            log("waiting for a 3D GPS fix")
            while not self.stop.is_set() and not self.autopilot.fix.wait(POLL):
                pass
        if self.stop.is_set():
            return 0
        if "arm-early" in self.faults and self.autopilot is not None:
            log("arming before Mission_Ready (fault arm-early)")
            self.autopilot.submit("arm").wait(5.0)

        payload = struct.pack("!HH", self.id, 0) if "ready-bad-payload" in self.faults else b""
        src = self.id + 1 if "mission-ready-wrong-src" in self.faults else self.id
        dst = (5 if self.id != 5 else 6) if "ready-to-wrong-id" in self.faults else MANAGER_ID
        self.send_unicast(Action.MISSION_READY, payload, dst, src=src, ack_src=MANAGER_ID)
        if "arm-before-start" in self.faults and self.autopilot is not None and not self.started:
            log("asking the autopilot to arm before Start_Mission (fault arm-before-start)")
            self.autopilot.submit("arm")

        while not self.stop.is_set() and not self.ended:
            msg = self.recv_message(POLL)
            if msg is not None:
                self.handle(msg)
        if self.stop.is_set():
            return 0
        linger = 2 * self.rto if self.linger is None else self.linger
        log(f"End_Mission: still ACKing for {linger:.2f} s")
        if self.recv_loop:
            self.pump(time.monotonic() + linger)
        else:
            self.stop.wait(linger)
        if self.autopilot is not None:  # let RTL (and anything queued before it) reach the autopilot
            self.autopilot.submit("noop").wait(5.0)
        log("mission over: exiting")
        self.outcome = "end_mission"
        return 0

    def _start(self, target: Any, name: str) -> None:
        t = threading.Thread(target=target, name=name, daemon=True)
        t.start()
        self._threads.append(t)

    def write_record(self) -> None:
        """The delivery log (``--record``): what the application was given, in order."""
        if not self.record_path:
            return
        import json

        if self.outcome == "running" and self.ended:
            self.outcome = "end_mission"
        try:
            Path(self.record_path).write_text(json.dumps(
                {"role": "drone", "id": self.id, "outcome": self.outcome, "deliveries": self.deliveries}) + "\n")
        except OSError as exc:
            log(f"cannot write the record: {exc}")

    def close(self) -> None:
        self.write_record()
        self.stop.set()
        for t in self._threads:
            if t is not threading.current_thread():
                t.join(timeout=1.0)
        if self.autopilot is not None:
            self.autopilot.close()
        self.sock.close()


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter,
                                epilog="faults:\n" + "\n".join(f"  {k:24} {r}: {d}" for k, (r, d) in FAULTS.items()))
    p.add_argument("--id", type=int, required=True, help="this drone's MCP ID (1..65534)")
    p.add_argument("--bind", type=hostport, required=True, metavar="HOST:PORT")
    p.add_argument("--send-to", type=hostport, required=True, metavar="HOST:PORT")
    p.add_argument("--mavlink", default=None, metavar="URL",
                   help="pymavlink connection string; without it there is no autopilot and the fix counts as present")
    p.add_argument("--rto", type=float, default=5.0, help="retransmission timeout, s (default 5)")
    p.add_argument("--retries", type=int, default=1000, help="retransmissions before giving up (default 1000)")
    p.add_argument("--ack-mode", choices=("thread", "recv-loop"), default="thread")
    p.add_argument("--reply-to-source", action="store_true", help="ACK to the datagram's source address")
    p.add_argument("--no-passthrough", action="store_true", help="ACK Mav_Passthrough but do not forward it")
    p.add_argument("--rtl-refused", action="store_true",
                   help="on End_Mission, request RTL in a form the autopilot refuses (SET_MODE without the "
                        "custom-mode flag), once: still an RTL request (MCP-BLK-7)")
    p.add_argument("--busy-start", type=float, default=None, metavar="S",
                   help="seconds the Start_Mission handler blocks (default 1.0 in recv-loop mode, else 0)")
    p.add_argument("--read-delay", type=float, default=0.0, metavar="S",
                   help="seconds each malformed datagram costs the receiver (a slow, correct reader)")
    p.add_argument("--linger", type=float, default=None, metavar="S",
                   help="seconds to keep ACKing after End_Mission (default 2 x rto)")
    p.add_argument("--record", default=None, metavar="FILE",
                   help="write the delivery log (JSON: deliveries as [action, src, seq]) on exit")
    p.add_argument("--fault", action="append", default=[], choices=sorted(FAULTS), metavar="NAME")
    args = p.parse_args(argv)
    if not 1 <= args.id <= 0xFFFE:
        p.error("--id must be 1..65534")
    if not args.rto > 0:
        p.error("--rto must be positive")
    return args


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        node = Node(args)
    except OSError as exc:
        log(f"cannot bind {args.bind[0]}:{args.bind[1]}: {exc}")
        return 2

    signalled: list[int] = []

    def on_signal(signum: int, _frame: Any) -> None:
        # no log() here: the handler runs in the main thread, which may be inside log() holding
        # its lock (a loaded host's SIGTERM while "sent MISSION_READY" was being written: the
        # node hung for good). A list append and an Event set take no lock the main thread holds
        signalled.append(signum)
        node.stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        return node.run()
    finally:
        if signalled:
            log(f"signal {signalled[0]}: exiting")
        node.close()


if __name__ == "__main__":
    sys.exit(main())

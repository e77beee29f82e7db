"""Nsqd backends that misbehave whatever they are sent (issue 36 item 2), for the fuzzer's
blame tests (tests/fuzz/test_blame.py): a finding against them is the target's behaviour,
under its rule, with no input blamed.

``--mode slow``: on accept one valid UPDATE at once, then the next UPDATEs one byte a second
(NSQD-MSG-1: "no gap longer than update_gap_max_s"; mcp-conform names it in
MSG/test_update_stream_keeps_its_period). ``--mode stops``: valid UPDATEs every 0.05 s (a fast period) for the first 0.6 s of a
connection, then none (NSQD-MSG-1: a stream that stops). ``--mode bad-frames``: an UPDATE every update
period whose 32-bit length is written little-endian (a missing ``htonl``, E-1), so every
frame it sends breaks NSQD-FRM-1 (mcp-conform: FRM/test_backend_frames_are_well_formed).
Both read and discard whatever a client sends, serve up to ``MAX_CLIENTS`` clients at once
(a thread each) and exit after ``--lifetime`` seconds.

``--mode slow-restart`` (the campaign's bound, ``fuzz.budget``): valid UPDATEs every update
period, and an exit (status 1) at the first byte a client sends; its first start serves at
once, every later one (``--state FILE`` marks the first) sends its first UPDATE only
``--restart-delay`` seconds after it started, so each replay of a triage outlasts the grace.

``--mode flaky-crash`` (environment-dependent naming, issue 36 item 3): valid UPDATEs every
update period; the first two times any of its processes is sent bytes (counted in ``--state
FILE``) it exits (status 1), and never again: the campaign sees it, one replay of triage
reproduces it, the confirming replays do not.

``--mode late-crash`` (a death read late is a death, not a command without its effect): an
UPDATE on accept and every update period; bytes a client sends are read ``LATE_READ_S`` after
they came (a backend held off the CPU), then the process exits (status 1): a fuzzer's FIN and
new connection after a command are served (an UPDATE, the state unchanged) before it dies.

``--mode deaf`` (a lost command is not a lost stream, NSQD-MSG-3 vs NSQD-ROB-3): valid UPDATEs
every update period, the drone grounded whatever it is sent; it reads and discards every byte
(no command takes its effect, with or without a frame cut before it: what flaky-crash's
processes do once its two crashes are spent).

``--mode deaf-to --ignore NAME,NAME`` (a backend that ignores only some commands, NSQD-MSG-3):
valid UPDATEs every update period showing a flight state shared by its connections (GROUNDED
at start), which every whole frame of a command with an effect sets to the first state of its
``to`` (spec/nsqd.yaml's messages table), except the commands named: those it reads and
discards. It checks no body and answers nothing (a test selects NSQD-MSG-3's cases).

``python -m tests.fuzz.servers.misbehaving_backend --bind HOST:PORT --mode slow|stops|bad-frames|slow-restart|flaky-crash|late-crash|deaf|deaf-to
[--lifetime S] [--state FILE --restart-delay S] [--ignore NAME,NAME]``
"""

from __future__ import annotations

import argparse
import contextlib
import os
import select
import socket
import struct
import threading
import time

from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import Deframer, Frame, encode

MAX_CLIENTS = 64
STATE = ""  # --state
#: ``--mode stops``: its fast period, and how long into a connection its stream stops
FAST_PERIOD = 0.05
STOPS_AFTER_S = 0.6
PERIOD = float(NSQD.params["update_period_s"])
LATE_READ_S = 0.5  # --mode late-crash: how long after bytes came they are read (then the exit)
IGNORE: frozenset[str] = frozenset()  # --mode deaf-to: the commands it ignores (--ignore)
FLIGHT = [NSQD.states["GROUNDED"]]  # --mode deaf-to: the flight state, shared by its connections


def update(state: int = NSQD.states["GROUNDED"]) -> bytes:
    """A valid UPDATE (NSQD-MSG-2's layout), the drone grounded (or in ``state``)."""
    return encode(NSQD, "UPDATE", roll=0.0, pitch=0.0, yaw=0.0, thrust=0.0, lat=55.0, lon=10.0, alt=0.0,
                  state=state)


def _deaf_to(c: socket.socket, end: float) -> None:
    """``--mode deaf-to``: each whole command frame not in :data:`IGNORE` sets :data:`FLIGHT`
    to its effect's first state; an UPDATE with it at once and every period."""
    deframer, nxt = Deframer(NSQD), time.monotonic()
    while time.monotonic() < end:
        try:
            data = c.recv(65536)
            if not data:
                return  # the client closed
            for item in deframer.feed(data):
                if isinstance(item, Frame) and NSQD.has_message(item.msg_id):
                    msg = NSQD.message(item.msg_id)
                    if msg.effect.to and msg.name not in IGNORE:
                        FLIGHT[0] = msg.effect.to[0]
        except BlockingIOError:
            pass
        if time.monotonic() >= nxt:
            c.sendall(update(FLIGHT[0]))
            nxt = time.monotonic() + PERIOD
        time.sleep(0.01)


def _drain(c: socket.socket) -> bool:
    """Read and discard what the client sent; False once it closed."""
    try:
        while True:
            data = c.recv(65536)
            if not data:
                return False
    except BlockingIOError:
        return True
    except OSError:
        return False


def serve_client(c: socket.socket, mode: str, end: float, ready: float = 0.0) -> None:
    c.setblocking(False)
    try:
        if mode in ("slow-restart", "flaky-crash"):
            _crash_on_input(c, end, ready, STATE if mode == "flaky-crash" else None)
            return
        if mode == "stops":
            _stop_after(c, end, FAST_PERIOD, STOPS_AFTER_S)
            return
        if mode == "late-crash":
            _read_late(c, end)
            return
        if mode == "deaf-to":
            _deaf_to(c, end)
            return
        if mode == "slow":
            c.sendall(update())
            pending, step = b"", 1.0
        elif mode == "deaf":
            pending, step = b"", PERIOD
            c.sendall(update())
        else:
            pending, step = b"", PERIOD
        nxt = time.monotonic() + step
        while time.monotonic() < end:
            if not _drain(c):
                return
            now = time.monotonic()
            if now >= nxt:
                nxt = now + step
                if mode == "slow":
                    pending = pending or update()
                    c.sendall(pending[:1])
                    pending = pending[1:]
                elif mode == "deaf":
                    c.sendall(update())
                else:
                    frame = update()
                    c.sendall(struct.pack("<I", len(frame)) + frame[4:])  # the length not in network order
            time.sleep(0.02)
    except OSError:
        pass
    finally:
        with contextlib.suppress(OSError):
            c.close()


def _stop_after(c: socket.socket, end: float, period: float, after: float) -> None:
    """UPDATEs every ``period`` for ``after`` s from accept, then none; reads what it is sent."""
    stop, nxt = time.monotonic() + after, time.monotonic()
    while time.monotonic() < end:
        if not _drain(c):
            return
        if nxt <= time.monotonic() < stop:
            c.sendall(update())
            nxt += period
        time.sleep(0.005)


def _read_late(c: socket.socket, end: float) -> None:
    """An UPDATE at once and every period; bytes sent are read :data:`LATE_READ_S` after they
    came, and the process exits on them."""
    nxt, came = time.monotonic(), None
    while time.monotonic() < end:
        now = time.monotonic()
        if came is None and select.select([c], [], [], 0)[0]:
            came = now
        if came is not None and now >= came + LATE_READ_S:
            if c.recv(65536):
                os._exit(1)
            return  # the client closed, sent nothing
        if now >= nxt:
            c.sendall(update())
            nxt = now + PERIOD
        time.sleep(0.01)


def _crash_on_input(c: socket.socket, end: float, ready: float, count: str | None) -> None:
    """UPDATEs every period from ``ready`` on; the process exits at the first byte received
    (with ``count``, a file: only the first two times, over all processes, that bytes came)."""
    nxt = ready
    while time.monotonic() < end:
        try:
            data = c.recv(65536)
            if data and count is not None:
                with open(count, "a+") as f:
                    f.write("x")
                    f.seek(0)
                    times = len(f.read())
                if times <= 2:
                    os._exit(1)
            elif data:
                os._exit(1)
            else:
                return  # the client closed
        except BlockingIOError:
            pass
        if time.monotonic() >= nxt:
            c.sendall(update())
            nxt = max(ready, time.monotonic()) + PERIOD
        time.sleep(0.01)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--bind", required=True)
    ap.add_argument("--mode", choices=("slow", "stops", "bad-frames", "slow-restart", "flaky-crash", "late-crash", "deaf",
                                       "deaf-to"), required=True)
    ap.add_argument("--ignore", default="", help="deaf-to: the commands it ignores, comma-separated")
    ap.add_argument("--lifetime", type=float, default=300.0)
    ap.add_argument("--state", help="slow-restart: marks that the first start happened")
    ap.add_argument("--restart-delay", type=float, default=0.0)
    ns = ap.parse_args()
    global STATE, IGNORE
    STATE = ns.state or ""
    IGNORE = frozenset(filter(None, ns.ignore.split(",")))
    ready = time.monotonic()
    if ns.state and ns.mode == "slow-restart":
        if os.path.exists(ns.state):
            ready += ns.restart_delay
        else:
            open(ns.state, "w").close()
    host, _, port = ns.bind.rpartition(":")
    end = time.monotonic() + ns.lifetime
    ls = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    ls.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    ls.bind((host, int(port)))
    ls.listen(16)
    ls.settimeout(0.2)
    print(f"listening on {host}:{port}", flush=True)
    threads: list[threading.Thread] = []
    while time.monotonic() < end:
        try:
            c, _ = ls.accept()
        except TimeoutError:
            continue
        threads = [t for t in threads if t.is_alive()]
        if len(threads) >= MAX_CLIENTS:
            c.close()
            continue
        t = threading.Thread(target=serve_client, args=(c, ns.mode, end, ready), daemon=True)
        t.start()
        threads.append(t)
    ls.close()


if __name__ == "__main__":
    main()

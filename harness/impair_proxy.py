"""``mcp-impair``: a UDP proxy that is a bad link, reproducible by seed (issue 22 item 2).

    mcp-impair --listen HOST:PORT --target HOST:PORT [--loss P] [--dup P] [--reorder P]
               [--delay LO-HI] [--corrupt P] [--burst P_GB/P_BG[/LOSS]] [--rate N]
               [--seed N] [--impair SPEC] [--capture FILE.mcap] [--duration S]
               [--max-held N] [--max-held-bytes B] [-v|-q]

Point a node at ``--listen`` instead of its peer: every datagram it sends there goes on to
``--target`` (``--forward``, its old name, still works) through the impairment, from a socket of its own for that sender (as a NAT
would), and every datagram the forward side sends back to that socket returns to the sender
from ``--listen``, impaired too. The two directions are impaired independently
(``harness.impair``: the same seed and traffic give the same decisions). On exit (SIGINT,
SIGTERM, ``--duration``: how it is stopped) it prints what it did, per direction and kind; ``--capture`` records
each decision with the datagram it touched (MCAP channel ``/impair``), so a capture shows
which losses were the link's. Exit 0 at the end of ``--duration``; 130 or 143 when SIGINT or
SIGTERM stopped it (128 + the signal's number, the tools' one convention: docs/grammar.md),
its report printed and its capture closed all the same; 2 with one line on a bad option, a
port in use or a ``--target`` host that does not resolve (it is resolved once, at start:
never a DNS lookup per datagram).

Delayed copies wait in a bounded queue (``harness.impair.DelayQueue``): at most
``--max-held`` copies (default 20,000) and ``--max-held-bytes`` bytes (default 16 MiB, each
copy charged its length plus 256 bytes of bookkeeping), so a flood through a long delay holds
at most that much beside the interpreter; a copy past the cap is dropped, recorded
(``dropped: "queue"`` on ``/impair``) and counted in the end summary (``K queue``).

Sockets and clocks live here; the decisions are ``harness.impair.Impairment``'s.
"""

from __future__ import annotations

import argparse
import contextlib
import selectors
import signal
import socket
import sys
import time
from collections.abc import Sequence
from typing import Any, NoReturn

from mcp_conform.harness.config import parse_hostport
from mcp_conform.harness.impair import (
    MAX_HELD,
    MAX_HELD_BYTES,
    DelayQueue,
    Impairment,
    ImpairmentError,
    ImpairSpec,
    parse_impairment,
)
from mcp_conform.traceio.grammar import add_verbosity, add_version, deprecated, epilog

__all__ = ["ImpairProxy", "main", "resolve"]

PROG = "mcp-impair"
Address = tuple[str, int]
#: the most senders one proxy keeps a forward socket for (a bound on open sockets)
MAX_PEERS = 256


def resolve(addr: Address, what: str) -> Address:
    """``addr`` with its host as an IPv4 address, looked up once (``socket.getaddrinfo``);
    ValueError in one line when it does not resolve."""
    host, port = addr
    try:
        infos = socket.getaddrinfo(host, port, socket.AF_INET, socket.SOCK_DGRAM)
    except (socket.gaierror, UnicodeError) as exc:
        why = exc.strerror if isinstance(exc, socket.gaierror) else str(exc)
        raise ValueError(f"{what}: cannot resolve {host!r}: {why}") from None
    return str(infos[0][4][0]), int(infos[0][4][1])


class ImpairProxy:
    """The proxy's sockets and its delivery queue; ``run(until)`` serves until a deadline or
    :meth:`stop`. ``recorder`` (optional) gets every decision (``impairment(...)``);
    ``max_held``/``max_held_bytes``: the delay queue's cap. ``forward`` is resolved here, once
    (ValueError when it does not)."""

    def __init__(self, listen: Address, forward: Address, impairment: Impairment, *,
                 recorder: Any = None, max_held: int = MAX_HELD,
                 max_held_bytes: int = MAX_HELD_BYTES) -> None:
        self.impairment = impairment
        self.forward = resolve(forward, "--target")
        self.queue: DelayQueue[tuple[socket.socket, bytes, Address]] = DelayQueue(max_held, max_held_bytes)
        self.recorder = recorder
        self.verbose = False  # -v: one line per datagram the link touched
        self.sel = selectors.DefaultSelector()
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            self.front.bind(listen)
        except OSError:
            self.front.close()
            raise
        self.front.setblocking(False)
        self.sel.register(self.front, selectors.EVENT_READ, None)
        self.back: dict[Address, socket.socket] = {}  # sender -> its forward socket
        self._stop = False
        self.per_direction: dict[str, int] = {"up": 0, "down": 0}

    @property
    def address(self) -> Address:
        host, port = self.front.getsockname()[:2]
        return str(host), int(port)

    def stop(self) -> None:
        self._stop = True

    def _back_socket(self, sender: Address) -> socket.socket | None:
        sock = self.back.get(sender)
        if sock is None:
            if len(self.back) >= MAX_PEERS:
                return None
            sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            sock.bind((self.front.getsockname()[0], 0))
            sock.setblocking(False)
            self.back[sender] = sock
            self.sel.register(sock, selectors.EVENT_READ, sender)
        return sock

    def _impair(self, direction: str, data: bytes, out: socket.socket, dst: Address,
                now: float) -> None:
        decision = self.impairment.decide(direction, data, now)
        self.per_direction[direction] += 1
        kept = tuple(d for d in decision.deliveries
                     if self.queue.push(now + d.delay_s, len(d.data), (out, d.data, dst)))
        decision = self.impairment.refused(decision, kept)
        if self.recorder is not None:
            with contextlib.suppress(Exception):
                self.recorder.impairment(decision, data, time.time_ns())
        if self.verbose and decision.kinds:  # -v: what the link did to it
            print(f"{PROG}: {direction} #{decision.n} ({decision.size} B): {', '.join(decision.kinds)}",
                  file=sys.stderr, flush=True)

    def _read(self, sock: socket.socket, sender: Address | None, now: float) -> None:
        for _ in range(64):  # bounded per wake-up
            try:
                data, addr = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError:  # ICMP port unreachable from a peer: UDP goes on
                return
            if sender is None:  # from a node to --listen: up, from its own forward socket
                peer = (str(addr[0]), int(addr[1]))
                back = self._back_socket(peer)
                if back is not None:
                    self._impair("up", data, back, self.forward, now)
            else:  # from the forward side to a sender's socket: down, from --listen
                self._impair("down", data, self.front, sender, now)

    def _deliver(self, now: float) -> None:
        for sock, data, dst in self.queue.pop_due(now):
            with contextlib.suppress(OSError):
                sock.sendto(data, dst)

    def run(self, until: float | None = None) -> None:
        """Serve until ``until`` (a ``time.monotonic()`` deadline) or :meth:`stop`."""
        while not self._stop:
            now = time.monotonic()
            if until is not None and now >= until:
                break
            self._deliver(now)
            due = self.queue.next_due()
            wait = 0.2 if due is None else max(0.0, due - now)
            if until is not None:
                wait = min(wait, max(0.0, until - now))
            for key, _ in self.sel.select(min(wait, 0.2)):
                self._read(key.fileobj, key.data, time.monotonic())  # type: ignore[arg-type]
            self._deliver(time.monotonic())

    def close(self) -> None:
        for sock in [self.front, *self.back.values()]:
            with contextlib.suppress(Exception):
                self.sel.unregister(sock)
            sock.close()
        self.sel.close()
        self.queue.clear()

    def report(self) -> str:
        """What it did: per direction, then per kind (``K queue``: copies the full delay queue
        dropped), then the most the queue held against its cap."""
        dirs = ", ".join(f"{n} {d}" for d, n in self.per_direction.items())
        q = self.queue
        return (f"{PROG}: {dirs}: {self.impairment.summary()}; delay queue held at most "
                f"{q.peak_count} copies, {q.peak_bytes / (1 << 20):.1f} MiB (cap {q.cap_text()})")


class _Parser(argparse.ArgumentParser):
    """argparse that says a usage error in one line (not the whole usage), exit 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{PROG}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="A UDP proxy that impairs both directions, "
                "reproducibly by seed (loss, duplication, delay, reordering, "
                "corruption, burst loss, rate limit).",
                epilog=epilog("--duration is its normal end (exit 0); Ctrl-C or SIGTERM stops it too: "
                              "exit 130 or 143, its report printed."),
                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_version(p, PROG)
    p.add_argument("--listen", required=True, metavar="HOST:PORT", help="where the node sends")
    p.add_argument("--target", metavar="HOST:PORT", help="where it goes on to (required)")
    deprecated(p, "--forward", "--target")
    add_verbosity(p, "also one line on stderr per datagram the link touched (dropped, duplicated, "
                  "delayed, corrupted)", "no start and end lines: errors only")
    for key, what in (("loss", "drop probability"), ("dup", "duplication probability"),
                      ("reorder", "probability of being held back past later datagrams"),
                      ("corrupt", "probability of bit flips or a cut")):
        p.add_argument(f"--{key}", metavar="P", help=what)
    p.add_argument("--delay", metavar="LO-HI", help="delay range, e.g. 0-50ms (jitter)")
    p.add_argument("--burst", metavar="P_GB/P_BG[/LOSS]", help="Gilbert-Elliott burst loss")
    p.add_argument("--rate", metavar="N", help="at most N datagrams per second per direction")
    p.add_argument("--seed", metavar="N", help="the seed of the decisions (default 0)")
    p.add_argument("--impair", metavar="SPEC", help="all of the above as one string "
                   "(loss=0.3,dup=0.1,reorder=0.2,delay=0-50ms,seed=7); options given beside it win")
    p.add_argument("--capture", metavar="FILE.mcap", help="record every decision (channel /impair)")
    p.add_argument("--duration", metavar="S", type=float, help="stop after S seconds")
    p.add_argument("--max-held", metavar="N", type=int, default=MAX_HELD,
                   help=f"the delay queue's cap in copies held at once ({MAX_HELD}); past it a "
                   "copy is dropped, recorded and counted ('queue')")
    p.add_argument("--max-held-bytes", metavar="B", type=int, default=MAX_HELD_BYTES,
                   help=f"the delay queue's cap in bytes ({MAX_HELD_BYTES}: 16 MiB; each copy "
                   "counts its length plus 256): the most a flood through a long delay holds")
    return p


def spec_from_args(ns: argparse.Namespace) -> ImpairSpec:
    words = [w for w in (ns.impair or "").split(",") if w.strip()]
    given = {w.split("=", 1)[0].strip().lower(): w for w in words}
    for key in ("loss", "dup", "reorder", "corrupt", "delay", "burst", "rate", "seed"):
        value = getattr(ns, key)
        if value is not None:
            given[key] = f"{key}={value}"
    return parse_impairment(",".join(given.values()) or "seed=0")


def main(argv: Sequence[str] | None = None) -> int:
    ns = build_parser().parse_args(argv)
    try:
        if ns.target is None:
            raise ImpairmentError("--target HOST:PORT is required: where the datagrams go on to")
        spec = spec_from_args(ns)
        listen = parse_hostport(ns.listen, "--listen")
        forward = resolve(parse_hostport(ns.target, "--target"), "--target")
        if ns.duration is not None and not ns.duration > 0:
            raise ImpairmentError("--duration: must be > 0")
        if ns.max_held < 1 or ns.max_held_bytes < 1:
            raise ImpairmentError("--max-held and --max-held-bytes must be >= 1")
    except (ImpairmentError, ValueError) as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    recorder = None
    if ns.capture:
        from mcp_conform.traceio.recorder import McapRecorder, RecorderError, run_metadata

        try:
            recorder = McapRecorder(ns.capture, library=PROG, metadata=run_metadata(
                PROG, impair=spec.text(), listen=ns.listen, forward=ns.target))
        except RecorderError as exc:
            print(f"{PROG}: error: {exc}", file=sys.stderr)
            return 2
    try:
        proxy = ImpairProxy(listen, forward, Impairment(spec), recorder=recorder,
                            max_held=ns.max_held, max_held_bytes=ns.max_held_bytes)
    except OSError as exc:
        print(f"{PROG}: error: --listen {ns.listen}: {exc.strerror}", file=sys.stderr)
        if recorder is not None:
            recorder.close()
        return 2
    proxy.verbose = ns.verbose
    stopped_by: list[int] = []  # the signals that stopped it: a handler takes no lock

    def stop(signum: int, _frame: object) -> None:
        stopped_by.append(signum)
        proxy.stop()

    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, stop)
    if not ns.quiet:
        print(f"{PROG}: {proxy.address[0]}:{proxy.address[1]} -> {forward[0]}:{forward[1]} "
              f"({spec.text()})", flush=True)
    try:
        proxy.run(None if ns.duration is None else time.monotonic() + ns.duration)
    finally:
        proxy.close()
        if recorder is not None:
            recorder.close()
    if not ns.quiet:
        print(proxy.report(), flush=True)
    return 128 + stopped_by[0] if stopped_by else 0


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

"""A bad link at a socket's own edge (issue 22 item 3): ``--impair SPEC`` on the runner.

The runner's driver (``harness.driver``) and a node's transport pass each datagram they send
and receive through an :class:`ImpairedLink`: ``harness.impair.Impairment`` decides (drop,
duplicate, delay, reorder, corrupt), this module carries it out (a timer thread delivers the
delayed copies) and, unlike a proxy in between, *knows* every decision: each is kept
(``touched``: what the link did to which datagram, and when) and recorded in the capture
like ``mcp-impair``'s (channel ``/impair``, ``recorder.impairment``). So a conformance case
whose observation a decision spoiled is repeated or reported with that reason, never failed
(``conformance._plugin_run``), and a fuzzer oracle never turns a dropped ACK into a finding.

Directions are named from the socket owner's side: ``tx`` what it sends, ``rx`` what it
receives. A corrupted ``rx`` copy is discarded, as the UDP checksum would discard it: the
owner's own input is not what is under test (a node's robustness against garbage is, and
``tx`` corruption reaches it).
"""

from __future__ import annotations

import contextlib
import heapq
import itertools
import socket
import threading
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.impair import (
    Decision,
    Impairment,
    ImpairmentError,
    ImpairSpec,
    parse_impairment,
)

__all__ = ["ImpairEvent", "ImpairedLink", "ImpairmentError", "ImpairSpec", "impair_option"]

Address = tuple[str, int]
#: what makes a decision able to spoil an observation (a plain short delay does not)
SPOILING = ("dup", "reorder", "corrupt", "cut")
#: the most decisions kept for ``touched`` (a long run forgets the oldest)
MAX_EVENTS = 100_000


def impair_option(text: str | None) -> ImpairSpec | None:
    """``--impair SPEC`` as every CLI reads it (one parser, ``harness.impair``): None when
    not given; ``ImpairmentError`` with a one-line message otherwise (the CLI exits 2)."""
    if text is None:
        return None
    return parse_impairment(text)


def _describe_datagram(data: bytes) -> str:
    from mcp_conform.spec.codec import Action, peek_header

    hdr = peek_header(data, require_preamble=False)
    if hdr is None:
        return f"a {len(data)}-byte datagram"
    dst, src, seq, action = hdr
    try:
        name = Action(action).name
    except ValueError:
        name = f"action {action}"
    return f"{name} seq {seq} {src}->{dst}"


@dataclass(frozen=True)
class ImpairEvent:
    """One decision that did something to a datagram (a clean pass is not kept)."""

    t: float  # the link's clock's monotonic() when the datagram reached the link
    t_ns: int
    decision: Decision
    what: str  # the datagram, for a person ("ACK seq 12 1->0")
    spoils: bool  # it can spoil an observation (a drop, a copy, a reordering, a corruption, a long delay)

    def describe(self) -> str:
        who = "sent" if self.decision.direction == "tx" else "received"
        kinds = sorted({k for k in self.decision.kinds if k != "delay"} or {"delay"})
        return f"{self.what} ({who}) {'/'.join(kinds)}"


class ImpairedLink:
    """Impairs one socket owner's traffic both ways; thread-safe.

    ``spoil_delay_s``: a delay longer than this can spoil an observation (a late reply
    falls outside a window); shorter ones are only recorded.
    """

    def __init__(self, impairment: Impairment, *, recorder: Any = None,
                 spoil_delay_s: float = 0.05, clock: Clock = REAL) -> None:
        self.impairment = impairment
        self.clock = clock  # the owner's (``harness.clock``): the host's, or virtual time
        self.recorder = recorder
        self.spoil_delay_s = spoil_delay_s
        self.paused = False  # a clean link for the while (a case's last attempt)
        self.events: list[ImpairEvent] = []
        self._lock = threading.Lock()
        self._cond = clock.condition(self._lock)
        self._queue: list[tuple[float, int, Callable[[], None]]] = []
        self._order = itertools.count()
        self._thread: Any = None
        self._closed = False
        self.dropped_held = 0  # copies dropped as the node they were for was replaced

    @property
    def spec(self) -> ImpairSpec:
        return self.impairment.spec

    # ------------------------------------------------------------------ the two edges
    def send(self, sock: socket.socket, data: bytes, addr: Address,
             on_wire: Callable[[bytes], None] | None = None) -> list[float]:
        """``sock.sendto(data, addr)`` through the link (a drop sends nothing);
        ``on_wire(copy)`` for each copy as it leaves (what the far end is sent). Returns each
        copy's delay (s) from now: none when the link dropped it, two when it duplicated it."""
        def out(body: bytes) -> Callable[[], None]:
            def go() -> None:
                with contextlib.suppress(OSError):
                    sock.sendto(body, addr)
                if on_wire is not None:
                    on_wire(body)
            return go

        if self.paused:
            out(data)()
            return [0.0]
        decision = self._decide("tx", data)
        for d in decision.deliveries:
            if d.delay_s <= 0:
                out(d.data)()
            else:
                self._later(d.delay_s, out(d.data))
        return [max(0.0, d.delay_s) for d in decision.deliveries]

    def receive(self, data: bytes, addr: Address, deliver: Callable[[bytes, Address], None]) -> int:
        """A datagram read from the socket: ``deliver(data, addr)`` for each copy the link
        lets through, now or later (from the link's timer thread); how many it lets through
        (0: the link dropped it)."""
        if self.paused:
            deliver(data, addr)
            return 1
        decision = self._decide("rx", data)
        handed = 0
        for d in decision.deliveries:
            if "corrupt" in d.kinds or "cut" in d.kinds:
                continue  # the UDP checksum's business: never handed to the owner
            handed += 1
            if d.delay_s <= 0:
                deliver(d.data, addr)
            else:
                body = d.data
                self._later(d.delay_s, lambda body=body: deliver(body, addr))  # type: ignore[misc]  # mypy: a default argument
        return handed

    # ------------------------------------------------------------------ decisions
    def _decide(self, direction: str, data: bytes) -> Decision:
        t, t_ns = self.clock.monotonic(), self.clock.time_ns()
        with self._lock:
            decision = self.impairment.decide(direction, data, t)
        kinds = decision.kinds
        if kinds:
            long_delay = any(d.delay_s > self.spoil_delay_s for d in decision.deliveries)
            spoils = bool(decision.dropped) or long_delay or any(k in SPOILING for k in kinds)
            ev = ImpairEvent(t, t_ns, decision, _describe_datagram(data), spoils)
            with self._lock:
                self.events.append(ev)
                if len(self.events) > MAX_EVENTS:
                    del self.events[: MAX_EVENTS // 10]
            if self.recorder is not None:
                with contextlib.suppress(Exception):
                    self.recorder.impairment(decision, data, t_ns)
        return decision

    def touched(self, since: float, until: float | None = None) -> list[ImpairEvent]:
        """The decisions able to spoil an observation taken between ``since`` and ``until``
        (the link's clock's ``monotonic()``; None: now): a copy delayed into the window counts too."""
        with self._lock:
            events = list(self.events)
        out = []
        for ev in events:
            if not ev.spoils:
                continue
            last = ev.t + max((d.delay_s for d in ev.decision.deliveries), default=0.0)
            if last >= since and (until is None or ev.t <= until):
                out.append(ev)
        return out

    def summary(self) -> str:
        return self.impairment.summary()

    # ------------------------------------------------------------------ the timer thread
    def _later(self, delay_s: float, fn: Callable[[], None]) -> None:
        with self._cond:
            if self._closed:
                return
            heapq.heappush(self._queue, (self.clock.monotonic() + delay_s, next(self._order), fn))
            if self._thread is None:
                self._thread = self.clock.start_thread(self._run, "impair-link")
            self._cond.notify()

    def _run(self) -> None:
        while True:
            with self._cond:
                while not self._closed and (not self._queue or self._queue[0][0] > self.clock.monotonic()):
                    wait = None if not self._queue else self._queue[0][0] - self.clock.monotonic()
                    self._cond.wait(wait)
                if self._closed:
                    return
                _, _, fn = heapq.heappop(self._queue)
            try:
                fn()
            except Exception:  # noqa: BLE001 - a delivery problem must not stop the link
                pass

    def drop_held(self) -> int:
        """Drop every copy held for later; how many. The session calls it as it replaces the
        node (``DatagramSessionBase.respawn``): a delayed copy of a command to the old process
        must not reach the new one on the same port (a late End_Mission copy ended a fresh
        reference drone's mission before its Start_Mission: found in the simulator, the
        seed in tests/sim/test_runner_sim.py)."""
        with self._cond:
            n = len(self._queue)
            self._queue.clear()
            self.dropped_held += n
        return n

    def close(self) -> None:
        """Stop delivering (copies still held are dropped, as a link going down would)."""
        with self._cond:
            self._closed = True
            self._queue.clear()
            self._cond.notify_all()
        if self._thread is not None and getattr(self._thread, "ident", None) != threading.get_ident():
            self._thread.join(timeout=1.0)

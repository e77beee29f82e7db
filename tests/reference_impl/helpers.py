"""Test helpers: N sans-I/O endpoints joined by an in-memory, seeded, lossy link.

Like h11's ConnectionPair, but the medium drops, duplicates and reorders datagrams, and a
virtual clock jumps straight to the next thing that happens (a datagram arriving or an
endpoint's retransmit timer), so a test of minutes of protocol time runs in milliseconds
and every run with the same seed is identical.

The medium is a shared broadcast segment, as MCP's IP broadcasts are (MCP-TRN-1): every
datagram an endpoint sends reaches every *other* endpoint, which filters by MCP ID itself.

Each endpoint's ``trace`` is its own history in order: ``("tx", t, bytes)`` for every
datagram it put on the wire and ``("ev", t, event)`` for every event it emitted, so tests
can check ordering invariants such as stop-and-wait (MCP-BLK-1).
"""

from __future__ import annotations

import heapq
import random
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.reference_impl import Endpoint, Event

__all__ = ["Link", "Node"]


@dataclass
class Node:
    """One endpoint on the link, with everything it sent and emitted."""

    endpoint: Endpoint
    addr: tuple[str, int]
    trace: list[tuple[str, float, Any]] = field(default_factory=list)

    @property
    def sent(self) -> list[bytes]:
        return [x for kind, _, x in self.trace if kind == "tx"]

    @property
    def events(self) -> list[Event]:
        return [x for kind, _, x in self.trace if kind == "ev"]

    def events_of(self, cls: type) -> list[Any]:
        return [e for e in self.events if isinstance(e, cls)]


class Link:
    """A lossy shared medium with a virtual clock.

    ``drop``, ``duplicate`` and ``reorder`` are per-datagram probabilities (per receiver);
    a reordered datagram is held back by up to ``jitter`` seconds, otherwise it arrives
    after ``latency``. Everything random comes from ``random.Random(seed)``.
    """

    def __init__(self, endpoints: list[Endpoint], *, seed: int = 0, drop: float = 0.0,
                 duplicate: float = 0.0, reorder: float = 0.0, latency: float = 0.001,
                 jitter: float = 0.05, now: float = 0.0, impairment: Any = None) -> None:
        self.nodes = [Node(ep, (f"10.0.0.{i + 1}", 7000 + i)) for i, ep in enumerate(endpoints)]
        self.rng = random.Random(seed)
        self.drop, self.duplicate, self.reorder = drop, duplicate, reorder
        self.latency, self.jitter = latency, jitter
        self.now = now
        self._wire: list[tuple[float, int, int, bytes, tuple[str, int]]] = []  # heap
        self._order = 0
        self.delivered_datagrams = 0
        #: a ``harness.impair.Impairment`` deciding instead of drop/duplicate/reorder: each
        #: (sender, receiver) pair is a direction of its own
        self.impairment = impairment

    # ------------------------------------------------------------------ driving
    def send(self, i: int, action: int, payload: Any, dst: int, **kw: Any) -> int:
        """``nodes[i].endpoint.send(...)`` at the current time, then flush the link."""
        handle = self.nodes[i].endpoint.send(action, payload, dst, now=self.now, **kw)
        self._pump()
        return handle

    def inject(self, i: int, data: bytes, addr: tuple[str, int] = ("10.9.9.9", 9)) -> None:
        """Hand raw bytes straight to ``nodes[i]`` now (crafted or malformed input)."""
        self.nodes[i].endpoint.receive_datagram(data, addr, self.now)
        self._pump()

    def next_time(self) -> float | None:
        """When the next datagram arrives or the next timer fires, or None when quiet."""
        times = [t for t in (n.endpoint.get_timer() for n in self.nodes) if t is not None]
        if self._wire:
            times.append(self._wire[0][0])
        return min(times) if times else None

    def step(self) -> bool:
        """Advance the clock to the next happening and process it; False when quiet."""
        t = self.next_time()
        if t is None:
            return False
        self.now = max(self.now, t)
        while self._wire and self._wire[0][0] <= self.now:
            _, _, dst, data, src_addr = heapq.heappop(self._wire)
            self.delivered_datagrams += 1
            self.nodes[dst].endpoint.receive_datagram(data, src_addr, self.now)
            self._pump()
        for n in self.nodes:
            timer = n.endpoint.get_timer()
            if timer is not None and timer <= self.now:
                n.endpoint.handle_timer(self.now)
                self._pump()
        return True

    def run(self, *, until: float | None = None, max_steps: int = 100_000) -> int:
        """Step until quiet, until virtual time ``until``, or ``max_steps``; returns the steps."""
        steps = 0
        while steps < max_steps:
            t = self.next_time()
            if t is None or (until is not None and t > until):
                break
            self.step()
            steps += 1
        if until is not None:
            self.now = max(self.now, until)
        return steps

    # ------------------------------------------------------------------ machinery
    def _pump(self) -> None:
        """Move every endpoint's events, then its outgoing datagrams, to its trace / the wire.

        Events first: an outcome (DeliveryConfirmed) precedes the first copy of the queued
        unicast it releases, as it does inside the endpoint.
        """
        for i, n in enumerate(self.nodes):
            for ev in n.endpoint.events():
                n.trace.append(("ev", self.now, ev))
            for data, _hint in n.endpoint.datagrams_to_send(self.now):
                n.trace.append(("tx", self.now, data))
                for j in range(len(self.nodes)):
                    if j != i:
                        self._transmit(j, data, n.addr)

    def _transmit(self, dst: int, data: bytes, src_addr: tuple[str, int]) -> None:
        if self.impairment is not None:
            decision = self.impairment.decide(f"{src_addr[0]}>{dst}", data, self.now)
            for d in decision.deliveries:
                self._order += 1
                heapq.heappush(self._wire, (self.now + self.latency + d.delay_s, self._order, dst,
                                            d.data, src_addr))
            return
        rng = self.rng
        if self.drop and rng.random() < self.drop:
            return
        copies = 2 if (self.duplicate and rng.random() < self.duplicate) else 1
        for _ in range(copies):
            delay = self.latency
            if self.reorder and rng.random() < self.reorder:
                delay += rng.random() * self.jitter
            self._order += 1
            heapq.heappush(self._wire, (self.now + delay, self._order, dst, data, src_addr))

"""The simulator's link is the runner's own (issue 38, item 2): each direction's datagrams go
through ``harness.impair`` -- :class:`Impairment` decides (loss, Gilbert-Elliott bursts, the
rate limit, duplication into ``copies`` extra copies, delay, reordering), :meth:`Impairment.carry`
holds each copy in a bounded :class:`DelayQueue` until it is due and records what a full queue
refused -- exactly as ``mcp-impair`` and ``mcp-soak``'s medium do on a host, only the clock is
the simulator's virtual one and the seed the schedule's. So the simulator tests the link
``--impair`` ships, not a second model of it.

The directions are named as ``mcp-soak``'s medium names them (``drone{N}:down`` from the
manager, ``drone{N}:up`` to it), and a decision depends on the seed, the direction and the
datagram's identity (``harness.impair``: the c-th copy of the r-th distinct message), never on
the timing around it. A spec that would corrupt is refused (:func:`check_spec`): a corrupted
copy would reach the judges as its sender's bytes, which the UDP checksum (and the runner's own
link, ``harness.impair_link``) keeps from a node.

Each :class:`Link` keeps its own record (:class:`LinkRecord`: every copy made, when it was
sent and when due, or dropped and why) so a judge can be told what the link did
(``judge.explain``'s copy capacity, :mod:`sim.judges`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from mcp_conform.harness.impair import Decision, DelayQueue, Impairment, ImpairSpec

__all__ = ["Link", "LinkRecord", "check_spec"]

T = TypeVar("T")


def check_spec(spec: ImpairSpec) -> ImpairSpec:
    """``spec`` if the simulator can run it; ValueError in one line if it corrupts."""
    if spec.corrupt:
        raise ValueError(f"link {spec.text()!r}: corrupt is not simulated (the judges would read a "
                         "corrupted copy as its sender's; the UDP checksum keeps it from a node)")
    return spec


@dataclass(frozen=True, slots=True)
class LinkRecord:
    """What the link did with copy ``copy`` (0: the datagram itself, 1..: the link's
    duplicates) of its ``index``-th datagram, sent at ``t_sent``: due at ``t_arrive``, or
    dropped (None, ``kinds`` saying why: ``drop:loss``, ``drop:burst``, ``drop:rate``)."""

    index: int
    copy: int
    t_sent: float
    t_arrive: float | None
    kinds: tuple[str, ...] = ()


class Link:
    """One direction: :meth:`send` carries a datagram into the world's delay queue."""

    __slots__ = ("name", "impairment", "queue", "_records", "max_copies", "_clean", "_sent")

    def __init__(self, name: str, impairment: Impairment, queue: DelayQueue[Any]) -> None:
        self.name = name
        self.impairment = impairment
        #: the spec (frozen) does nothing: read once, not per datagram (``ImpairSpec.active`` is
        #: an any() of seven fields: a tenth of the simulated MCP-ROB-7 flood's 10,000 sends)
        self._clean = not impairment.spec.active
        self.queue = queue
        self._records: list[LinkRecord] = []
        #: a clean link's record, compact: each datagram's send time (its copy 0, due then);
        #: :attr:`records` makes its LinkRecords when asked (a judge's question, not
        #: each of the flood's 10,000 sends)
        self._sent: list[float] = []
        self.max_copies = 1  # the most copies the link delivered of one datagram

    def send(self, data: bytes, now: float, held: Callable[[bytes], T]) -> Decision | None:
        """Carry ``data`` entering the link at ``now``: each copy held in the queue as
        ``held(copy's bytes)`` until due; the decision (None: a clean link, passed at once)."""
        if self._clean:  # decide() would pass it unchanged, undelayed
            self.queue.push(now, len(data), held(data))
            self._sent.append(now)
            return None
        decision = self.impairment.carry(self.name, data, now, self.queue, lambda d: held(d.data))
        n = decision.n
        records = self._records
        if not decision.deliveries:
            records.append(LinkRecord(n, 0, now, None, decision.kinds))
        for copy, d in enumerate(decision.deliveries):
            records.append(LinkRecord(n, copy, now, now + d.delay_s, d.kinds))
        self.max_copies = max(self.max_copies, len(decision.deliveries))
        return decision

    @property
    def records(self) -> list[LinkRecord]:
        """Every copy the link made or dropped, in the order sent (:class:`LinkRecord`)."""
        if self._clean:
            return [LinkRecord(i, 0, t, t) for i, t in enumerate(self._sent)]
        return self._records

    @property
    def duplicates(self) -> int:
        """How many extra copies the link delivered."""
        return 0 if self._clean else sum(1 for r in self._records if r.copy)

    @property
    def drops(self) -> int:
        """How many datagrams the link dropped whole (loss, burst, rate, a full queue)."""
        return 0 if self._clean else sum(1 for r in self._records if r.t_arrive is None)

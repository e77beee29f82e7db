"""The model of :mod:`judge.explain` (issue 38, item 1): one direction of MCP unicast -- the
copies a sender ``S`` sent a receiver ``R``, the ACKs to ``S`` and ``R``'s own, the bounds the
trace is judged with -- and the two tools every rule is decided with: a maximum bipartite
matching with capacities (Kuhn's augmenting paths) and the Hall set read off it, the set of
left items that outnumbers what it can take, which is the evidence a person reads.

Sans-I/O: no clock, socket, file or thread; times are seconds on the observer's clock.
"""

from __future__ import annotations

import math
import sys
from bisect import bisect_left, bisect_right
from collections.abc import Sequence
from dataclasses import dataclass, field

PROVEN, CONSISTENT, UNOBSERVABLE = "proven", "consistent", "unobservable"
EITHER_RTX = "MCP-RTX-1 or MCP-RTX-2"
EITHER_ACK = "MCP-ACK-1 or MCP-ACK-2"
RANK = {PROVEN: 2, CONSISTENT: 1, UNOBSERVABLE: 0}


@dataclass(frozen=True)
class Copy:
    """A datagram ``S`` sent ``R``, as observed at ``t``. ``msg`` names the message (copies of
    one message share it); ``ackable`` is false for one a node must not ACK (an ACK, a
    broadcast: MCP-ACK-4/6), which is in the model only because an ACK may name it;
    ``judged`` says MCP-ACK-1 asks for its answer (sent while ``R`` receives, D-6);
    ``link_copy`` marks a duplicate the runner's own link made (not the sender's); ``own`` is
    false for one the runner sent in ``S``'s name (a script's harness beside its manager):
    what the sender did with it is not judged."""

    seq: int
    msg: int
    t: float
    ackable: bool = True
    judged: bool = True
    link_copy: bool = False
    own: bool = True


@dataclass(frozen=True)
class Ack:
    """An ACK from ``src`` observed at ``t``, naming ``named`` (None: a payload that is not 2
    bytes, MCP-ACK-2), to ``dst`` (None: to ``S``). ``R``'s ACKs to other nodes are in the
    model because a node may ACK ``S``'s copy to the wrong ID (MCP-ACK-3's business, not
    MCP-ACK-1's): they may answer a copy, and need not."""

    t: float
    named: int | None
    src: int = 1
    dst: int | None = None


#: no bound on the ACKs one copy may draw (:attr:`Bounds.copy_capacity`, D-9)
UNBOUNDED = sys.maxsize


@dataclass(frozen=True)
class Bounds:
    """What the trace is judged with. A datagram observed at ``t`` was sent (a copy) or
    reached the sender (an ACK) at a true time in ``[t - *_early, t + *_late]``: ``*_early``
    is the observer's lag (a receive backlog, a run delay), ``*_late`` the time from the
    observer's stamp to the datagram's departure or arrival (a link's delay). The defaults
    are spec/mcp.yaml's parameters (timeout_s, ack_window_s, min_copies,
    rtx_spacing_tolerance, timing_jitter_s) with a perfect observer."""

    copy_early: float = 0.0
    copy_late: float = 0.0
    ack_early: float = 0.0
    ack_late: float = 0.0
    ack_window: float = 2.0  # a node answers a copy within this (MCP-ACK-1, D-6)
    horizon: float = math.inf  # an ACK answers a copy at most this long after it (MCP-ACK-2)
    rto: float = 5.0  # the sender's retransmission timeout (MCP-RTX-1..3)
    rto_tolerance: float = 0.2  # gaps within this fraction of the timeout (MCP-RTX-3)
    rto_slack: float = 0.015  # scheduling allowance: jitter plus any measured run delay (D-7)
    min_copies: int = 3  # the least retry limit (MCP-RTX-1: at least 3 copies while withheld)
    #: ACKs one copy may draw: any number (D-9: the spec asks every copy ACKed and nowhere
    #: forbids answering one datagram more than once, so a count of ACKs above the copies
    #: proves nothing); a caller may bound it only for a node it knows answers each copy once
    copy_capacity: int = UNBOUNDED
    max_ack_copies: int = 5  # copies a node may miss while busy before its first ACK (D-6)
    #: a new message (numbered above, MCP-SEQ-1) ends the previous one's retransmission (BLK-1)
    stop_and_wait: bool = True

    @property
    def rto_min(self) -> float:
        return self.rto * (1 - self.rto_tolerance) - self.rto_slack

    @property
    def rto_max(self) -> float:
        return self.rto * (1 + self.rto_tolerance) + self.rto_slack


@dataclass(frozen=True)
class Trace:
    """One direction: ``copies`` from ``sender`` to ``receiver``, ``acks`` to ``sender`` (and
    the receiver's to others); ``end`` is when the observation ended; ``complete`` says it
    holds every datagram; ``elsewhere``: the sender's unicast copies to other nodes, which show
    it moved on from a message (stop-and-wait is node-wide, MCP-BLK-1); ``run_delay``: the
    sender's run delay (D-7) as read at times, ``(t, s)`` in time order (:func:`run_delay_over`):
    a silence is judged in the time it could run."""

    copies: Sequence[Copy]
    acks: Sequence[Ack]
    end: float
    sender: int = 0
    receiver: int = 1
    complete: bool = True
    elsewhere: Sequence[Copy] = ()
    run_delay: Sequence[tuple[float, float]] = ()


def run_delay_over(readings: Sequence[tuple[float, float]], t_a: float, t_b: float,
                   times: Sequence[float] | None = None) -> float:
    """The run delay (D-7) a sender may have accrued from ``t_a`` to ``t_b``, as its
    ``readings`` bound it: ``(t, cumulative run delay)`` in time order (its datagrams carry
    them, ``harness.run_delay``; a reading without a datagram at its view's end), in any one
    unit. It is the growth between the readings that bracket the span -- the last at or
    before ``t_a``, the first at or after ``t_b`` -- since nothing tells where between them
    the sender waited for a CPU: an explanation that puts it inside the span is consistent
    with the trace (a node that read an ACK as a stall ended and sent its next datagram later
    shows its stall only then). A stall outside the bracket -- before the reading at or before
    ``t_a``, after the one at or after ``t_b`` -- counts nothing. Where no reading comes at or
    after ``t_b``, only the growth up to the last one before it (nothing unmeasured is assumed:
    a perfect observer, as where no run delay is known at all). No readings: 0. ``times``: the
    readings' times, where the caller keeps them (a long trace's many spans)."""
    if not readings or t_b < t_a:
        return 0
    if times is None:
        times = [t for t, _ in readings]
    i_a = bisect_right(times, t_a) - 1  # the last at or before t_a
    j_b = bisect_left(times, t_b)  # the first at or after t_b
    lo = i_a if i_a >= 0 else 0
    hi = j_b if j_b < len(readings) else bisect_right(times, t_b) - 1
    return max(readings[hi][1] - readings[lo][1], 0) if 0 <= lo <= hi < len(readings) else 0


@dataclass(frozen=True)
class Verdict:
    """A rule's verdict; ``explanation`` pairs each ACK's index with the copy's index it
    answers (None: none), or is empty where no matching is involved."""

    rule: str
    status: str
    evidence: str
    explanation: tuple[tuple[int, int | None], ...] = field(default=())


# ------------------------------------------------------------------ matching


def _match(n_left: int, cands: Sequence[Sequence[int]], capacity: Sequence[int]
           ) -> tuple[list[int | None], list[list[int]]]:
    """A maximum matching of left items to right items with capacities (Kuhn's augmenting
    paths, iterative): ``cands[i]`` the right items left item ``i`` may take. Returns each
    left item's right item (None: unmatched) and each right item's left items."""
    owner: list[int | None] = [None] * n_left
    held: list[list[int]] = [[] for _ in capacity]
    for root in range(n_left):
        if not cands[root]:
            continue
        # breadth-first search for an augmenting path from ``root``
        parent: dict[int, tuple[int, int | None]] = {}  # right -> (left that reached it, from)
        seen_left = {root}
        queue = [root]
        found: int | None = None
        while queue and found is None:
            nxt: list[int] = []
            for left in queue:
                for r in cands[left]:
                    if r in parent:
                        continue
                    parent[r] = (left, owner[left])
                    if len(held[r]) < capacity[r]:
                        found = r
                        break
                    for other in held[r]:
                        if other not in seen_left:
                            seen_left.add(other)
                            nxt.append(other)
                if found is not None:
                    break
            queue = nxt
        if found is None:
            continue
        r2: int | None = found
        while r2 is not None:
            left, _ = parent[r2]
            prev = owner[left]
            if prev is not None:
                held[prev].remove(left)
            held[r2].append(left)
            owner[left] = r2
            r2 = prev if left != root else None
    return owner, held


def _hall(start: int, cands: Sequence[Sequence[int]], held: Sequence[Sequence[int]]
          ) -> tuple[list[int], list[int]]:
    """From an unmatched left item of a maximum matching, the left items and right items
    alternating paths reach: the right items are all full and held by the others, so the
    left set outnumbers what it can take (Hall's condition fails)."""
    lefts, rights = [start], []
    seen_l, seen_r = {start}, set()
    i = 0
    while i < len(lefts):
        for r in cands[lefts[i]]:
            if r not in seen_r:
                seen_r.add(r)
                rights.append(r)
                for other in held[r]:
                    if other not in seen_l:
                        seen_l.add(other)
                        lefts.append(other)
        i += 1
    return lefts, rights


def _intervals_meet(lo: float, hi: float, lo2: float, hi2: float) -> bool:
    return max(lo, lo2) <= min(hi, hi2)


def _latency(c: Copy, a: Ack, b: Bounds) -> tuple[float, float]:
    """The latencies from a copy's true departure to an ACK's true time the bounds allow."""
    return (a.t - b.ack_early) - (c.t + b.copy_late), (a.t + b.ack_late) - (c.t - b.copy_early)


def _answers(c: Copy, a: Ack, b: Bounds, most: float) -> bool:
    lo, hi = _latency(c, a, b)
    return _intervals_meet(lo, hi, 0.0, most)


def _candidates(copies: Sequence[Copy], acks: Sequence[Ack], before: float, after: float
                ) -> list[list[int]]:
    """For each copy, the ACKs seen from ``before`` ahead of it to ``after`` behind it (a sort
    and two bisections: a trace of hundreds stays cheap)."""
    order = sorted(range(len(acks)), key=lambda j: acks[j].t)
    times = [acks[j].t for j in order]
    return [order[_bisect(times, c.t - before):_bisect(times, c.t + after, right=True)]
            for c in copies]


def _bisect(xs: Sequence[float], x: float, right: bool = False) -> int:
    lo, hi = 0, len(xs)
    while lo < hi:
        mid = (lo + hi) // 2
        if xs[mid] < x or (right and xs[mid] == x):
            lo = mid + 1
        else:
            hi = mid
    return lo


def _fmt_copy(c: Copy) -> str:
    return f"copy of seq {c.seq} at {c.t:.3f} s" if c.ackable else (
        f"datagram seq {c.seq} (not to be ACKed) at {c.t:.3f} s")


def _fmt_ack(a: Ack) -> str:
    named = "a malformed payload" if a.named is None else f"'{a.named}'"
    return f"ACK {named} from ID {a.src} at {a.t:.3f} s"


def _some(items: Sequence[str], limit: int = 6) -> str:
    more = f", ... {len(items) - limit} more" if len(items) > limit else ""
    return ", ".join(items[:limit]) + more


def _explain(pairs: Sequence[tuple[int, int | None]], copies: Sequence[Copy],
             acks: Sequence[Ack], limit: int = 6) -> str:
    shown = [f"{_fmt_ack(acks[a])} answers {'nothing' if c is None else _fmt_copy(copies[c])}"
             for a, c in pairs[:limit]]
    more = f"; ... {len(pairs) - limit} more" if len(pairs) > limit else ""
    return "; ".join(shown) + more

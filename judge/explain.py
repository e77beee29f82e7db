"""Attribution as one algorithm: which ACK answered which copy, decided over every explanation
of a trace consistent with stated bounds (issue 38, item 1).

The model is one direction of MCP unicast, a sender ``S`` and a receiver ``R``: the copies
``S`` sent (:class:`Copy`: a message's sequence number, its identity, the time the observer
saw it), the ACKs ``R`` or anyone else sent ``S`` (:class:`Ack`: the time seen, the number its
payload names, ``None`` for a payload that is not 2 bytes), and :class:`Bounds`: how far an
observed time may lie from the datagram's true time (the runner's receive backlog, the run
delay ``harness/run_delay.py`` measures, a link's delay), how soon a node answers (the ACK
window, ``--ack-window``, D-6) and when a sender retransmits (``--rto`` and RTX-3's
tolerance).

An *explanation* assigns each ACK to at most one copy it could answer -- with a latency of
at least zero and within the bounds -- each copy drawing at most ``copy_capacity`` ACKs (a
node ACKs each copy it receives once; the link may duplicate), or, for the sender's
retransmission, assigns the end of a message's retransmission a cause: an ACK that reached
the sender before it, or a give-up at a timer's expiry. A rule is:

- ``proven`` when every consistent explanation violates it; the evidence is one explanation
  (the one that comes nearest to keeping the rule: a maximum matching) and the set of
  copies or ACKs that no explanation can satisfy together (Hall's condition, read off the
  matching), written for a person;
- ``consistent`` when some explanation keeps it (that explanation is the evidence);
- ``unobservable`` when the trace holds nothing the rule speaks about, or cannot be
  explained at all within the bounds (then another rule, or the bounds, are wrong).

Which ACK answered which copy is a bipartite matching problem (Kuhn's augmenting paths,
polynomial); the time bounds are checked per (ACK, copy) pair, which is a relaxation of the
joint constraint that one datagram has one delay: it admits more explanations than the
exact model, so a rule proven here is proven in the exact model too (sound; it may leave
undecided what a joint check would prove).

Rules decided (docs/spec.md, spec/mcp.yaml):

- MCP-ACK-1 (receiver): every copy ``judged`` is answered, by an ACK of any payload, within
  the ACK window. Only on a complete trace.
- MCP-ACK-2 (receiver): every ACK from ``R`` answers a copy whose number it names (or a
  datagram ``S`` sent that a node must not ACK, :attr:`Copy.ackable` false: MCP-ACK-5/6's
  business, not ACK-2's). Only on a complete trace, where an ACK cannot answer a copy the
  capture missed.
- MCP-RTX-1 (sender): a sender that stops retransmitting with no ACK reaching it has sent
  at least ``min_copies`` copies of its own (copies the link made, :attr:`Copy.link_copy`,
  are not retransmissions).
- MCP-RTX-2 (sender): what ended a message's retransmission is an ACK from ``R`` naming its
  number. ``MCP-RTX-1 or MCP-RTX-2`` is reported too: where a stop could be either a give-up
  too early or a wrong ACK taken, every explanation violates one of them.

Sans-I/O: no clock, socket, file or thread; times are seconds on the observer's clock.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

__all__ = [
    "Ack",
    "Bounds",
    "Copy",
    "Trace",
    "Verdict",
    "decide",
    "decide_receiver",
    "decide_sender",
]

PROVEN, CONSISTENT, UNOBSERVABLE = "proven", "consistent", "unobservable"
EITHER_RTX = "MCP-RTX-1 or MCP-RTX-2"


@dataclass(frozen=True)
class Copy:
    """A datagram ``S`` sent ``R``, as observed at ``t``. ``msg`` names the message (copies of
    one message share it); ``ackable`` is false for one a node must not ACK (an ACK, a
    broadcast: MCP-ACK-4/6), which is in the model only because an ACK may name it;
    ``judged`` says MCP-ACK-1 asks for its answer (sent while ``R`` receives, D-6);
    ``link_copy`` marks a duplicate the runner's own link made (not the sender's)."""

    seq: int
    msg: int
    t: float
    ackable: bool = True
    judged: bool = True
    link_copy: bool = False


@dataclass(frozen=True)
class Ack:
    """An ACK to ``S`` from ``src`` observed at ``t``, naming ``named`` (None: a payload that
    is not 2 bytes, MCP-ACK-2)."""

    t: float
    named: int | None
    src: int = 1


@dataclass(frozen=True)
class Bounds:
    """What the trace is judged with. A datagram observed at ``t`` was sent (a copy) or
    reached the sender (an ACK) at a true time in ``[t - *_early, t + *_late]``: ``*_early``
    is the observer's lag (a receive backlog, a run delay), ``*_late`` the time from the
    observer's stamp to the datagram's departure or arrival (a link's delay). The defaults
    are spec/mcp.yaml's parameters (timeout_s, ack_window_s, min_retransmissions,
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
    copy_capacity: int = 1  # ACKs one copy may draw: 1 + the copies the link may make of it
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
    """One direction: ``copies`` from ``sender`` to ``receiver``, ``acks`` to ``sender``;
    ``end`` is when the observation ended; ``complete`` says it holds every datagram."""

    copies: Sequence[Copy]
    acks: Sequence[Ack]
    end: float
    sender: int = 0
    receiver: int = 1
    complete: bool = True


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


# ------------------------------------------------------------------ receiver: ACK-1, ACK-2


def decide_receiver(trace: Trace, b: Bounds) -> dict[str, Verdict]:
    """MCP-ACK-1 and MCP-ACK-2 of the receiver ``trace.receiver``."""
    return {"MCP-ACK-1": _ack1(trace, b), "MCP-ACK-2": _ack2(trace, b)}


def _own_acks(trace: Trace) -> list[int]:
    return [j for j, a in enumerate(trace.acks) if a.src == trace.receiver]


def _ack1(trace: Trace, b: Bounds) -> Verdict:
    rule = "MCP-ACK-1"
    if not trace.complete:
        return Verdict(rule, UNOBSERVABLE, "the trace may miss ACKs (not complete)")
    # judged: a copy whose window closed, however late the observer saw its answer
    idx = [i for i, c in enumerate(trace.copies) if c.ackable and c.judged
           and c.t + b.copy_late + b.ack_window + b.ack_early <= trace.end]
    due = [trace.copies[i] for i in idx]
    if not due:
        return Verdict(rule, UNOBSERVABLE, "no copy whose ACK window closed within the trace")
    own = _own_acks(trace)
    acks = [trace.acks[j] for j in own]
    # _answers(c, a, b, ack_window) as a range of observed times
    cands = _candidates(due, acks, b.copy_early + b.ack_late,
                        b.ack_window + b.copy_late + b.ack_early)
    owner, held = _match(len(due), cands, [1] * len(acks))
    pairs = tuple(sorted((own[a], idx[ci])
                         for ci, a in enumerate(owner) if a is not None))
    missing = [ci for ci, a in enumerate(owner) if a is None]
    if not missing:
        return Verdict(rule, CONSISTENT, "every copy answered within the window: "
                       + _explain(pairs, trace.copies, trace.acks), pairs)
    lefts, rights = _hall(missing[0], cands, held)
    names = _some([_fmt_copy(due[ci]) for ci in sorted(lefts, key=lambda i: due[i].t)])
    could = _some([_fmt_ack(acks[r]) for r in sorted(rights, key=lambda r: acks[r].t)])
    text = (f"{len(lefts)} copies ({names}) and only {len(rights)} ACKs from ID {trace.receiver} "
            f"any of them could have been answered by within {b.ack_window:g} s"
            f" ({could or 'none'}): in every explanation one of them goes unanswered; "
            f"nearest explanation: {_explain(pairs, trace.copies, trace.acks) or 'no ACK answers any'}")
    return Verdict(rule, PROVEN, text, pairs)


def _ack2(trace: Trace, b: Bounds) -> Verdict:
    rule = "MCP-ACK-2"
    own = _own_acks(trace)
    if not own:
        return Verdict(rule, UNOBSERVABLE, f"no ACK from ID {trace.receiver}")
    if not trace.complete:
        return Verdict(rule, CONSISTENT, "the trace may miss the copy each ACK answers")
    acks = [trace.acks[j] for j in own]
    copies = list(trace.copies)

    naming: dict[int | None, list[int]] = {}
    for j, a in enumerate(acks):
        naming.setdefault(a.named, []).append(j)
    cands: list[list[int]] = [[] for _ in acks]  # an ACK's copies: the number it names
    for ci, c in enumerate(copies):
        for j in naming.get(c.seq, ()):
            if _answers(c, acks[j], b, b.horizon):
                cands[j].append(ci)
    owner, held = _match(len(acks), cands, [b.copy_capacity] * len(copies))
    pairs = tuple((own[j], owner[j]) for j in range(len(acks)))
    homeless = [j for j, c in enumerate(owner) if c is None]
    if not homeless:
        return Verdict(rule, CONSISTENT, "every ACK answers a copy of the number it names: "
                       + _explain(pairs, copies, trace.acks), pairs)
    lefts, rights = _hall(homeless[0], cands, held)
    wrong = acks[homeless[0]]
    if not rights:
        why = (f"{_fmt_ack(wrong)} names no copy sent to ID {trace.receiver} before it"
               if wrong.named is not None else f"{_fmt_ack(wrong)} names no number")
    else:
        why = (f"{len(lefts)} ACKs ({_some([_fmt_ack(acks[j]) for j in sorted(lefts)])}) "
               f"and {len(rights)} datagrams they name "
               f"({_some([_fmt_copy(copies[r]) for r in sorted(rights)])}), each answered "
               f"at most {b.copy_capacity} time(s)")
    # the explanation as a whole: the right matching, the rest answering any copy it can
    return Verdict(rule, PROVEN, f"{why}: in every explanation an ACK answers a copy whose "
                   f"number it does not name; nearest explanation: "
                   f"{_explain(pairs, copies, trace.acks)}", pairs)


# ------------------------------------------------------------------ sender: RTX-1, RTX-2


@dataclass(frozen=True)
class _Stop:
    """Where a message's retransmission ended: no later than ``latest`` (true time), shown
    by ``how``."""

    latest: float
    how: str


@dataclass(frozen=True)
class _Index:
    """The sender's trace sorted once: ACK times, and each message's first copy (time, seq)."""

    ack_times: list[float]
    acks: list[Ack]
    starts: list[tuple[float, int, int]]  # (first copy's time, seq, msg), in time order
    start_times: list[float]


def _index(trace: Trace) -> _Index:
    acks = sorted(trace.acks, key=lambda a: a.t)
    starts: dict[int, tuple[float, int]] = {}
    for c in trace.copies:
        if c.ackable and not c.link_copy:
            starts[c.msg] = min(starts.get(c.msg, (c.t, c.seq)), (c.t, c.seq))
    ordered = sorted((t, seq, m) for m, (t, seq) in starts.items())
    return _Index([a.t for a in acks], acks, ordered, [t for t, _, _ in ordered])


def _stops(trace: Trace, b: Bounds, ix: _Index, msg: int, own: Sequence[Copy]) -> list[_Stop]:
    """What shows that ``msg``'s retransmission ended, strongest first: a new message seen
    after its last copy (the sender is stop-and-wait, MCP-BLK-1), then a due copy that never
    came on a complete trace."""
    first, last = min(c.t for c in own), max(c.t for c in own)
    out = []
    if b.stop_and_wait:
        # a new message: its first copy seen after this one's last, and newer -- numbered
        # above it (MCP-SEQ-1) or surely sent after its first copy (an observer's lag may
        # show an older message's copy late)
        seq = own[0].seq
        k = _bisect(ix.start_times, last, right=True)
        later = [t for t, n, m in ix.starts[k:] if m != msg and (
            0 < (n - seq) % 0x10000 < 0x8000 or t - b.copy_early > first + b.copy_late)]
        if later:
            out.append(_Stop(later[0] + b.copy_late,
                             f"the sender moved on to a new message at {later[0]:.3f} s"))
    silent_until = last + b.copy_late + b.rto_max + b.copy_early
    if trace.complete and trace.end >= silent_until:
        out.append(_Stop(last + b.copy_late + b.rto_max,
                         f"no copy came in the {trace.end - last:.3f} s after the last, "
                         f"longer than the timeout allows ({b.rto_max:.3f} s)"))
    return out


def _message(trace: Trace, b: Bounds, ix: _Index, msg: int, copies: list[Copy]
             ) -> dict[str, Verdict]:
    """RTX-1, RTX-2 and their disjunction for one message."""
    seq = copies[0].seq
    own = [c for c in copies if not c.link_copy] or copies
    k = len(own)
    first, last = min(c.t for c in own), max(c.t for c in own)
    name = f"seq {seq} (first copy at {first:.3f} s, {k} own copies)"
    rules = ("MCP-RTX-1", "MCP-RTX-2", EITHER_RTX)
    stops = _stops(trace, b, ix, msg, own)
    if not stops:
        status = CONSISTENT if k >= b.min_copies else UNOBSERVABLE
        text = (f"{name}: retransmitted to the end of the trace" if status == CONSISTENT else
                f"{name}: the trace ends before its retransmission could be seen to end")
        return {r: Verdict(r, status, text) for r in rules}
    for stop in stops:
        lo = _bisect(ix.ack_times, last - b.copy_early - b.ack_late)
        hi = _bisect(ix.ack_times, stop.latest + b.ack_early, right=True)
        causes = ix.acks[lo:hi]  # reached the sender after its last copy, before it stopped
        right = [a for a in causes if a.src == trace.receiver and a.named == seq]
        give_up = last - b.copy_early + b.rto_min <= stop.latest
        if causes or give_up:
            break
    else:  # no explanation under the strongest evidence's assumption, nor the others
        return {r: Verdict(r, UNOBSERVABLE, f"{name}: {stops[0].how} with no ACK to take "
                           f"and before a timeout: no explanation within the bounds "
                           f"(MCP-BLK-1's business, or the bounds are too tight)") for r in rules}
    wrong = [a for a in causes if a not in right]
    out: dict[str, Verdict] = {}
    # RTX-2: some explanation ends it on a right ACK, or on a give-up
    if right:
        out["MCP-RTX-2"] = Verdict("MCP-RTX-2", CONSISTENT,
                                   f"{name}: ended by {_fmt_ack(right[0])}; {stop.how}")
    elif give_up:
        out["MCP-RTX-2"] = Verdict("MCP-RTX-2", CONSISTENT,
                                   f"{name}: may have given up at a timeout; {stop.how}")
    else:
        out["MCP-RTX-2"] = Verdict(
            "MCP-RTX-2", PROVEN,
            f"{name}: {stop.how}, before a timeout could end it "
            f"({b.rto_min:.3f} s after the last copy at {last:.3f} s); no ACK from ID "
            f"{trace.receiver} naming {seq} reached it by then, so in every explanation it "
            f"took a wrong one: {_some([_fmt_ack(a) for a in wrong])}")
    # RTX-1: some explanation ends it on an ACK, or on a give-up after enough copies
    if causes:
        out["MCP-RTX-1"] = Verdict("MCP-RTX-1", CONSISTENT,
                                   f"{name}: {_fmt_ack(causes[0])} may have ended it")
    elif k >= b.min_copies:
        out["MCP-RTX-1"] = Verdict("MCP-RTX-1", CONSISTENT,
                                   f"{name}: gave up after {k} copies; {stop.how}")
    else:
        out["MCP-RTX-1"] = Verdict(
            "MCP-RTX-1", PROVEN,
            f"{name}: {stop.how}, and no ACK reached the sender before: it stopped "
            f"retransmitting unACKed after {k} copies (at least {b.min_copies})")
    either_ok = bool(right) or (give_up and k >= b.min_copies)
    if either_ok:
        out[EITHER_RTX] = Verdict(EITHER_RTX, CONSISTENT, out["MCP-RTX-2"].evidence)
    else:
        took = _some([_fmt_ack(a) for a in wrong]) or "none"
        out[EITHER_RTX] = Verdict(
            EITHER_RTX, PROVEN,
            f"{name}: {stop.how}; no right ACK reached the sender before, so it either took a "
            f"wrong ACK ({took}, MCP-RTX-2) or gave up after {k} copies, fewer than "
            f"{b.min_copies} (MCP-RTX-1)")
    return out


def decide_sender(trace: Trace, b: Bounds) -> dict[str, Verdict]:
    """MCP-RTX-1, MCP-RTX-2 (and their disjunction) of the sender ``trace.sender``: each
    message judged on its own; a rule is proven where one message proves it."""
    by_msg: dict[int, list[Copy]] = {}
    for c in trace.copies:
        if c.ackable:
            by_msg.setdefault(c.msg, []).append(c)
    rules = ("MCP-RTX-1", "MCP-RTX-2", EITHER_RTX)
    found: dict[str, Verdict] = {}
    ix = _index(trace)
    for msg in sorted(by_msg, key=lambda m: min(c.t for c in by_msg[m])):
        for rule, v in _message(trace, b, ix, msg, by_msg[msg]).items():
            old = found.get(rule)
            rank = {PROVEN: 2, CONSISTENT: 1, UNOBSERVABLE: 0}
            if old is None or rank[v.status] > rank[old.status]:
                found[rule] = v
    return {r: found.get(r, Verdict(r, UNOBSERVABLE, "no unicast message sent")) for r in rules}


def decide(trace: Trace, b: Bounds, side: str) -> dict[str, Verdict]:
    """The verdicts of the node on ``side`` ("receiver": ACK-1/2; "sender": RTX-1/2)."""
    if side == "receiver":
        return decide_receiver(trace, b)
    if side == "sender":
        return decide_sender(trace, b)
    raise ValueError(f"side is 'receiver' or 'sender', not {side!r}")

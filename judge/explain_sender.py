"""Sender-side rules of :mod:`judge.explain`: MCP-RTX-1 and MCP-RTX-2 of ``S``, decided over
the causes that could have ended each message's retransmission."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from mcp_conform.judge.explain_model import (
    CONSISTENT,
    EITHER_RTX,
    PROVEN,
    RANK,
    UNOBSERVABLE,
    Ack,
    Bounds,
    Copy,
    Trace,
    Verdict,
    _bisect,
    _fmt_ack,
    _some,
    run_delay_over,
)

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
    rd_times: list[float]  # the times of the sender's run delay readings (Trace.run_delay)


def _index(trace: Trace) -> _Index:
    acks = sorted(trace.acks, key=lambda a: a.t)
    starts: dict[tuple[bool, int], tuple[float, int]] = {}  # (elsewhere, msg) -> (t, seq)
    for away, copies in ((False, trace.copies), (True, trace.elsewhere)):
        for c in copies:
            if c.ackable and c.own and not c.link_copy:
                key = (away, c.msg)
                starts[key] = min(starts.get(key, (c.t, c.seq)), (c.t, c.seq))
    # a message elsewhere never equals one here: its msg is put out of range
    ordered = sorted((t, seq, -1 - m if away else m) for (away, m), (t, seq) in starts.items())
    return _Index([a.t for a in acks], acks, ordered, [t for t, _, _ in ordered],
                  [t for t, _ in trace.run_delay])


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
    # the silence in the time the sender could run: a copy due while it was off the CPU goes
    # out late by its run delay (D-7), as far as its readings bound it
    seen = _bisect(ix.rd_times, trace.end, right=True)  # a reading after the trace is not in it
    starved = run_delay_over(trace.run_delay[:seen], last, trace.end, ix.rd_times[:seen])
    silent_until = last + b.copy_late + b.rto_max + b.copy_early + starved
    if trace.complete and trace.end >= silent_until:
        ran = f", {starved:.3f} s of it off the CPU (run delay, D-7)" if starved else ""
        out.append(_Stop(last + b.copy_late + b.rto_max + starved,
                         f"no copy came in the {trace.end - last:.3f} s after the last{ran}, "
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
    # each stop is a fact (the retransmission had ended by its ``latest``): the earliest binds.
    # A move on at the instant a late ACK came does not let that ACK end a retransmission
    # already over -- no copy when the next was due, the ACK withheld (seed
    # explain-rtx1-missed-late-ack: a manager-rtx-none manager's lone Start_Mission)
    for stop in sorted(stops, key=lambda x: x.latest):
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
        if c.ackable and c.own:
            by_msg.setdefault(c.msg, []).append(c)
    rules = ("MCP-RTX-1", "MCP-RTX-2", EITHER_RTX)
    found: dict[str, Verdict] = {}
    ix = _index(trace)
    for msg in sorted(by_msg, key=lambda m: min(c.t for c in by_msg[m])):
        for rule, v in _message(trace, b, ix, msg, by_msg[msg]).items():
            old = found.get(rule)
            if old is None or RANK[v.status] > RANK[old.status]:
                found[rule] = v
    return {r: found.get(r, Verdict(r, UNOBSERVABLE, "no unicast message sent")) for r in rules}


def decide_message(trace: Trace, b: Bounds, seq: int, t: float) -> dict[str, Verdict] | None:
    """MCP-RTX-1, MCP-RTX-2 (and their disjunction) of one message of ``trace.sender``: the one
    with an own copy numbered ``seq`` seen nearest ``t`` (None: no such copy) -- what a monitor
    failure about that message is weighed against (``judge.veto``), where
    :func:`decide_sender` reports the worst of every message."""
    by_msg: dict[int, list[Copy]] = {}
    for c in trace.copies:
        if c.ackable and c.own:
            by_msg.setdefault(c.msg, []).append(c)
    near = [(abs(c.t - t), c.msg) for c in trace.copies if c.ackable and c.own and c.seq == seq]
    if not near:
        return None
    msg = min(near)[1]
    return _message(trace, b, _index(trace), msg, by_msg[msg])

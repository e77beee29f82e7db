"""Where a fault is observable (issue 38, item 3: "a faulty model gets its rule where its
fault is observable"): per fault model, from what it did (its deviations) and what its own
view holds, ``True`` (the trace proves the rule broken: a sound judge must find it),
``False`` (the trace cannot show it: nothing may be asked) or ``None`` (on a boundary of the
rule's observed reading, its tolerances: neither asked nor refused). The readings are
docs/spec.md's:

- MCP-ACK-1 "Observed: each command sent between the node's Mission_Ready and its End_Mission
  is ACKed, ... up to 5 copies (a node may be deaf while busy, D-6) ..., and every later copy
  is ACKed again": a message it received 5 times and never ACKed (of the copies before its
  first datagram, only the last: a node's capture does not show it running before), or a copy it left
  unanswered after answering one (the copies of End_Mission excepted: D-6 lets a drone stop
  receiving after its ACK of End_Mission);
- MCP-ACK-2 "the acknowledged message's sequence number": an ACK naming a number that no
  datagram in the node's view carried up to the judge's reorder grace after the ACK
  (``seq_reorder_grace_s``: a judge of times sees one instant in any order, and a datagram read
  just after the ACK may be what it answers) -- it acknowledges no message. A count (more ACKs
  naming a number than datagrams carrying it) proves nothing: a node may ACK one datagram more
  than once (D-9), and the link's record of which copies it made is no judge's to read;
- MCP-RTX-1 "Observed: at least 3 copies while the ACK is withheld": copies ``rto`` apart
  within ±20 % (MCP-RTX-3) plus the jitter allowance, so fewer than 3 with the ACK withheld past
  the latest time the third was due, and the view going on past it;
- MCP-RTX-2 "Only an ACK from the message's destination whose payload equals the message's
  sequence number ends its retransmission": a wrong ACK taken, and the sender seen to move on
  (its next message at once).
"""

from __future__ import annotations

import re
from typing import Any

from mcp_conform.sim.schedule import Outcome
from mcp_conform.sim.world import NS, ViewRecord
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action, peek_header

__all__ = ["observable"]

ACK = int(Action.ACK)
MAX_ACK_COPIES = 5
#: the latest a copy is due: rto x 1.2 (MCP-RTX-3's tolerance) plus jitter, with a margin
LATE, EARLY, MARGIN = 1.25, 0.8, 0.05
#: the judge's reorder grace (a datagram read this long after an ACK may be what it answers)
GRACE = float(SPEC.params["seq_reorder_grace_s"])
#: what a party does at one virtual instant, as its stamps show it (``sim.world.STEP_NS`` apart)
INSTANT = 1e-3


def s_stalls(o: Any, pid: int) -> list[tuple[float, float]]:
    """The party's stall windows (``Outcome.world.stalls``), passed along as ``s._stalls``."""
    return list(getattr(o, "_stalls", {}).get(pid, ()))


def _heads(view: list[ViewRecord]) -> list[tuple[float, bool, tuple[int, int, int, int], bytes]]:
    out = []
    for r in view:
        h = peek_header(r.data)
        if h is not None:
            out.append((r.t_ns / NS, r.tx, h, r.data))
    return out


def _named(data: bytes) -> int:
    return int.from_bytes(data[17:19], "big")


def observable(o: Outcome) -> tuple[bool | None, str]:
    """Whether the schedule's fault is observable in its node's view, and why."""
    s = o.schedule
    f = s.faulty
    if f is None or f.rule is None:
        return False, "no rule broken"
    pid = s.faulty_party
    assert pid is not None
    dev = o.deviations
    if not dev:
        return False, "the fault never changed what the node did"
    view = _heads(o.world.views[pid])
    end = o.world.view_end(pid)
    fn = _ORACLES.get(f.name)
    if fn is None:
        return False, f"{f.rule} is not observable on the simulated wire (no oracle of sim.oracles reads it)"
    return fn(_WithStalls(s, o.world.stalls), pid, dev, view, end)


class _WithStalls:
    """The schedule, and the stall windows the world drew from it."""

    def __init__(self, s: Any, stalls: dict[int, list[tuple[float, float]]]) -> None:
        self.rto = s.rto
        self._stalls = stalls


def _unanswered_copies(s: Any, pid: int, dev: Any, view: Any, end: float) -> tuple[bool | None, str]:
    """MCP-ACK-1, never ACKed: some message received 5 times while receiving."""
    ready = min((t for t, tx, h, _ in view if tx and h[3] == Action.MISSION_READY), default=None)
    # a judge of the node's capture knows it runs from its first datagram on: of the copies
    # before, only the last may have been heard (``Monitor._ack_rearm``)
    shown = min((t for t, tx, *_ in view if tx), default=None)
    if shown is None:
        return False, "the node sent nothing: no judge knows it was running"
    before: set[tuple[int, int]] = set()
    counts: dict[tuple[int, int], int] = {}
    window = max(0.5, 2 * s.rto)  # the ACK window the judges are given (sim.judges)
    for t, tx, (dst, src, seq, action), _ in view:
        if t + window + MARGIN > end:
            break  # its answer would be due after the view's end
        if tx or action == ACK or dst != pid:
            continue
        if pid != 0 and (ready is None or t < ready):
            continue  # a drone receives from its Mission_Ready on (D-6)
        if pid != 0 and action == Action.END_MISSION:
            continue
        if t <= shown + INSTANT:
            before.add((src, seq))
            continue
        counts[(src, seq)] = counts.get((src, seq), 0) + 1
    most = max((n + ((k in before) if n else 0) for k, n in counts.items()), default=0)
    if most >= MAX_ACK_COPIES:
        return True, f"{most} copies of one message received, none ACKed"
    return False, f"at most {most} copies of a message received (a node may miss {MAX_ACK_COPIES - 1})"


def _copy_after_answer(s: Any, pid: int, dev: Any, view: Any, end: float) -> tuple[bool | None, str]:
    """MCP-ACK-1, a copy unanswered after one answered (End_Mission's excepted, D-6)."""
    window = max(0.5, 2 * s.rto)
    lag = max((b - a for a, b in s_stalls(s, pid)), default=0.0)  # a copy read late arrived earlier
    verdict: tuple[bool | None, str] = (False, "only End_Mission copies went unanswered (deaf after its ACK, D-6)")
    for t, what in dev:
        if "END_MISSION" in what:
            continue
        if t + window + MARGIN > end:
            verdict = (None, f"at {t:.3f} s: {what}, the view ends within the ACK window")
        elif any(tx and h[3] == ACK and t - lag - MARGIN <= t2 <= t + window + MARGIN for t2, tx, h, _ in view):
            # D-6: an ACK of any payload within the window answers the copy as far as MCP-ACK-1
            # goes (a wrong number is MCP-ACK-2's): only the pair of rules is broken
            verdict = (None, f"at {t:.3f} s: {what}, another ACK of its within the window")
        else:
            return True, f"at {t:.3f} s: {what}, no ACK of its within the window"
    return verdict


def _names_what_none_carried(s: Any, pid: int, dev: Any, view: Any, end: float) -> tuple[bool | None, str]:
    """MCP-ACK-2: an ACK naming a number no datagram of the view carried by the reorder grace
    after it (D-9: never a count of ACKs against copies)."""
    carried: dict[int, float] = {}  # number -> the first time a datagram of the view carried it
    for t, _tx, h, _ in view:
        carried.setdefault(h[2], t)
    verdict: tuple[bool | None, str] = (
        False, "every number it named was carried by a datagram within the ACK's reorder grace "
               "(D-9: a count proves nothing)")
    for t, tx, (_dst, _, _, action), data in view:
        if tx and action == ACK and len(data) == 19:
            named = _named(data)
            first = carried.get(named)
            if first is None or first > t + GRACE + MARGIN:
                return True, f"at {t:.3f} s: an ACK naming {named}, which no datagram carried by then"
            if first > t + GRACE - MARGIN:
                verdict = None, f"at {t:.3f} s: an ACK naming {named}, first carried at the grace's end"
    return verdict


def _first_copy_then_silence(s: Any, pid: int, dev: Any, view: Any, end: float) -> tuple[bool | None, str]:
    """MCP-RTX-1 for a sender of one copy: some message's ACK withheld past the third copy's
    latest time."""
    sent: dict[tuple[int, int], list[float]] = {}
    for t, tx, h, _ in view:
        if tx and h[3] != ACK and h[0] != 0xFFFF:
            sent.setdefault((h[0], h[2]), []).append(t)
    verdict: tuple[bool | None, str] = (False, "every message ACKed in time")
    for (dst, seq), copies in sent.items():
        got = _withheld(s, view, dst, seq, copies, end, pid)
        if got[0] is True:
            return got
        if got[0] is None:
            verdict = got
    return verdict


def _withheld(s: Any, view: Any, dst: int, seq: int, copies: list[float], end: float,
              pid: int) -> tuple[bool | None, str]:
    if len(copies) >= 3:
        return False, f"{len(copies)} copies"
    last = copies[-1]
    lag = max((b - a for a, b in s_stalls(s, pid)), default=0.0)  # read late, sent late (D-7)
    # the third copy's latest time: each gap may stretch by a stall, the ACK be read one late
    due = last + (3 - len(copies)) * (LATE * s.rto + lag) + MARGIN + lag
    soon = last + (3 - len(copies)) * (EARLY * s.rto - lag) - MARGIN - lag
    ack = min((t for t, tx, (d, src, _, a), data in view
               if not tx and a == ACK and src == dst and d == pid and _named(data) == seq), default=None)
    later = any(t > due for t, *_ in view) or end > due
    if (ack is None or ack > due) and later:
        return True, f"{len(copies)} copies of seq {seq}, no ACK by {due:.3f} s, the view goes on"
    if ack is not None and ack < soon:
        return False, f"ACKed at {ack:.3f} s, before a third copy was due"
    return None, f"{len(copies)} copies of seq {seq}, the ACK or the view's end near the third's time"


def _gave_up(s: Any, pid: int, dev: Any, view: Any, end: float) -> tuple[bool | None, str]:
    """MCP-RTX-1 for a sender that gave up after two copies."""
    verdict: tuple[bool | None, str] = (False, "no give-up")
    for _t, what in dev:
        m = re.search(r"seq (\d+) given up", what)
        if m is None:
            continue
        seq = int(m.group(1))
        copies = [(t, h[0]) for t, tx, h, _ in view if tx and h[3] != ACK and h[2] == seq]
        got = _withheld(s, view, copies[0][1], seq, [t for t, _ in copies], end, pid)
        if got[0] is True:
            return got
        if got[0] is None:
            verdict = got
    return verdict


def _moved_on(s: Any, pid: int, dev: Any, view: Any, end: float) -> tuple[bool | None, str]:
    """MCP-RTX-2: a wrong ACK taken, and the next message sent at once."""
    for t, what in dev:
        m = re.search(r"seq (\d+) ended", what)
        seq = int(m.group(1)) if m else -1
        copies = [t2 for t2, tx, h, _ in view if tx and h[3] != ACK and h[2] == seq and t2 <= t]
        lag = max((b - a for a, b in s_stalls(s, pid)), default=0.0)
        if len(copies) >= 3 and abs(t - copies[-1] - s.rto) <= (LATE - 1) * s.rto + MARGIN + lag:
            continue  # at a timer's expiry after 3 copies: a give-up (MCP-RTX-1's limit) explains it
        if any(not tx and h[3] == ACK and _named(d) == seq and t - lag - 1e-6 <= t2 <= t + MARGIN + lag
               for t2, tx, h, d in view):
            continue  # the right ACK at (nearly) the same instant: a judge of times may take it
        if any(tx and -1e-9 <= t2 - t < INSTANT and h[3] != ACK and 0 < ((h[2] - seq) & 0xFFFF) < 0x8000
               for t2, tx, h, _ in view):
            if end < t + LATE * s.rto + MARGIN:
                return None, f"at {t:.3f} s: {what}, the next message sent, the view ends within a timeout"
            return True, f"at {t:.3f} s: {what}, and the next message sent then"
    return False, "a wrong ACK taken, but nothing sent after it (the node closed)"


def _undecided(s: Any, pid: int, dev: Any, view: Any, end: float) -> tuple[bool | None, str]:
    return None, "a wrong ACK taken by a drone: nothing sent after it shows it (its view may)"


_ORACLES = {
    "rtx-stop-on-any-ack": _undecided,
    "no-ack": _unanswered_copies,
    "no-ready-ack": _unanswered_copies,
    "ack-first-copy-only": _copy_after_answer,
    "ack-previous-seq": _names_what_none_carried,
    "ack-copies-wrong-seq": _names_what_none_carried,
    "rtx-none": _first_copy_then_silence,
    "manager-rtx-none": _first_copy_then_silence,
    "give-up-after-two": _gave_up,
    "wrong-seq-ack": _moved_on,
}

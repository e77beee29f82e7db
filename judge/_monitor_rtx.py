"""Retransmission and stop-and-wait rules of the trace monitor (a sender's messages against
each other): MCP-RTX-1 (copies until ACKed, or a sender that gave up too soon), MCP-RTX-2
(only the right ACK ends retransmission: judged on what the sender did after a wrong one),
MCP-RTX-3 (even spacing), MCP-BLK-1/3 (no new unicast while one awaits its ACK), with
MCP-SEQ-2's renumbered retransmissions told apart. Complete traces only: each needs an absence.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from mcp_conform.judge._monitor_base import (
    HDR,
    JITTER_NS,
    MANAGER,
    MIN_COPIES,
    NS,
    RTX_MIN_GAP_NS,
    RTX_TOLERANCE,
    START,
    WRONG_SEQ,
    WRONG_SRC,
    _Exchange,
    _Node,
    fmt_ms,
    fmt_s,
    gaps,
    median,
)
from mcp_conform.judge.spacing import judge_spacing
from mcp_conform.spec import SPEC

if TYPE_CHECKING:
    from mcp_conform.judge._monitor_host import MonitorHost
else:
    MonitorHost = object  # the host's state, declared for the type checker only

#: The description's retransmission timeout: a lone copy's next one is not overdue before it
#: even when the assumed --rto is shorter (issue 18 item 10: a correct node retransmitting every
#: 1.5 s failed MCP-RTX-1 under --rto 0.2 after its first copy; its next copies would come)
DESCRIPTION_TIMEOUT_NS = int(float(SPEC.params["timeout_s"]) * NS)

# bits of _Exchange.flags: a rule already reported on that exchange (F_GAVE_UP: its sender
# moved on at its timer's time after MIN_COPIES copies or more, a retry limit's give-up;
# F_SILENT: MCP-RTX-1 failed on it by its deadline, its copies stopped with no ACK)
F_STORM, F_RTX4, F_INTERLEAVE, F_RTX3, F_RTX2, F_ACK1, F_SEQ2, F_FAULTY, F_RTX1, F_GAVE_UP, F_SILENT = (
    1 << k for k in range(11))


def _running_gaps(ex: _Exchange) -> list[int]:
    """The gaps between ``ex``'s copies in the time its sender could run (D-7): each less the
    growth of the run delay its two copies carry, where both carry one -- the pace of its timer,
    which a stall between two copies stretches on the wire (the give-up-after-two manager's
    second copy 1.54 s after its first, 0.54 s of it off the CPU, then its move on at its
    timer's time 1 s later, taken for a message sent before its ACK: seed
    monitor-blk1-after-give-up)."""
    out = []
    for (a, b), ra, rb in zip(zip(ex.copies, ex.copies[1:], strict=False), ex.run_delays,
                              ex.run_delays[1:], strict=False):
        gap = b[1] - a[1]
        if ra is not None and rb is not None and rb > ra:
            gap = max(gap - (rb - ra), 0)
        out.append(gap)
    return out


class RetransmissionRules(MonitorHost):
    """Mixin of :class:`judge.monitor.Monitor` (through ``SenderRules``)."""

    def _check_stop_and_wait(self, node: _Node, prev: _Exchange, ex: _Exchange, i: int, t: int) -> None:
        """MCP-BLK-1 (and MCP-BLK-3, MCP-SEQ-2): a new unicast while the previous one still
        awaits its ACK. Proven on a complete trace when the previous is unACKed and its next
        copy was due later; on any trace when a copy of the previous follows (``_copy``)."""
        if self._renumbered(prev, ex):
            # the same message again, unACKed, before a sender that retries could have given
            # up: a retransmission under a new number
            chained = prev.flags & F_SEQ2
            prev.flags |= F_SEQ2
            ex.flags |= F_SEQ2
            if chained:
                return  # the same renumbered retransmission, reported at its first copy
            self._emit("MCP-SEQ-2", node.id, t, "a retransmission repeats the original's sequence number",
                       f"{ex.describe()} repeats unACKed seq {prev.seq} with a new number",
                       [prev.copies[-1], (i, t)])
            return
        g = gaps(prev.copies)
        est = median(_running_gaps(prev)) if g else self.rto_ns
        wrong = self._taken_ack(prev)
        if t - prev.last_t >= est * (1 - RTX_TOLERANCE) - JITTER_NS:
            # at its timer's time: it gave up (retry limit) -- unless it moved at once after a
            # wrong ACK with fewer copies than any retry limit stops at: a give-up then breaks
            # MCP-RTX-1 as taking the ACK breaks MCP-RTX-2, and the ACK is what it moved on
            if wrong is None or len(prev.copies) >= MIN_COPIES or t - wrong[1] > JITTER_NS:
                if g and len(prev.copies) < MIN_COPIES:
                    self._gave_up(prev, ex, i, t)
                elif len(prev.copies) >= MIN_COPIES:
                    # its retry limit reached (MCP-RTX-1: configurable): the silence since
                    # its last copy is the limit's, whatever ACK came in it -- a wrong ACK
                    # read after the last copy proves no MCP-RTX-2 (``_wrong_ack_deadline``;
                    # the ack-copies-wrong-seq drone's "seq + 1" ACKs of a manager's 21st copy)
                    prev.flags |= F_GAVE_UP
                return
        if wrong is not None:
            # sent at once after an ACK that must not end ``prev``, with no copy of ``prev``
            # since: the sender took it for ``prev``'s ACK (MCP-RTX-2), unless a copy of
            # ``prev`` follows (then it does not wait at all: MCP-BLK-1, ``_copy``)
            prev.moved_on = (i, t)
            # judged when ``prev``'s next copy is overdue, counted from its last copy where its
            # pace is known -- not from the move, which a view that ends a timeout later never
            # reached (the wrong-seq-ack manager's move 0.3 s after its lone copy, its view
            # ending 1.3 s after the move: seed monitor-rtx2-missed-reordered-link): where the
            # nodes' timeout is declared, MCP-RTX-3's latest (rto + 20 % + the jitter) as
            # MCP-RTX-1's ``lone_due_ns``; by its gaps, 1.5 of them (``_stopped_before``)
            if self.rto_declared:
                due = prev.last_t + int(self.rto_ns * (1 + RTX_TOLERANCE)) + 3 * JITTER_NS
            elif g:
                due = prev.last_t + 3 * est // 2 + 3 * JITTER_NS
            else:
                due = t + 3 * est // 2 + 3 * JITTER_NS
            self._timers.at(max(due, t), self._moved_on_deadline, prev, wrong, ex)
            return
        self._stop_and_wait(prev, ex, t, [prev.copies[-1], (i, t)], "before its ACK")

    @staticmethod
    def _renumbered(prev: _Exchange, ex: _Exchange) -> bool:
        """``ex`` repeats the sender's unACKed ``prev`` -- same destination, action and payload
        -- under a new number, ``prev`` sent once (or a chain of such): one message
        retransmitted, MCP-SEQ-2's fault, not a new one (no second list, MCP-FLOW-4/6). A
        ``prev`` with copies that repeat its number was retransmitted as the description
        identifies retransmissions ("by repeating sequence number"): the same message under a
        new number after them, at its timer's time, is a new message after a give-up, and its
        copies are counted by number (MCP-RTX-1, ``_gave_up``; the Node.js drone's ``--retries
        1 --reannounce``, two copies of seq N then seq N+1, was MCP-SEQ-2 here)."""
        return (not prev.acks and prev.dst == ex.dst and prev.action == ex.action
                and prev.data[HDR:] == ex.data[HDR:]
                and (len(prev.copies) == 1 or bool(prev.flags & F_SEQ2)))

    def _gave_up(self, ex: _Exchange, newer: _Exchange, i: int, t: int) -> None:
        """MCP-RTX-1 (complete trace): the sender moved on to a new unicast when the next copy
        of the unACKed ``ex`` was due, after fewer copies than the rule asks for -- proven then,
        however soon an ACK of ``ex`` comes after it."""
        if ex.flags & (F_RTX1 | F_SEQ2):
            return
        ex.flags |= F_RTX1
        n = len(ex.copies)
        self._emit("MCP-RTX-1", ex.src, t, f"at least {MIN_COPIES} copies until it is ACKed",
                   f"{n} cop{'y' if n == 1 else 'ies'} of {ex.describe()}, no ACK, then {newer.describe()} "
                   f"{fmt_ms(t - ex.last_t)} after the last: it gave up", [*ex.copies[:MIN_COPIES], (i, t)])

    def _taken_ack(self, ex: _Exchange) -> tuple[int, int] | None:
        """The ACK a sender may have taken for ``ex``'s: a wrong one (the wrong seq from its
        destination, its seq from another node) read after its last copy, or an ACK from its
        destination that was already there, with no copy of ``ex`` after its first -- of a
        kind the sender was not seen to ignore (it retransmitted well after one, or it moved on
        before with no ACK to take, ``_stop_and_wait``: a sender that never waits is then
        MCP-BLK-1/3's, not taken for one that took a stale ACK)."""
        node = self._nodes.get(ex.src)  # none for the harness's own sender (the fuzzer as the manager)
        ignores = node.ignores if node is not None else 0
        taken = [a for k, a in (ex.wrong_at or {}).items() if a[1] >= ex.last_t and k & ~ignores]
        if taken:
            return max(taken, key=lambda a: a[1])
        if ex.stale_ack is not None and len(ex.copies) == 1 and not ignores & WRONG_SEQ:
            return ex.stale_ack
        return None

    def _moved_on_deadline(self, now: int, ex: _Exchange, wrong: tuple[int, int], newer: _Exchange) -> None:
        """MCP-RTX-2 (complete trace): a new unicast at once after a wrong ACK, and no copy of
        the unACKed ``ex`` after it when its next one was due: the wrong ACK ended ``ex``'s
        retransmission. A copy after the new unicast is MCP-BLK-1's (``_copy``)."""
        if ex.last_t > newer.first[1] or ex.flags & F_RTX2:
            return
        ex.flags |= F_RTX2
        right = [a for a in ex.acks if a[1] > newer.first[1]]
        self._emit("MCP-RTX-2", ex.src, now, "retransmission goes on until the right ACK",
                   f"{ex.describe()} taken as ACKed by an ACK that does not name it: {newer.describe()} "
                   f"sent {fmt_ms(newer.first[1] - wrong[1])} after that ACK, no copy of it since"
                   + (f" (its right ACK came {fmt_ms(right[0][1] - wrong[1])} after the wrong one)" if right else ""),
                   [ex.copies[-1], wrong, newer.first])

    def _stop_and_wait(self, pending: _Exchange, newer: _Exchange, t: int, evidence: list[Any],
                       how: str) -> None:
        """MCP-BLK-1/3, proven: ``newer`` went out while ``pending`` awaited its ACK, with no
        ACK it could have taken for it. A sender seen moving on so is not taken, later, for
        one that took a wrong or stale ACK (``_taken_ack``): moving on after one is what it
        does anyway (the no-wait-start-ack manager's WP_List 20 ms after each Start_Mission,
        whatever came: MCP-BLK-3, not MCP-RTX-2 when drone 2's stale ACK was there)."""
        if pending.flags & F_SEQ2:
            return
        self._nodes[pending.src].ignores |= WRONG_SEQ | WRONG_SRC
        if pending.action == START and pending.dst == newer.dst and pending.src == MANAGER:
            self._emit("MCP-BLK-3", MANAGER, t, "no further command to that drone until Start_Mission is ACKed",
                       f"{newer.describe()} sent {how} ({pending.describe()})", evidence)
        else:
            self._emit("MCP-BLK-1", pending.src, t,
                       "no new unicast message while one awaits its ACK (stop-and-wait)",
                       f"{newer.describe()} sent {how} ({pending.describe()})", evidence)

    def _rtx_deadline(self, now: int, ex: _Exchange) -> None:
        """MCP-RTX-1 (complete trace): an unACKed unicast has MIN_COPIES copies by the time
        its retransmissions were due. Where the nodes' timeout is declared (``rto_declared``),
        a lone copy is judged as the rule is observed, "at least 3 copies while the ACK is
        withheld": no ACK in the trace by the time the third copy was due at the latest (each
        gap ``rto`` and MCP-RTX-3's tolerance, plus the timestamp jitter, ``lone_due_ns``),
        and the trace going on to then; it is ``now`` that time, so every ACK fed is before it."""
        if ex.flags & F_RTX1:
            return  # reported when it gave up (``_gave_up``)
        if ex.flags & F_SEQ2:
            return  # retransmitted under new numbers: MCP-SEQ-2's, no copies of one message to count
        if ex.acks or len(ex.copies) >= MIN_COPIES:
            self._nodes[ex.src].seen.add("MCP-RTX-1")
            return
        g = gaps(ex.copies)
        if g or not self.rto_declared:
            est = median(g) if g else self.lone_rto_ns
            due = ex.last_t + 3 * est // 2 + self.window_ns
        else:  # a lone copy at the declared pace: its ACK withheld past the last copy's latest time
            due = ex.last_t + self.lone_due_ns
        if now < due:
            self._timers.at(due, self._rtx_deadline, ex)
            return
        if ex.moved_on is not None or (len(ex.copies) > 1 and ex.wrong_ack is not None
                                       and not self._stopped_before(ex, ex.wrong_ack[1])):
            return  # stopped after a wrong ACK: MCP-RTX-2's (``_wrong_ack_deadline``)
        n = len(ex.copies)
        ex.flags |= F_SILENT
        self._emit("MCP-RTX-1", ex.src, now, f"at least {MIN_COPIES} copies until it is ACKed",
                   f"{n} cop{'y' if n == 1 else 'ies'} of {ex.describe()}, no ACK, "
                   f"none for {fmt_s(now - ex.last_t)}", ex.copies[:MIN_COPIES])

    def _wrong_ack_deadline(self, now: int, ex: _Exchange, wrong: tuple[int, int]) -> None:
        """MCP-RTX-2 (complete trace): retransmission goes on after an ACK that names the
        wrong seq or comes from the wrong node."""
        if ex.moved_on is not None:
            return  # moved on at once after a wrong ACK: ``_moved_on_deadline`` judges it
        later = [c for c in ex.copies if c[1] > wrong[1]]
        newer = self._nodes[ex.src].last_unicast
        if ex.flags & F_SEQ2 and newer is not None and newer.first[1] > wrong[1]:
            later.append(newer.first)  # it went on, under new numbers (MCP-SEQ-2's fault)
        right = [a for a in ex.acks if a[1] > wrong[1]]
        if later:
            self._observe(ex.src, "MCP-RTX-2")
            return
        if (right or ex.flags & (F_RTX2 | F_RTX1 | F_GAVE_UP) or self._stopped_before(ex, wrong[1])
                or len(ex.copies) == 1):
            return  # the right ACK came before the next copy was due (inconclusive), or it
            # had stopped before the wrong ACK came or gave up at its timer after it (MCP-RTX-1's,
            # ``_gave_up``: a give-up-after-two manager read a re-ACK between; after MIN_COPIES
            # copies, its retry limit: F_GAVE_UP), or it was never seen
            # retransmitting: a sender that never does falls silent the same way, and the
            # right ACK withheld past its copies' time is MCP-RTX-1's (``_rtx_deadline``)
        ex.flags |= F_RTX2
        self._emit("MCP-RTX-2", ex.src, now, "retransmission goes on until the right ACK",
                   f"{ex.describe()} not retransmitted for {fmt_s(now - wrong[1])} after a wrong ACK",
                   [ex.copies[-1], wrong])

    def _stopped_before(self, ex: _Exchange, t: int) -> bool:
        """Whether ``ex``'s next copy was already overdue at ``t``."""
        before = [c for c in ex.copies if c[1] <= t]
        g = gaps(before)
        est = median(g) if g else self.rto_ns
        return t - before[-1][1] > 3 * est // 2 + 3 * JITTER_NS

    def _judge_spacing(self, ex: _Exchange, copies: list[tuple[int, int]], t: int) -> None:
        """MCP-RTX-3 (complete trace): every gap within ±20 % of the median (plus the spec's
        timestamp jitter) and none under 50 ms; a gap the host's load accounts for (the
        sender's run delay, where known) is excused (``judge.spacing``)."""
        g = gaps(copies)
        if len(g) < 2 or ex.flags & (F_RTX3 | F_STORM):
            return
        self._observe(ex.src, "MCP-RTX-3")
        med, _allowance, bad, _excused, _starved = judge_spacing(g, ex.run_delays)
        if bad:
            ex.flags |= F_RTX3
            self._emit("MCP-RTX-3", ex.src, t,
                       f"every gap within ±{RTX_TOLERANCE:.0%} of the median gap and none under "
                       f"{fmt_ms(RTX_MIN_GAP_NS)}",
                       f"{ex.describe()}: median {fmt_ms(med)}, outliers "
                       + ", ".join(fmt_ms(x) for x in bad), copies)

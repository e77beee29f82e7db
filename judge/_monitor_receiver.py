"""Receiver-side rules of the trace monitor: what a node did with what it received, as its
ACKs show it.

An ACK names a sequence number and goes to a node ID; the monitor looks up what that node
sent with that number (``_by_seq``) and so learns what the ACK answers:

- a well-formed unicast to the ACKing node: the right answer (MCP-ACK-1, -3, -7);
- a broadcast (MCP-ACK-4), a message to another ID (MCP-ACK-5), an ACK (MCP-ACK-6, on a
  complete trace only, since D-5 lets ACKs share numbers), a datagram with a bad preamble
  (MCP-ROB-2), an unknown action (MCP-ROB-3) or a payload that does not fit (MCP-ROB-4):
  an ACK that must not exist. A sender's numbers do not repeat within a window, so even a
  lossy trace proves these;
- nothing: the message may simply be missing from the trace, unless the number is the
  byte swap of a message the node did get (MCP-ACK-2, little-endian; not when another node's
  message to it has the number as it stands: that explanation breaks MCP-ACK-3 instead, so
  the ACK proves neither) or, on a complete trace, another node's message to it has that
  number (MCP-ACK-3).

Missing ACKs (MCP-ACK-1) are judged only on a complete trace, while the node is receiving
(a drone between its Mission_Ready and the ACK of its End_Mission, D-6), once a command
went unanswered through ``max_ack_copies`` copies, or a copy after the ACK was not ACKed
again within the ACK window.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from mcp_conform.judge._monitor_base import (
    ACK_DEADLINE_NS,
    ACK_SAMPLES,
    END,
    JITTER_NS,
    MANAGER,
    MAX_ACK_COPIES,
    PASSTHROUGH,
    WRONG_SEQ,
    WRONG_SRC,
    _Exchange,
    _Node,
    fmt_ms,
    gaps,
    late_ack_wait_ns,
    median,
)
from mcp_conform.judge._monitor_rtx import F_ACK1, F_FAULTY
from mcp_conform.judge._monitor_sender import SEQ_GAP_GRACE_NS, _entry_t

if TYPE_CHECKING:
    from mcp_conform.judge._monitor_host import MonitorHost
else:
    MonitorHost = object  # the host's state, declared for the type checker only

_ROB_EXPECTED = {
    "MCP-ROB-2": "a datagram whose first 9 bytes are not the preamble is discarded silently",
    "MCP-ROB-3": "a datagram with an action code above 8 is discarded silently",
    "MCP-ROB-4": "a payload that does not fit its action is discarded without ACK (D-4)",
}


class ReceiverRules(MonitorHost):
    """Mixin of :class:`judge.monitor.Monitor`: receiver-side judgement."""

    def _ack(self, i: int, t: int, src: int, dst: int, own_seq: int, named: int, tester: bool,
             node: _Node | None) -> None:
        """A well-formed ACK from ``src`` (``node``, None for the harness) to ``dst`` naming
        ``named``."""
        if node is not None:
            self._seq_number_taken(node, own_seq, t)  # D-5: an ACK may take a number (MCP-SEQ-1)
        if self._complete_for(src, dst):  # MCP-ACK-6: what an ACK to this node would answer
            key = src << 16 | own_seq
            seen = self._ack_seq.get(key)
            if seen is not None and seen[0] == dst and t - seen[2] <= self._ack_horizon:
                seen[1:4] = i, t, seen[3] + 1  # a copy of it (the link duplicated it)
            else:  # [dst, i, t, copies of it, ACKs naming it counted as its answers]
                self._ack_seq[key] = [dst, i, t, 1, 0]
        match = self._ex.get(dst << 32 | src << 16 | named)
        if match is not None and t - match.last_t <= self.horizon_ns:  # however late
            # an ACK of another message of dst's (a late or duplicated one) is, to dst's pending
            # message to src, an ACK of the wrong seq from its destination: MCP-RTX-2's input
            # where dst moves on at once after it; a silence after it is not judged by it (a
            # re-ACK while dst was off the CPU, a stalled manager's End_Mission: no-ready-ack)
            self._wrong_for_pending(dst, src, named, i, t, silence=False)
            acks = match.acks
            if (node is not None and acks and len(acks) >= len(match.copies)
                    and self._complete_for(src, dst)):
                # every copy of it drew an ACK already: a re-ACK, which no rule forbids (D-9: a
                # node may answer one datagram more than once), or a waiting copy's wrong ACK
                # (a node that ACKs a copy of seq 1339 with 1340, just after 1340 itself). A
                # count proves neither: a copy waiting since before it is judged by neither
                # MCP-ACK-1 nor MCP-ACK-2 (``_reacks``)
                self._reacks[(src, dst)] = (i, t)
                return
            if acks:  # an ACK of a later copy
                acks.append((i, t))
                w = self._waiting_copy.get((src, dst))
                if w is not None and w is not match and w.last_t > match.last_t and w.acks[-1][1] < w.last_t:
                    # a later copy of another message waits for its ACK: this may be that
                    # copy's wrong ACK (a copy of 1325 ACKed naming 1326, whose own copy waited
                    # before it) as well as a re-ACK of ``match`` (``_ack_deadline``)
                    self._doubtful.add(i)
                    w.maybe_answered = (i, t)
                if match.deliveries and node is not None:  # a duplicate not to deliver again
                    node.seen.add("MCP-DUP-1")
            else:
                self._acked(match, src, i, t, tester)
            if node is not None and i not in self._doubtful:
                # an ACK of a message answers one of its copies, the first at the earliest:
                # the node had read that far (``_answered_later``). Not its n-th copy for its
                # n-th ACK: a node may answer one copy more than once (D-9)
                pair = (src, dst)
                self._answered_to[pair] = max(self._answered_to.get(pair, 0), match.copies[0][1])
            return
        horizon = self._ack_horizon
        if node is not None:
            node.seen.add("MCP-ACK-2")
        self._acks_to.add(dst)
        if dst == self.broadcast_id:
            if not tester:
                self._emit("MCP-ACK-3", src, t, "an ACK's dst is the src of the acknowledged message",
                           f"ACK of seq {named} sent to the broadcast ID", [(i, t)])
            return
        if dst == src:  # no message the capture missed explains it: a node's own ID is not a
            if not tester:  # sender it hears from (one that was seen is ``match`` above)
                self._emit("MCP-ACK-3", src, t, "an ACK's dst is the src of the acknowledged message",
                           f"ACK of seq {named} addressed to its own sender's ID {src}", [(i, t)])
            return
        other = self._by_seq.get(dst << 16 | named)
        if other is not None and t - _entry_t(other) > horizon:
            other = None
        if other is None and self._complete_for(src, dst):
            a = self._ack_seq.get(dst << 16 | named)
            if a is not None and t - a[2] <= horizon and a[4] < a[3]:
                # an ACK of that ACK, if any: a node answers each datagram it reads once, so
                # once every copy of the ACK has drawn an answer, an ACK naming it answers
                # something else -- a copy's wrong ACK, MCP-ACK-2 (the ack-copies-wrong-seq
                # drone's eleven ACKs naming 15568, the number of one ACK of the manager's)
                a[4] += 1
                other = ("ack", a[0], a[1], a[2], 0)
        self._maybe_wrong_ack(dst, src, named, i, t)
        if tester:
            return
        if other is not None:
            w = self._waiting_copy.get((src, dst))
            if (w is not None and w.acks and (w.acks[-1][1] < w.last_t or len(w.acks) < w.owed)
                    and t - w.last_t <= horizon):
                # a copy of an ACKed message waits for its ACK (sent after the first ACK, or
                # before it came back: ``owed``): this may be that copy's wrong ACK
                # (MCP-ACK-2: the copy of seq 1339 ACKed with 1340, the seq of the broadcast
                # sent just after it) as well as an ACK of ``other``; the copy's ACK-1
                # deadline decides which (``_decide_ambiguous``)
                self._stray_acks[(src, dst)] = (i, t, named)
                self._ambiguous.setdefault(id(w), (w, []))[1].append((other, named, i, t))
                return
            if isinstance(other, tuple) and other[0] == "ack" and self._may_answer_a_copy(src, dst, other, named, i, t):
                return
            self._ack_of_what_is_not_acked(src, other, named, i, t)
            return
        swapped = ((named & 0xFF) << 8) | (named >> 8)
        ex = self._ex.get(dst << 32 | src << 16 | swapped) if swapped != named else None
        if ex is not None and t - ex.last_t <= horizon:
            if any((m := self._ex.get(o << 32 | src << 16 | named)) is not None and t - m.last_t <= horizon
                   for o in (self._nodes.keys() | self._tester_ids) - {src, dst}):
                # as well the ACK of another sender's message numbered ``named``, sent to the
                # wrong ID (MCP-ACK-3): each explanation breaks another rule, so it proves
                # neither (D-9's principle; the ack-to-manager drone's ACK of the runner's
                # seq 516 from src 2, sent to ID 0 while the manager's 1026 waited)
                return
            self._emit("MCP-ACK-2", src, t, f"ACK payload {ex.seq} as 2 bytes big-endian (D-2)",
                       f"ACK names {named}: {ex.seq} byte-swapped", [ex.copies[-1], (i, t)])
            return
        if not self._complete_for(src, dst):
            return  # the ACK may answer a message the capture missed
        ex = self._to_seq.get(src << 16 | named)
        if ex is not None:
            if ex.src != dst and not ex.acks and t - ex.last_t <= horizon:
                self._emit("MCP-ACK-3", src, t, f"the ACK goes to ID {ex.src}, the message's src",
                           f"ACK of seq {named} sent to ID {dst} ({ex.describe()})",
                           [ex.copies[-1], (i, t)])
                return
        if node is not None:  # an ACK naming nothing dst sent: a wrong payload, if a copy waits
            self._stray_acks[(src, dst)] = (i, t, named)
            if not self._carried[named] and self.party in (None, src):
                # nor anything at all, so far: an ACK of nothing, unless a datagram with that
                # number is read within the reorder grace (``_ack_of_nothing``)
                self._nothing[i] = (src, dst, named, t)
                self._timers.at(t + SEQ_GAP_GRACE_NS, self._ack_of_nothing, i)

    def _ack_of_nothing(self, now: int, i: int) -> None:
        """MCP-ACK-2 ("the acknowledged message's sequence number"), on a trace complete for
        the ACK's sender (its own, or every node's): ACK ``i`` names a number that no datagram
        in the trace carried up to the ACK's reorder grace (``seq_reorder_grace_s``: a copy
        read just after the ACK may be what it answers) or, where the trace ends sooner, up to
        its end (a complete trace holds every datagram, however it was recorded), so it
        acknowledges no message. A number some datagram carried -- another node's message, an
        ACK, a malformed one -- is not proven so: the ACK may answer that, wrongly addressed
        (MCP-ACK-3/4/5/6's)."""
        pending = self._nothing.pop(i, None)
        if pending is None:
            return
        src, dst, named, t = pending
        if self._carried[named]:
            return
        self._emit("MCP-ACK-2", src, now, "the ACK names the acknowledged message's seq (D-2)",
                   f"ACK to ID {dst} names {named}: no datagram in the trace carried that number "
                   f"(it acknowledges no message)", [(i, t)])

    def _may_answer_a_copy(self, src: int, dst: int, other: Any, named: int, i: int, t: int) -> bool:
        """MCP-ACK-6 on trial: ACK ``i`` from ``src`` names the number an ACK of ``dst``'s took (D-5),
        yet a copy of a message from ``dst`` to ``src`` came before it (within ``late_ack_wait_ns``,
        however late an answer) and has drawn no ACK naming its number: the ACK may be that copy's
        answer with a wrong number (MCP-ACK-2) as well as an ACK of the ACK. Each explanation
        breaks another rule (D-9's principle), so neither is proven by it: held on the copy
        (``_ambiguous``, as a stray ACK of it) until the copy's deadline, where an ACK naming the
        copy's number decides that the copy was answered and this ACK named what it ACKed
        (``_undecided_deadline``). The C++ manager whose ACKs name the copy's seq + 1: a
        Mission_Ready copy of 1307 ACKed 0.2 ms later naming 1308, the number the drone's ACK had
        taken 0.3 s before, was failed MCP-ACK-6 (tests/judge/test_ack6_wrong_seq_copy.py). True when held."""
        wait = late_ack_wait_ns(self.rto_ns, self.window_ns)
        pair = dst << 16 | src
        last = self._last_to.get(pair)
        if last is None or t - last > wait:  # no message from dst to src lately: nothing else it answers
            return False
        best: tuple[Any, tuple[int, int]] | None = None
        for key, ex in self._ex.items():
            if key >> 16 != pair or ex.bcast:
                continue
            copy = next((c for c in reversed(ex.copies) if c[1] <= t), None)
            if (copy is None or t - copy[1] > wait or any(a[1] >= copy[1] for a in ex.acks)
                    or (best is not None and best[1][1] >= copy[1])):
                continue
            best = (ex, copy)
        if best is None:
            return False
        ex, copy = best
        self._stray_acks[(src, dst)] = (i, t, named)
        self._ambiguous.setdefault(id(ex), (ex, []))[1].append((other, named, i, t))
        self._timers.at(copy[1] + wait, self._undecided_deadline, ex, copy)
        return True

    def _ack_of_what_is_not_acked(self, node: int, other: Any, named: int, i: int, t: int) -> None:
        if isinstance(other, _Exchange):
            if other.bcast:
                self._emit("MCP-ACK-4", node, t, "a broadcast message is not ACKed",
                           f"ACK of {other.describe()}", [other.copies[-1], (i, t)])
            else:
                self._emit("MCP-ACK-5", node, t, "no ACK of a message addressed to another ID",
                           f"ACK of {other.describe()}", [other.copies[-1], (i, t)])
            return
        kind, dst, j, tj, action = other
        if kind == "ack":
            if dst == node and self._complete_for(node):
                self._emit("MCP-ACK-6", node, t, "an ACK is never ACKed",
                           f"ACK of the ACK with seq {named} (datagram #{j})", [(j, tj), (i, t)])
        elif dst == node:
            self._emit(kind, node, t, _ROB_EXPECTED[kind],
                       f"ACK of malformed datagram #{j} (seq {named})", [(j, tj), (i, t)])

    def _acked(self, ex: _Exchange, node: int, i: int, t: int, tester: bool) -> None:
        """``node`` ACKed ``ex`` (the right answer)."""
        first = not ex.acks
        ex.acks.append((i, t))
        if not first:
            return
        acker = self._nodes.get(node) or self._node(node)
        action = ex.action
        if action == END:
            acker.end_acked = t
            self._end_acked(ex, acker, t)
        elif action == PASSTHROUGH:
            self._passthrough_acked(ex, acker, t)
        copies = ex.copies
        before = copies if copies[-1][1] <= t else ex.copies_before(t)
        complete = self._complete_for(ex.src, ex.dst)
        if complete and not ex.bcast and not ex.tester:
            # MCP-RTX-1 observed: a unicast retransmitted until ACKed, judged now, not at its
            # deadline (``_rtx_expire``), which a trace that ends sooner never reaches: a side-by-
            # side run and a serial one of the same manager disagreed on "passed"
            self._nodes[ex.src].seen.add("MCP-RTX-1")
        if complete and len(before) > 1 and action != END:
            # copies that left before this ACK came back (a slow answer, a loaded host) are each
            # owed an ACK too: until they have them, an ACK naming what the node must not ACK
            # may be one of theirs with a wrong number (``_owed_deadline`` decides; CI under
            # load judged a copy's ACK naming N+1, the next message, to drone 2, MCP-ACK-5)
            ex.owed = len(before)
            self._waiting_copy[(ex.dst, ex.src)] = ex
            self._timers.at(t + late_ack_wait_ns(self.rto_ns, self.window_ns), self._owed_deadline, ex, before[-1])
        if complete and len(before) >= 3 and not ex.tester:
            self._judge_spacing(ex, before, t)
        if ex.addr is not None:
            key = (ex.src, node)
            addrs = self._acked_addrs.get(key)
            if addrs is None:
                self._acked_addrs[key] = {ex.addr}
            elif ex.addr not in addrs:
                addrs.add(ex.addr)
                acker.seen.add("MCP-TRN-2")  # ACKed from two source addresses
        if tester:
            return
        if "MCP-ACK-1" not in acker.seen:
            acker.seen.update(("MCP-ACK-1", "MCP-ACK-2", "MCP-ACK-3"))
        self._acks_to.add(ex.src)
        if complete and len(before) == 1:
            lat = t - before[0][1]
            samples = self._latency.get(node)
            if samples is None:
                samples = self._latency[node] = [[], (0, ())]
            samples[0].append(lat)
            if lat > samples[1][0]:  # the slowest, as evidence
                samples[1] = (lat, (before[0], (i, t)))

    def _maybe_wrong_ack(self, dst: int, src: int, named: int, i: int, t: int) -> None:
        """An ACK to ``dst`` that must not end its pending message: the wrong seq from the
        message's destination, or its seq from another node (input of MCP-RTX-2)."""
        self._unmatched_acks[(src, dst)] = (i, t)  # what a later message to src may take (stale_ack)
        self._wrong_for_pending(dst, src, named, i, t)

    def _wrong_for_pending(self, dst: int, src: int, named: int, i: int, t: int, silence: bool = True) -> None:
        """An ACK from ``src`` naming ``named`` that must not end ``dst``'s pending message,
        noted on it (``_Exchange.wrong_at``: what a sender moving on at once took) and, with
        ``silence``, its MCP-RTX-2 deadline (no copy after it)."""
        node = self._nodes.get(dst)
        pending = node.last_unicast if node is not None else None
        if pending is None or pending.acks or pending.tester or pending.flags & F_FAULTY:
            return
        if (pending.dst == src) == (pending.seq == named):
            return
        pending.wrong_at = {**(pending.wrong_at or {}), WRONG_SEQ if pending.dst == src else WRONG_SRC: (i, t)}
        if silence and self._complete_for(pending.src, pending.dst):
            g = gaps(pending.copies)
            est = median(g) if g else self.rto_ns
            self._timers.at(t + 3 * est // 2 + 3 * JITTER_NS, self._wrong_ack_deadline, pending, (i, t))

    # ------------------------------------------------------------------ missing ACKs
    def _copy_received(self, ex: _Exchange, i: int, t: int) -> None:
        """MCP-ACK-1 deadlines for a copy (complete trace only)."""
        if not self._complete_for(ex.src, ex.dst) or ex.bcast:
            return
        if not ex.acks:
            if len(ex.copies) - ex.heard == MAX_ACK_COPIES:
                self._timers.at(t + self.window_ns, self._ack_deadline, ex, None)
        elif ex.action != END:  # ACKed again, however late (latency is MCP-ACK-7's business)
            self._waiting_copy[(ex.dst, ex.src)] = ex
            self._timers.at(t + late_ack_wait_ns(self.rto_ns, self.window_ns), self._ack_deadline, ex, (i, t))
        else:  # D-6: no MCP-ACK-1 for End_Mission's copies after its ACK, yet an ACK while one
            # waits, naming what the node must not ACK, may be its wrong ACK (``_ack``)
            self._waiting_copy[(ex.dst, ex.src)] = ex
            self._timers.at(t + late_ack_wait_ns(self.rto_ns, self.window_ns), self._undecided_deadline, ex, (i, t))

    def _ack_rearm(self, now: int, ex: _Exchange) -> None:
        """``ex``'s receiver showed itself only at ``now``, after ``ex``'s ACK-1 deadline: it
        may not have been running yet (a node started after the message was first sent), so
        the copies before ``now`` but the last went unheard; MCP-ACK-1 counts the copies from
        the last of them (as it would have for a message first sent then)."""
        if ex.acks:
            return
        ex.heard = max(0, len(ex.copies_before(now)) - 1)
        if len(ex.copies) - ex.heard >= MAX_ACK_COPIES:
            self._timers.at(ex.copies[ex.heard + MAX_ACK_COPIES - 1][1] + self.window_ns, self._ack_deadline, ex, None)

    def _receiving(self, node: _Node, ex: _Exchange) -> bool:
        """D-6: a drone receives between its Mission_Ready and the ACK of its End_Mission and
        is judged on the manager's commands; the manager on the drones' messages."""
        if node.id == MANAGER:
            return ex.src != MANAGER
        if ex.src != MANAGER or node.ready is None or ex.first[1] < node.ready[1]:
            return False
        return node.end_acked is None or ex.first[1] < node.end_acked

    def _ack_deadline(self, now: int, ex: _Exchange, copy: tuple[int, int] | None) -> None:
        node = self._nodes.get(ex.dst)
        if node is None or not node.real:
            if ex.dst not in self._tester_ids:  # judged once it shows it is a node, not the harness
                self._on_real.setdefault(ex.dst, []).append((self._ack_rearm, (ex,)))
            return
        if not self._receiving(node, ex):
            return
        if ex.flags & F_ACK1:  # reported: the ACKs that came while this copy waited are decided
            self._undecided_deadline(now, ex, copy)  # only, never reported as its wrong ACKs again
            return
        if copy is None:
            if ex.acks:
                return
            ex.flags |= F_ACK1
            acked_from = self._acked_addrs.get((ex.src, ex.dst), set())
            if ex.addr is not None and acked_from and ex.addr not in acked_from:
                host, port = ex.addr
                self._emit("MCP-TRN-2", node.id, now, "a datagram accepted whatever its source address",
                           f"no ACK of {len(ex.copies)} copies of {ex.describe()} from {host}:{port}; "
                           f"its messages from {', '.join(f'{h}:{p}' for h, p in sorted(acked_from))} "
                           "are ACKed", ex.copies[:MAX_ACK_COPIES])
                return
            stray = self._stray_acks.get((node.id, ex.src))
            if stray is not None and stray[1] >= ex.first[1]:  # ACKs came, naming another seq
                self._emit("MCP-ACK-2", node.id, now, f"the ACK names the message's seq {ex.seq} (D-2)",
                           f"{len(ex.copies)} copies of {ex.describe()} answered by ACKs naming "
                           f"another seq (the last: {stray[2]})", [ex.copies[0], (stray[0], stray[1])])
                return
            if self._reacked_since(node.id, ex.src, ex.first[1]):
                return  # a re-ACK of another message came: the copies' wrong ACK, or none (D-9)
            # a Mission_Ready the manager never ACKs is MCP-ACK-1's too, as the manager-role
            # case judges it (one judge); MCP-FLOW-2 judges the Start_Mission that follows
            heard = ex.copies[ex.heard:]
            self._emit("MCP-ACK-1", node.id, now, f"an ACK of {ex.describe()} within {MAX_ACK_COPIES} copies",
                       f"no ACK of {len(heard)} copies" + (f" (and {ex.heard} before the node showed itself)"
                                                           if ex.heard else ""), heard[:MAX_ACK_COPIES])
            return
        after = [a for a in ex.acks if a[1] >= copy[1]]
        if after:
            if all(a[0] in self._doubtful for a in after):
                # each may be another copy's wrong ACK: whether the copy was ACKed (and the
                # ACKs that came while it waited named what they ACKed, MCP-ACK-4/5) or ACKed
                # wrongly (MCP-ACK-2) is not proven either way (a scheduled run of the sample
                # node acking copies with the seq plus 1: a copy of 1326 answered "1327", the
                # seq of a WP_Off to drone 2, then a copy of 1325 answered "1326")
                self._ambiguous.pop(id(ex), None)
                return
            self._decide_ambiguous(ex, node.id, wrong=False)  # they named what they ACKed
            return
        stray = self._stray_acks.get((node.id, ex.src))
        if stray is not None and stray[1] >= copy[1]:  # an ACK came, naming another seq
            ex.flags |= F_ACK1
            self._decide_ambiguous(ex, node.id, wrong=True)  # the copy's wrong ACKs
            self._emit("MCP-ACK-2", node.id, now,
                       f"the ACK of every copy names the copy's seq {ex.seq} (D-2)",
                       f"the copy of {ex.describe()} was answered by an ACK naming {stray[2]}",
                       [copy, (stray[0], stray[1])])
            return
        if self._reacked_since(node.id, ex.src, copy[1]):
            # a re-ACK of another message came after the copy (D-9: no rule forbids it): it may
            # be the copy's wrong ACK (MCP-ACK-2) or the copy went unanswered (MCP-ACK-1);
            # neither is proven, nor what the ACKs that came while it waited answered
            self._ambiguous.pop(id(ex), None)
            return
        maybe = ex.maybe_answered
        if maybe is not None and maybe[1] >= copy[1]:
            # an ACK came after the copy that was counted as another message's copy's (its
            # number, while that copy waited too: the doubtful ACK of ``_ack``): it may have
            # answered this copy with a wrong seq. Neither rule is proven by this copy: not
            # MCP-ACK-1 (an ACK came), not MCP-ACK-2 (it may be the other copy's). CI under
            # load, the ack-copies-wrong-seq node: a copy of 1326 answered "1327" while 1327's
            # copy waited was judged unACKed, beside the node's proven MCP-ACK-2
            self._decide_ambiguous(ex, node.id, wrong=False)
            return
        ex.flags |= F_ACK1
        self._decide_ambiguous(ex, node.id, wrong=False)
        self._emit("MCP-ACK-1", node.id, now, "every later copy is ACKed again",
                   f"copy of {ex.describe()} after its ACK was not ACKed", [ex.acks[0], copy])

    def _reacked_since(self, node: int, dst: int, since: int) -> bool:
        """``node`` sent ``dst`` a re-ACK at or after ``since``: an ACK naming a message every copy
        of which had drawn an ACK (``_ack``)."""
        r = self._reacks.get((node, dst))
        return r is not None and r[1] >= since

    def _undecided_deadline(self, now: int, ex: _Exchange, copy: tuple[int, int] | None) -> None:
        """The ACKs naming what the node must not ACK that came while a copy of ``ex`` waited,
        where no rule of the copy's is judged (End_Mission's copies after its ACK, D-6; a copy
        of a message already reported, F_ACK1): the copy answered by an ACK naming its seq,
        they named what they ACKed (MCP-ACK-4/5/6); else each may be the copy's wrong ACK
        (MCP-ACK-2) as well as an ACK of what it named, and neither is proven."""
        if id(ex) not in self._ambiguous:
            return
        since = copy[1] if copy is not None else ex.last_t
        if any(a[1] >= since and a[0] not in self._doubtful for a in ex.acks):
            self._decide_ambiguous(ex, ex.dst, wrong=False)
        else:
            self._ambiguous.pop(id(ex), None)

    def _owed_deadline(self, now: int, ex: _Exchange, copy: tuple[int, int]) -> None:
        """The ACKs owed to ``ex``'s copies sent before its first ACK came back: all came, so an
        ACK naming something else meanwhile was an ACK of that; or not (a copy's wrong ACK, or
        a starved node's late one beside a real ACK of an ACK): nothing is proven either way."""
        if id(ex) not in self._ambiguous:
            return
        self._decide_ambiguous(ex, ex.dst, wrong=len(ex.acks) < ex.owed and not ex.flags & F_ACK1)

    def _decide_ambiguous(self, ex: _Exchange, node: int, *, wrong: bool) -> None:
        """The ACKs naming what ``node`` must not ACK that came while a copy of ``ex`` waited:
        ``wrong`` (the copy was not ACKed, an ACK naming another seq came): they were the
        copy's wrong ACKs, judged as MCP-ACK-2 by the caller; else ACKs of what they named."""
        for other, named, i, t in self._ambiguous.pop(id(ex), (ex, []))[1]:
            if not wrong:
                self._ack_of_what_is_not_acked(node, other, named, i, t)

    def _answered_later(self, end: int) -> None:
        """MCP-ACK-1 ("every later copy is ACKed again") of a copy whose deadline
        (``late_ack_wait_ns``: an ACK however late) lies past the trace's end: judged at the end
        when its ACK window passed before it and the node answered, meanwhile, a datagram from
        the same sender that reached it after the copy -- it had read past the copy (a socket
        is read in order) and answered what came next, not the copy (the ack-first-copy-only
        drone's copies of Start_Mission and WP_List, its view ending 0.6 s after its last ACK:
        seed monitor-ack1-missed-copy-after-answer). Else the trace may just end too soon."""
        waiting = [args for _t, _o, fn, args in self._timers.heap
                   if fn == self._ack_deadline and args[1] is not None]
        for ex, copy in sorted(waiting, key=lambda a: a[1][1]):
            if (end - copy[1] >= self.window_ns
                    and self._answered_to.get((ex.dst, ex.src), -1) > copy[1]):
                self._ack_deadline(end, ex, copy)

    def _finish_receiver(self, end: int) -> None:
        """Observations of the receiver-side rules, and MCP-ACK-7's medians."""
        self._answered_later(end)
        for i in list(self._nothing):  # ACKs of nothing within the grace of the trace's end
            self._ack_of_nothing(end, i)
        for ex, _ in list(self._ambiguous.values()):  # the trace ended before a copy's deadline
            # undecided unless the copy was answered: one of the ACKs may be its wrong ACK (the
            # ack-copies-wrong-seq drone ACKed a copy of 20357 naming 20358, the number the
            # manager's ACK read 0.4 s before had taken, and was failed MCP-ACK-6 with the
            # copy's ACK never judged: seed monitor-ack6-ack-before-its-number)
            self._undecided_deadline(end, ex, None)
        for node in self._nodes.values():
            if not node.real:
                continue
            nid = node.id
            if any(s != nid for s in self._bcast_srcs):
                self._observe(nid, "MCP-ACK-4")
            if self._unicast_dsts - {nid}:
                self._observe(nid, "MCP-ACK-5")
            if nid in self._acks_to:
                self._observe(nid, "MCP-ACK-6")
            for rule, dsts in self._rob_dsts.items():
                if nid in dsts:
                    self._observe(nid, rule)
            samples, slowest = self._latency.get(nid, [[], (0, ())])
            if len(samples) >= ACK_SAMPLES:
                self._observe(nid, "MCP-ACK-7")
                med = median(samples)
                if med > ACK_DEADLINE_NS:
                    self._emit("MCP-ACK-7", nid, end, f"median ACK latency within {fmt_ms(ACK_DEADLINE_NS)}",
                               f"median {fmt_ms(med)} over {len(samples)} ACKs (slowest "
                               f"{fmt_ms(slowest[0])})", slowest[1])

"""Sender-side rules of the trace monitor: what a node *sent* breaks the rule.

HDR-3/4/5 and the PAY rules judge one datagram; SEQ-1/2, RTX-1..4 and BLK-1 judge a
sender's messages against each other; BLK-2/3/6 and FLOW-1..6 judge the manager's commands
against the mission. A rule that needs an absence (no retransmission, a command never
sent) is judged only on a complete trace (``Monitor(complete=True)``) and only when its
deadline falls inside the trace.
"""

from __future__ import annotations

from typing import Any

from mcp_conform.judge._monitor_base import (
    DRONE_SENDS,
    END,
    HDR,
    JITTER_NS,
    MANAGER,
    MANAGER_SENDS,
    MIN_COPIES,
    MR,
    NS,
    OBSTACLES,
    PASSTHROUGH,
    PAYLOAD_RULE,
    RTX_MIN_GAP_NS,
    START,
    WP_LIST,
    WP_OFF,
    WP_ON,
    _Exchange,
    _Node,
    action_name,
    fmt_ms,
)
from mcp_conform.judge._monitor_mission import _LIST_FLOW, MissionRules
from mcp_conform.judge._monitor_rtx import (
    F_FAULTY,
    F_GAVE_UP,
    F_INTERLEAVE,
    F_RTX1,
    F_RTX3,
    F_RTX4,
    F_SILENT,
    F_STORM,
)
from mcp_conform.spec import SPEC

#: how long after a new message the numbers its ACKs took may still be read (MCP-SEQ-1): a
#: node's datagrams to different peers reach a recorder's sockets in an order of the host's
#: choosing, so the ACK that took the number before a message may be read just after it; and
#: one numbered after a message may be read this long before it (a sender whose receive
#: thread ACKs between its main thread's taking a number and sending the message)
SEQ_GAP_GRACE_NS = int(float(SPEC.params["seq_reorder_grace_s"]) * NS)
_CHALLENGE_OF = {WP_LIST: 1, WP_ON: 2, WP_OFF: 2, OBSTACLES: 3}
_ITEM_ACTIONS = (WP_LIST, WP_ON, OBSTACLES)


class SenderRules(MissionRules):
    """Mixin of :class:`judge.monitor.Monitor`: sender-side judgement."""

    # ------------------------------------------------------------------ bookkeeping
    def _remember(self, src: int, seq: int, entry: Any) -> None:
        """What ``src`` last sent with ``seq`` (an exchange, or a tuple for a malformed
        datagram): the receiver side looks here to learn what an ACK answers."""
        self._by_seq[src << 16 | seq] = entry

    def _message(self, i: int, t: int, src: int, dst: int, seq: int, action: int, data: bytes,
                 payload: Any, tester: bool, addr: Any = None) -> None:
        """A well-formed non-ACK message: a copy of a known one, or a new message."""
        key = src << 32 | dst << 16 | seq  # ints: cheap to hash, not tracked by the GC
        ex = self._ex.get(key)
        pair = src << 16 | dst
        last_to = self._last_to.get(pair)
        self._last_to[pair] = t
        if ex is None or t - ex.last_t > self.horizon_ns:
            ex = self._late_copy(pair, key, seq, data, tester)
        if ex is not None:
            self._copy(ex, i, t, data, tester)
            return
        bcast = dst == self.broadcast_id
        ex = _Exchange(src, dst, seq, action, data, payload, i, t, tester, bcast, self._rd)
        ex.addr = addr
        stale = self._unmatched_acks.get((dst, src)) if not bcast else None
        if stale is not None and (last_to is None or stale[1] > last_to) and t - stale[1] <= self._ack_horizon:
            ex.stale_ack = stale  # an ACK from dst already there, that nothing since answered
        self._ex[key] = ex
        self._by_seq[src << 16 | seq] = ex
        if not tester:
            self._latest_to[pair] = ex
        if bcast:
            self._bcast_srcs.add(src)
        else:
            self._unicast_dsts.add(dst)
            if self._complete_for(src, dst):  # MCP-ACK-3: the latest message to dst with seq
                self._to_seq[dst << 16 | seq] = ex
        if action == PASSTHROUGH:
            self._track_passthrough(ex)
        if not tester:
            self._judge_new(ex, i, t)
        self._track_mission(ex)

    def _late_copy(self, pair: int, key: int, seq: int, data: bytes, tester: bool) -> _Exchange | None:
        """The message a datagram past the horizon is a copy of, if any: its sender's latest
        message to that receiver when the datagram repeats its number and bytes, however late
        (MCP-DUP-1: "the same (src, seq) as the one last delivered from that src is a
        duplicate", with no time limit; MCP-SEQ-2: a retransmission repeats them). A new
        message can take a number again only after its sender took others for that receiver
        (the numbers wrapped, or it restarted); until then the copy is the explanation the
        trace cannot exclude -- its sender retransmits for its retry limit, which the monitor
        does not know, and the link may hold each copy several seconds: at ``--rto 5``, 20
        retries and 2.5-10 s delays a drone's last Mission_Ready reached the manager 115 s
        after its first, and taken for a restart it made the manager's Start_Mission, sent
        between the two, a false MCP-BLK-2 (seed monitor-blk2-manager-long-delays). The
        harness's own datagrams are recorded as sent: none comes late. The message is the
        monitor's again (its ACKs are matched, its copies judged)."""
        ex = self._latest_to.get(pair)
        if tester or ex is None or ex.seq != seq or ex.data != data:
            return None
        self._ex[key] = ex
        self._by_seq[ex.src << 16 | seq] = ex
        if not ex.bcast and self._complete_for(ex.src, ex.dst):
            self._to_seq[ex.dst << 16 | seq] = ex
        return ex

    def _copy(self, ex: _Exchange, i: int, t: int, data: bytes, tester: bool) -> None:
        """Another datagram with the same (src, dst, seq): a retransmission (MCP-SEQ-2)."""
        src = ex.src
        if data != ex.data:
            if not tester:
                rule = "MCP-SEQ-1" if ex.acks else "MCP-SEQ-2"
                expected = ("a new message takes a new sequence number" if ex.acks else
                            "a retransmission repeats the original's bytes exactly")
                self._emit(rule, src, t, expected,
                           f"{ex.describe()} sent again with different bytes", [ex.first, (i, t)])
            return
        prev_t = ex.last_t
        ex.copies.append((i, t))
        ex.run_delays.append(self._rd)
        ex.last_t = t
        self._copy_received(ex, i, t)
        if tester:
            return
        node = self._nodes[src]
        node.seen.add("MCP-SEQ-2")
        if ex.wrong_at is not None and not ex.acks:
            for kind, (_, wrong_t) in ex.wrong_at.items():
                if t - wrong_t > JITTER_NS:  # retransmitted after reading it: not taken
                    node.ignores |= kind
        if len(ex.copies) == MIN_COPIES and not ex.acks and not ex.bcast:
            node.seen.add("MCP-RTX-1")  # the copies the rule asks for, seen: on any trace
        if ex.bcast:
            if not ex.flags & F_RTX4:
                ex.flags |= F_RTX4
                self._emit("MCP-RTX-4", src, t, "a broadcast message is sent once",
                           f"{ex.describe()} sent again", [ex.first, (i, t)])
            return
        if t - prev_t < RTX_MIN_GAP_NS and not ex.flags & (F_STORM | F_RTX3):
            ex.flags |= F_STORM
            self._emit("MCP-RTX-3", src, t, f"no gap between copies under {fmt_ms(RTX_MIN_GAP_NS)}",
                       f"copies of {ex.describe()} {fmt_ms(t - prev_t)} apart", ex.copies[-2:])
        newer = node.last_unicast
        if (newer is not None and newer is not ex and not ex.acks and newer.first[1] > prev_t
                and not ex.flags & F_INTERLEAVE):
            ex.flags |= F_INTERLEAVE
            self._stop_and_wait(ex, newer, t, [ex.copies[-2], newer.first, (i, t)],
                                "while it still retransmitted")

    # ------------------------------------------------------------------ new messages
    def _judge_new(self, ex: _Exchange, i: int, t: int) -> None:
        src, action = ex.src, ex.action
        node: _Node = self._nodes[src]
        if action not in node.actions:  # what a message of this kind shows, observed once
            node.actions.add(action)
            self._first_of_kind(node, ex)
        allowed = MANAGER_SENDS if src == MANAGER else DRONE_SENDS
        if action not in allowed:
            self._emit("MCP-HDR-5", src, t,
                       "the manager never sends Mission_Ready" if src == MANAGER else
                       "a drone sends only Mission_Ready and ACK",
                       f"{ex.describe()}", [(i, t)])
            return
        prev = node.last_new  # MCP-SEQ-1
        node.last_new = ex
        if prev is not None:
            self._check_seq(node, prev, ex, i, t)
        node.acks_since = 0
        taken = node.taken
        while taken and taken[0][0] < t - SEQ_GAP_GRACE_NS:
            taken.popleft()
        node.taken_before = tuple(seq for _, seq in taken)  # read before ex, within the grace
        if action == MR:
            self._judge_ready(node, ex, i, t)
        else:
            self._judge_command(node, ex, i, t)
        if not ex.bcast:
            prev = node.last_unicast  # MCP-BLK-1
            if prev is not None:
                node.seen.add("MCP-BLK-1")
                if not prev.acks and self._complete_for(node.id):
                    self._check_stop_and_wait(node, prev, ex, i, t)
            node.last_unicast = ex
            if self._complete_for(ex.src, ex.dst):  # MCP-RTX-1's deadline; all share one delay, so a FIFO
                self._timers.after(t + self._rtx_delay, self._rtx_expire, ex)

    def _first_of_kind(self, node: _Node, ex: _Exchange) -> None:
        """Rules a node's first new message of a kind shows observed (not yet passed: a
        rule is passed at the end when observed and never violated)."""
        src, action = node.id, ex.action
        rules = ["MCP-HDR-1", "MCP-HDR-2", "MCP-HDR-3", "MCP-HDR-5"]
        if self.drones is not None and (src == MANAGER or src in self.drones):
            rules.append("MCP-HDR-4")
        if node.first_seq is None:
            node.first_seq = ex.seq
            rules.append("MCP-SEQ-4")
        if action == MR:
            rules += ["MCP-PAY-2", "MCP-FLOW-1"]
        elif action in (START, END, WP_OFF):
            rules.append("MCP-PAY-1")
        elif action == PASSTHROUGH:
            rules.append("MCP-PAY-6")
        elif action in _ITEM_ACTIONS:
            rules += ["MCP-PAY-5" if action == WP_ON else "MCP-PAY-3", "MCP-PAY-4", "MCP-PAY-7"]
        if src == MANAGER and action != MR:
            if self.inferred_challenge is None and action in _CHALLENGE_OF:
                self.inferred_challenge = _CHALLENGE_OF[action]
            challenge = self.challenge or self.inferred_challenge
            if action in _LIST_FLOW and challenge == _LIST_FLOW[action][1]:
                rules.append(_LIST_FLOW[action][0])
            elif action in (WP_ON, WP_OFF) and challenge == 2:
                rules.append("MCP-FLOW-5")
            elif action == END:
                rules.append("MCP-BLK-6")
        for rule in rules:
            self._observe(src, rule)

    def _check_seq(self, node: _Node, prev: _Exchange, ex: _Exchange, i: int, t: int) -> None:
        """MCP-SEQ-1: between two new non-ACK messages the number advances by at least 1 and
        at most 1 + the ACKs sent in between (D-5). On a lossy trace only a repeat is proof.
        The numbers are judged, not the order they were read in: a number skipped may be one
        an ACK took that was read within the grace before ``prev`` (a sender's threads, or
        the recorder's sockets, put the ACK first) or after ``ex`` (``_seq_number_taken``)."""
        acks = node.acks_since
        node.seen.add("MCP-SEQ-1")
        adv = (ex.seq - prev.seq) & 0xFFFF
        if adv > 1 + acks:  # numbers taken by ACKs read just before prev, in the gap
            early = {s for s in node.taken_before if 0 < (s - prev.seq) & 0xFFFF < adv}
            acks += len(early)
        if adv == 0 or (self._complete_for(node.id) and adv > 1 + acks):
            report = ("MCP-SEQ-1", node.id, t,
                      f"seq {(prev.seq + 1) & 0xFFFF}..{(prev.seq + 1 + acks) & 0xFFFF} "
                      f"(previous message {prev.seq}, {acks} ACK(s) since)",
                      f"{ex.describe()}", [prev.first, (i, t)])
            if adv == 0:
                self._emit(*report)
                return
            # numbers skipped: ACKs read within the grace that carry them explain the gap
            gap = [prev.seq, ex.seq, adv - 1 - acks, report]
            node.seq_gap = gap
            self._timers.at(t + SEQ_GAP_GRACE_NS, self._seq_gap_deadline, node, gap)

    def _seq_number_taken(self, node: _Node, seq: int, t: int) -> None:
        """``node`` sent an ACK (or a malformed datagram) numbered ``seq`` at ``t``: it explains
        one number of a pending MCP-SEQ-1 gap it falls in, else it counts for the next gap
        (and, by its number, for the gap after the next new message: read before it)."""
        taken = node.taken
        while taken and taken[0][0] < t - SEQ_GAP_GRACE_NS:
            taken.popleft()
        taken.append((t, seq))
        gap = node.seq_gap
        if gap is not None and 0 < (seq - gap[0]) & 0xFFFF < (gap[1] - gap[0]) & 0xFFFF:
            gap[2] -= 1
            if gap[2] <= 0:
                node.seq_gap = None
            return
        node.acks_since += 1

    def _seq_gap_deadline(self, now: int, node: _Node, gap: list[Any]) -> None:
        if node.seq_gap is gap:
            node.seq_gap = None
            self._emit(*gap[3])

    def _finish_sender(self, end: int) -> None:
        if self._complete_for(MANAGER):
            self._finish_blk2(end)
            self._finish_flow3(end)
            for ex in self._ex.values():
                if not ex.tester and not ex.bcast and not ex.acks and len(ex.copies) >= 3:
                    self._judge_spacing(ex, ex.copies, end)

    # ------------------------------------------------------------------ malformed
    def _malformed(self, i: int, t: int, src: int, dst: int, seq: int, action: int, rule: str,
                   tester: bool, why: str) -> None:
        """A framed datagram that is not a valid message. As input, ``rule`` (MCP-ROB-3/4) is
        the receiver's; as output, the sender broke MCP-HDR-3 or its payload rule."""
        self._remember(src, seq, (rule, dst, i, t, action))
        self._rob_dsts[rule].add(dst)
        if tester:
            return
        self._seq_number_taken(self._nodes[src], seq, t)  # it took a number (MCP-SEQ-1 allows for it)
        if rule == "MCP-ROB-3":
            self._observe(src, "MCP-HDR-3")
            self._emit("MCP-HDR-3", src, t, "action codes 0-8 only (9 'Any' is API-only)",
                       f"datagram #{i} with {why}", [(i, t)])
            return
        allowed = MANAGER_SENDS if src == MANAGER else DRONE_SENDS
        if action not in allowed:
            self._emit("MCP-HDR-5", src, t, "a drone sends only Mission_Ready and ACK"
                       if src != MANAGER else "the manager never sends Mission_Ready",
                       f"malformed {action_name(action)} seq {seq}", [(i, t)])
            return
        prule = PAYLOAD_RULE[action]
        self._observe(src, prule)
        if src == MANAGER and dst != self.broadcast_id and dst != MANAGER:
            # the manager's latest command to dst, malformed: whether dst ACKed it is not tracked,
            # so MCP-FLOW-3 leaves dst undecided (a manager giving up on a drone that rightly
            # did not ACK its malformed list is not also blamed for the missing End_Mission)
            self._node(dst).last_command = None
            if action == WP_ON and (src, dst, seq, action) not in self._malformed_seen:
                self._node(dst).wp_items.append(None)  # MCP-PAY-5's: every waypoint not judged
        if (src, dst, seq, action) in self._malformed_seen:
            return  # a retransmission of the same malformed message: reported once
        self._malformed_seen.add((src, dst, seq, action))
        if src == MANAGER and action in _LIST_FLOW:
            self._malformed_lists.add((dst, action))  # sent, if malformed: not missing (MCP-FLOW-4/6)
        self._emit(prule, src, t, f"a {action_name(action)} payload as the spec lays it out",
                   f"{action_name(action)} seq {seq} to ID {dst}: {why}", [(i, t)])

    # ------------------------------------------------------------------ the mission
    def _judge_ready(self, node: _Node, ex: _Exchange, i: int, t: int) -> None:
        """MCP-FLOW-1 / MCP-PAY-2: Mission_Ready is unicast to ID 0; MCP-BLK-5 (vehicle)."""
        if ex.dst != MANAGER:
            ex.flags |= F_FAULTY  # what follows from the wrong destination is not judged again
            self._emit("MCP-FLOW-1", node.id, t, f"Mission_Ready unicast to ID {MANAGER}",
                       f"{ex.describe()}", [(i, t)])
        self._check_ready_fix(node, i, t)

    def _judge_command(self, node: _Node, ex: _Exchange, i: int, t: int) -> None:
        """The manager's commands against the mission: PAY-7, FLOW-2..6, BLK-6."""
        if self._insane and ex.action in _ITEM_ACTIONS:
            problem = self._insane.get(ex.data[HDR:])
            if problem is not None:
                self._emit("MCP-PAY-7", MANAGER, t, "sane mission items", f"{ex.describe()}: {problem}",
                           [(i, t)])
        if node.first_command is None:
            node.first_command = (i, t)
        if not ex.bcast:
            self._judge_for_drone(self._nodes.get(ex.dst) or self._node(ex.dst), ex, i, t)
            return
        if ex.action == START:
            for d in [n for n in self._nodes.values() if n.id != MANAGER and n.ready is not None]:
                self._judge_for_drone(d, ex, i, t)
            return
        waiting = self._broadcast_to_every_drone(ex, i, t)  # MCP-BLK-3/6
        on = self._on_mission(t) + waiting  # D-11: a command to each of them; its items judged once
        for d in on:
            self._judge_for_drone(d, ex, i, t, items=False)
        if ex.action == WP_ON and on or ex.action in _LIST_FLOW and any(ex.action not in d.lists for d in on):
            self._judge_items(ex, i, t)

    def _on_mission(self, t: int) -> list[_Node]:
        """D-11: the drones whose mission is on at ``t``, a broadcast then a command to each (MCP-
        FLOW-4/5/6): Start_Mission answered before ``t`` (ACKed, or by an ACK the manager may have
        taken for it, MCP-RTX-2's business; a broadcast at the ACK's own time was sent before the
        ACK could reach the manager), no End_Mission sent to it yet."""
        out = []
        for d in self._nodes.values():
            s = d.start
            answer = None if s is None or d.end is not None else s.acks[0] if s.acks else self._taken_ack(s)
            if answer is not None and answer[1] < t and d.id != MANAGER:
                out.append(d)
        return out

    def _judge_for_drone(self, d: _Node, ex: _Exchange, i: int, t: int, items: bool = True) -> None:
        """``ex`` as a command to ``d``; ``items``: its items judged here (a broadcast's: once)."""
        action = ex.action
        if action == START:
            self._observe(MANAGER, "MCP-FLOW-2")
            if ex.bcast:
                self._emit("MCP-FLOW-2", MANAGER, t, "Start_Mission unicast to each drone",
                           f"{ex.describe()}", [(i, t)])
                return
        elif d.start is None and self._complete_for(MANAGER, d.id) and d.ready is not None and not ex.bcast:
            self._emit("MCP-FLOW-2", MANAGER, t, f"Start_Mission is the first command drone {d.id} gets",
                       f"{ex.describe()} before any Start_Mission", [d.ready, (i, t)])
        if d.end is not None and not ex.bcast:
            self._emit("MCP-BLK-6", MANAGER, t, f"no command to drone {d.id} after its End_Mission",
                       f"{ex.describe()}", [d.end.first, (i, t)])
            return
        challenge = self.challenge or self.inferred_challenge
        if action == WP_ON and items:
            self._judge_items(ex, i, t)
        elif action == WP_OFF:
            if challenge == 2 and d.wp_active is None and self._complete_for(MANAGER, d.id) and d.start is not None:
                self._emit("MCP-FLOW-5", MANAGER, t, "WP_Off follows a WP_On",
                           f"{ex.describe()} with no WP_On active for drone {d.id}", [(i, t)])
        elif action in _LIST_FLOW:
            rule, number = _LIST_FLOW[action]
            if challenge == number:
                earlier = d.lists.get(action)
                last = self._nodes[MANAGER].last_unicast
                if earlier is not None and last is not None and self._renumbered(last, ex):
                    return  # the list again under a new number, unACKed: MCP-SEQ-2's, not a second list
                if earlier is not None and earlier is not ex:
                    self._emit(rule, MANAGER, t, f"the mission's items as one {action_name(action)}",
                               f"a second {action_name(action)} to drone {d.id}"
                               + (" (a broadcast, D-11)" if ex.bcast or earlier.bcast else ""), [earlier.first, (i, t)])
                elif items:
                    self._judge_items(ex, i, t)
        elif action == END and challenge == 2:
            self._judge_every_waypoint(d, ex, i, t)
        elif action == END and self._complete_for(MANAGER, d.id) and self.challenge in (1, 3):
            want = WP_LIST if self.challenge == 1 else OBSTACLES
            rule = _LIST_FLOW[want][0]
            self._observe(MANAGER, rule)
            if want not in d.lists and d.start is not None and (d.id, want) not in self._malformed_lists:
                early = max((e for e in self._ex.values() if e.bcast and e.src == MANAGER and e.action == want),
                            key=lambda e: e.first[1], default=None)  # for the evidence: none of its (D-11)
                self._emit(rule, MANAGER, t, f"the mission's items as one {action_name(want)}",
                           f"End_Mission to drone {d.id} without any {action_name(want)}"
                           + (f" after its Start_Mission was ACKed ({early.describe()} came before it: "
                              "D-11)" if early is not None else ""),
                           [d.start.first] + ([early.first] if early is not None else []) + [(i, t)])

    def _track_mission(self, ex: _Exchange) -> None:
        """The mission as the trace shows it (whoever sent the commands)."""
        action = ex.action
        if action == MR and ex.src != MANAGER:
            node = self._nodes[ex.src] if ex.src in self._nodes else self._node(ex.src)
            prev = node.ready_ex
            if ex.tester and prev is not None and node.start is not None:
                return  # the harness's fresh Mission_Ready of a drone it plays, its mission under
                # way (a liveness probe of mcp-conform --role manager): no restart of that drone
            complete = self._complete_for(node.id, MANAGER)
            if prev is None or prev.acks or not complete:
                # its first Mission_Ready of a complete trace restarts no mission: a
                # Start_Mission the manager sent it before is MCP-BLK-2's, the mission it
                # started not forgotten (else MCP-FLOW-2 on each command after it)
                early = node.start if prev is None and complete else None
                _new_mission(node)
                node.start = early
                node.ready = ex.first
                node.ready_ex = ex
            return
        if ex.src != MANAGER or ex.bcast:
            if ex.src == MANAGER and action in (WP_ON, WP_OFF, *_LIST_FLOW):
                t = ex.first[1]  # D-11: to each drone whose mission is on (or, MCP-BLK-3's, starting)
                for d in self._on_mission(t) + self._awaiting_start(t):
                    if action in _LIST_FLOW:
                        d.lists.setdefault(action, ex)
                    else:
                        d.wp_active = ex if action == WP_ON else None
                        if action == WP_ON:
                            d.wp_items.append(ex.payload)
            return
        d = self._node(ex.dst)
        prev = d.last_command
        if prev is not None and not prev.acks and self._taken_ack(prev) is None:
            d.unanswered.append(prev)  # moved on from it unanswered (MCP-FLOW-5's excuse)
        d.last_command = ex
        if action != END:
            d.last_command_t = ex.first[1]
        if action == START and d.start is None:
            d.start = ex
        elif action == END and d.end is None:
            d.end = ex
        elif action in _LIST_FLOW:
            d.lists.setdefault(action, ex)
        elif action == WP_ON:
            d.wp_active = ex
            d.wp_items.append(ex.payload)
        elif action == WP_OFF:
            d.wp_active = None

    def _finish_blk2(self, end: int) -> None:
        """MCP-BLK-2 (complete trace): the manager's first command came after the
        Mission_Ready of every drone that took part (declared, or sent Start_Mission)."""
        mgr = self._nodes.get(MANAGER)
        if mgr is None or not mgr.real or mgr.first_command is None:
            return
        first = mgr.first_command
        drones = [n for n in self._nodes.values() if n.id != MANAGER
                  and (n.start is not None or (self.drones is not None and n.id in self.drones))]
        self._observe(MANAGER, "MCP-BLK-2")
        late = [n for n in drones if n.ready is None or n.ready[1] > first[1]]
        if late and all(n.ready is not None or n.start is not None for n in late):
            n = late[0]
            self._emit("MCP-BLK-2", MANAGER, first[1],
                       "no command before every drone of the mission sent Mission_Ready",
                       f"first command at datagram #{first[0]}; drone {n.id}'s Mission_Ready "
                       + ("came later" if n.ready is not None else "never came"),
                       [first] + ([n.ready] if n.ready is not None else []))

    def _finish_flow3(self, end: int) -> None:
        """MCP-FLOW-3 (complete trace): once the manager has ended the mission of some drones,
        every drone it started gets End_Mission (unless its last command was never ACKed or was
        malformed (``_malformed``), or the manager gave up on it before its ACK came: short of MCP-RTX-1's copies, that
        rule fails and a drone dropped after is its consequence; at its retry limit, F_GAVE_UP, none)."""
        mgr = self._nodes.get(MANAGER)
        if mgr is None or not mgr.real:
            return
        drones = [n for n in self._nodes.values() if n.id != MANAGER and n.start is not None
                  and not n.start.tester]
        ended = [n.end for n in drones if n.end is not None and n.end.acks]
        if not ended:
            return
        self._observe(MANAGER, "MCP-FLOW-3")
        last = max(e.acks[0][1] for e in ended)
        settle = 2 * max(self.rto_ns, self.window_ns, NS)
        if end - last < settle:
            return  # the trace may end while the manager is still ending missions
        busy = mgr.last_unicast
        if busy is not None and not busy.acks and (end - busy.last_t < settle or busy.flags & F_SILENT):
            return  # still retransmitting (an End_Mission to a drone that has gone): stop-and-
            # wait holds the next End_Mission, which a trace cut there cannot show (a deadline
            # after the end of the trace judges nothing); or it stopped retransmitting its
            # latest unicast and waits for that ACK still -- MCP-RTX-1, failed on it, and the
            # drones it never reached are stop-and-wait's consequence (the manager-rtx-none
            # manager's End_Mission to drone 2, lost, held drone 3's for 1,897 s)
        for n in drones:
            if n.end is None and self._last_command_acked(n):
                self._emit("MCP-FLOW-3", MANAGER, end, f"End_Mission as the last command to drone {n.id}",
                           f"drone {n.id} never got End_Mission (other drones did)",
                           [n.start.first] + [e.first for e in ended[:1]])  # type: ignore[union-attr]  # drones: n.start set

    def _last_command_acked(self, d: _Node) -> bool:
        last = d.last_command
        return last is not None and bool(last.acks) and not last.flags & (F_RTX1 | F_GAVE_UP)

    def _prune(self, now: int) -> None:
        """Forget messages older than the horizon (their copies can no longer come, their
        ACKs no longer be matched); judge what the end of the trace would have judged."""
        old = now - self.horizon_ns
        stale = [k for k, ex in self._ex.items() if ex.last_t < old]
        for k in stale:
            ex = self._ex.pop(k)
            if self._complete_for(ex.src, ex.dst) and not ex.tester and not ex.bcast and not ex.acks and len(ex.copies) >= 3:
                self._judge_spacing(ex, ex.copies, now)
        for k in [k for k, e in self._by_seq.items() if _entry_t(e) < old]:
            del self._by_seq[k]
        for k in [k for k, e in self._ack_seq.items() if e[2] < old]:
            del self._ack_seq[k]
        for k in [k for k, e in self._to_seq.items() if e.last_t < old]:
            del self._to_seq[k]
        for k in [k for k, e in self._last_to.items() if e < old]:
            del self._last_to[k]
        for pair in [k for k, e in self._unmatched_acks.items() if e[1] < old]:
            del self._unmatched_acks[pair]
        for index in (self._pt, self._pt_to):
            dead = []
            for k, lst in index.items():
                if lst[-1].last_t < old:
                    dead.append(k)
                elif lst[0].last_t < old:
                    lst[:] = [e for e in lst if e.last_t >= old]
            for k in dead:
                del index[k]


def _entry_t(entry: Any) -> int:
    return entry.last_t if isinstance(entry, _Exchange) else entry[3]


def _new_mission(node: _Node) -> None:
    """A drone's new Mission_Ready (a restart): its mission starts afresh."""
    node.start = node.end = None
    node.end_acked = None
    node.lists = {}
    node.wp_active = None
    node.wp_items = []
    node.unanswered = []
    node.last_new = None
    node.delivered_from = {}

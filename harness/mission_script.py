"""The scenarios the runner's drones play against a Mission Manager under test (``--role
manager``), each recorded in a :class:`harness.drone_players.Mission` the cases judge:

- ``main``: the drones announce readiness one by one; one drone sends a second
  Mission_Ready with a new seq (a manager that counts messages instead of drones starts
  early) and the last drone is held back while the receiver-side inputs are sent (ACK-1/4/
  5/6, ROB-*, TRN-2, each followed by a liveness probe); then the first Start_Mission's ACK
  is withheld for 3 copies (RTX-1/3, SEQ-2, BLK-1/3), the third answered as it arrives
  (MCP-RTX-1's "at least 3 copies while the ACK is withheld": a retry limit of 2, spec
  ``min_copies``, is not made to give up); then the next new unicast is withheld too, a
  wrong-seq and a wrong-source ACK sent after its second copy, its third answered as it
  arrives (RTX-2: ``DronePlayers.arm_again``); the rest of the mission is ACKed at once and
  watched to its end (payloads, order, End_Mission last, nothing after it). A quiet manager,
  alive, with drones still owed their End_Mission is waited for up to the record's cap, not
  cut short at the idle window (:meth:`MissionScript._owed`).
  When the manager ACKs no Mission_Ready within the startup limit, the other drones
  announce readiness all the same (the last one held back) and whatever the manager then
  does is watched as above: a manager that goes on with the mission without ACKing is
  judged on what it did (MCP-ACK-1 fails); the receiver-side inputs are not sent (their
  liveness probe is an ACKed Mission_Ready). Only a manager that sends nothing at all
  "never answered".
- ``silent``: every drone ready at once; one drone stops answering after its
  Start_Mission; what the manager does about the others is reported (INFO).

Every wait is bounded by the manager's timeout as assumed (``--rto``), the ACK window and
the number of copies; a timeout is an observation. Every wait and every reading of the time
is the driver's clock's (``TargetDriver.clock``, ``harness.clock``): the host's by default,
virtual time in the simulator (``sim.manager_runner``), where the flood's backlog is read by
the node model as it falls due (no kernel queue to wait on).
"""

from __future__ import annotations

import random
import statistics
from collections.abc import Callable

from mcp_conform.harness.driver import Datagram, Exchange, Sent, TargetDriver, read_header
from mcp_conform.harness.drone_players import MANAGER_ID, DronePlayers, Input, Mission
from mcp_conform.harness.rx_queue import FLOOD_READ_S, udp_rx_queue, wait_read
from mcp_conform.judge.monitor import late_ack_wait_s
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import HEADER_SIZE, MAX_DATAGRAM, PREAMBLE, Action, build_datagram
from mcp_conform.spec.generators import malformed_corpus

__all__ = ["MissionScript"]

MIN_COPIES = int(SPEC.params["min_copies"])
MAX_ACK_COPIES = int(SPEC.params["max_ack_copies"])
FLOOD_COUNT = int(SPEC.params["flood_count"])
PER_KIND = 2  # seeded malformed inputs per kind
_READY = int(Action.MISSION_READY)
_START = int(Action.START_MISSION)
_END = int(Action.END_MISSION)
_ACK = int(Action.ACK)


def _what(d: Datagram) -> tuple[int, int, bytes]:
    """A command's destination, action and payload: what its copies share (whatever their seq)."""
    assert d.header is not None
    return d.header[0], d.header[3], d.data[HEADER_SIZE:]


class MissionScript:
    """Drives one scenario against a running manager (see the module docstring)."""

    def __init__(self, driver: TargetDriver, players: DronePlayers, mission: Mission, *, rto: float,
                 ack_window: float, broadcast_id: int, seed: int, alive: Callable[[], bool],
                 ready_limit: float, backlog: Callable[[], bool] | None = None) -> None:
        self.driver = driver
        self.players = players
        self.m = mission
        self.rto = rto
        self.ack_window = ack_window
        self.broadcast_id = broadcast_id
        self.seed = seed
        self.alive = alive
        self.ready_limit = ready_limit
        self.clock = driver.clock
        #: the drones' socket holds datagrams its receiver has not read yet (default: the
        #: kernel's receive queue of the driver's socket, ``harness.rx_queue``)
        self.backlog = backlog or self._kernel_backlog

    def _kernel_backlog(self) -> bool:
        host, port = self.driver.listen[:2]
        return bool(udp_rx_queue(host or "0.0.0.0", port))

    def drain(self, limit: float = FLOOD_READ_S) -> None:
        """Until the receiver has read what the socket holds (at most ``limit`` s)."""
        end = self.clock.monotonic() + limit
        while self.backlog() and self.clock.monotonic() < end:
            self.clock.sleep(0.02)

    def wait_for(self, match: Callable[[Datagram], bool], timeout: float, since: int) -> Datagram | None:
        """The driver's ``wait_for``, and where it timed out with datagrams unread, a second
        look among them once read: one that arrived in time (the kernel's receive time) counts,
        however late a loaded host's receiver thread read it (a false "no copy" of MCP-RTX-2,
        and a mission cut short as "idle", in the simulator's stalls of the runner's threads)."""
        end = self.clock.monotonic() + max(0.0, timeout)
        got = self.driver.wait_for(match, timeout, since)
        if got is not None or not self.backlog():
            return got
        self.drain()
        return next((d for d in self.driver.received(since) if d.t <= end and match(d)), None)

    # ------------------------------------------------------------------ helpers
    def outsider(self) -> int:
        """An ID that is neither a mission drone, the manager nor the broadcast ID."""
        for cand in (0x0ABC, 0x0ABD, 0x0ABE):
            if cand not in self.m.drones and cand not in (MANAGER_ID, self.broadcast_id):
                return cand
        return 0x0ABF

    def acks_of(self, sent: Sent) -> Callable[[Datagram], bool]:
        """An ACK-like reply naming ``sent``'s seq (either byte order) that is not addressed to
        another of our drones: lenient, so a malformed ACK is judged by MCP-ACK-2/3, not
        taken for silence (our drones' seq ranges are disjoint)."""
        others = set(self.m.drones) - {sent.src}

        def match(d: Datagram) -> bool:
            return d.t >= sent.t and d.names_seq(sent.seq) and d.header is not None and d.header[0] not in others
        return match

    def exchange(self, sent: Sent, copies: int = MAX_ACK_COPIES) -> Exchange:
        """Await the ACK of ``sent``, retransmitting it every --rto up to ``copies`` copies."""
        ex = Exchange([sent])
        since = self.driver.mark_before(sent)
        match = self.acks_of(sent)
        for n in range(copies):
            wait = self.rto if n < copies - 1 else max(self.rto, self.ack_window)
            got = self.wait_for(match, wait, since)
            if got is not None:
                ex.ack = got
                return ex
            if not self.alive() or n == copies - 1:
                return ex
            ex.copies.append(self.driver.resend(sent))
        return ex

    def mission_ready(self, drone: int, *, first: bool = False) -> Exchange:
        """A Mission_Ready from ``drone``, retransmitted every --rto until ACKed (the first
        one of a fresh manager is retried up to the startup limit: it may still be starting)."""
        sent = self.players.send(Action.MISSION_READY, None, drone)
        copies = MAX_ACK_COPIES if not first else max(MAX_ACK_COPIES, int(self.ready_limit / self.rto) + 1)
        return self.exchange(sent, copies)

    def _mark(self) -> None:
        self.m.start = self.driver.mark()
        self.m.t0 = self.clock.monotonic()

    # ------------------------------------------------------------------ main
    def run_main(self) -> bool:
        """The main scenario; False when the manager sent nothing at all."""
        m = self.m
        self._mark()
        drones = m.drones
        first = self.mission_ready(drones[0], first=True) if len(drones) > 1 else None
        if first is not None:
            m.ready[drones[0]] = first
            if not first.acked:
                return self._ready_unacked(first, hold_back=True) and self._mission_on()
        for d in drones[1:-1]:
            m.ready[d] = self.mission_ready(d)
        if len(drones) > 1:
            dup_from = drones[1] if len(drones) > 2 else drones[0]
            m.duplicate = self.mission_ready(dup_from)
        m.held_back = drones[-1]
        hold_from = self.clock.monotonic()
        probe_src = drones[0] if len(drones) > 1 else self.outsider()
        if first is None:  # one drone: the inputs come from an outsider, before its Mission_Ready
            warm = self.mission_ready(probe_src, first=True)
            if not warm.acked:
                return self._ready_unacked(None, hold_back=True) and self._mission_on()
        self._receiver_inputs(probe_src)
        hold = max(2 * self.ack_window, 0.5)
        self.clock.sleep(max(0.0, hold_from + hold - self.clock.monotonic()))
        last = self.players.send(Action.MISSION_READY, None, drones[-1])
        m.all_ready_t = last.t
        m.ready[drones[-1]] = self.exchange(last)
        return self._mission_on()

    def _mission_on(self) -> bool:
        """Every drone ready: the first Start_Mission withheld, the rest watched to the end."""
        self._withhold_start()
        self._await_end()
        return True

    def _ready_unacked(self, first: Exchange | None, *, hold_back: bool) -> bool:
        """The manager ACKed no Mission_Ready within the startup limit (``first``: the one
        it did not ACK): the other drones announce readiness all the same, at once (the last
        one after them when ``hold_back``: MCP-BLK-2 stays observable), every Mission_Ready
        retransmitted every --rto up to ``MAX_ACK_COPIES`` copies (``first``'s go on), and
        the mission that follows, if any, is watched to its end. False when the manager sent
        nothing at all: it never answered."""
        m = self.m
        if first is not None:
            m.ready_unacked = (f"the manager did not ACK drone {first.first.src}'s Mission_Ready (seq {first.seq}) "
                               f"within {first.copies[-1].t - first.first.t:.1f} s")
        else:
            m.ready_unacked = f"the manager did not ACK a Mission_Ready within {self.ready_limit:g} s"
        m.notes.append(m.ready_unacked + ": the drones announced readiness without its ACKs")
        rest = [d for d in m.drones if d not in m.ready]
        last = rest.pop() if hold_back and rest else None
        group = [first] if first is not None else []
        for d in rest:
            m.ready[d] = Exchange([self.players.send(Action.MISSION_READY, None, d)])
            group.append(m.ready[d])
        if m.ready:
            m.all_ready_t = max(ex.first.t for ex in m.ready.values())
        self._exchange_all(group)
        if last is not None:
            m.held_back = last
            sent = self.players.send(Action.MISSION_READY, None, last)
            m.all_ready_t = sent.t
            m.ready[last] = self.exchange(sent)
        if not self.driver.received(m.start):
            return False
        return True

    def _exchange_all(self, exs: list[Exchange]) -> None:
        """Await the ACK of each of ``exs`` at once: each unACKed one retransmitted every
        --rto, ``MAX_ACK_COPIES`` rounds."""
        pending = [(ex, self.acks_of(ex.first)) for ex in exs]
        since = min((self.driver.mark_before(ex.first) for ex in exs), default=self.driver.mark())
        for n in range(MAX_ACK_COPIES):
            deadline = self.clock.monotonic() + (self.rto if n < MAX_ACK_COPIES - 1 else max(self.rto, self.ack_window))
            while pending and self.clock.monotonic() < deadline:
                got = self.driver.wait_for(lambda d: any(match(d) for _, match in pending),
                                           deadline - self.clock.monotonic(), since)
                if got is None:
                    break
                for ex, match in [p for p in pending if p[1](got)]:
                    ex.ack = got
                    pending.remove((ex, match))
            if not pending or not self.alive() or n == MAX_ACK_COPIES - 1:
                return
            for ex, _ in pending:
                ex.copies.append(self.driver.resend(ex.first))

    def _probe(self, probe_src: int) -> Exchange:
        return self.exchange(self.players.send(Action.MISSION_READY, None, probe_src))

    def _input(self, label: str, rule: str, sent: Sent, probe_src: int, *, expect_ack: bool = False) -> bool:
        inp = Input(label, rule, sent, expect_ack=expect_ack)
        self.m.inputs.append(inp)
        if expect_ack:  # ACKed again, however late: as long as the monitor waits (one judge)
            inp.reply = self.wait_for(self.acks_of(sent), late_ack_wait_s(self.rto, self.ack_window),
                                      self.driver.mark_before(sent))
        if not self.alive():
            inp.died = True
            return False
        inp.probe = self._probe(probe_src)
        inp.died = not self.alive()
        return not inp.died and inp.probe.acked

    def _receiver_inputs(self, p: int) -> None:
        """ACK-1/4/5/6, ROB-1..7 and TRN-2 inputs from drone ``p``, each followed by a probe."""
        pl = self.players
        drv = self.driver
        rnd = random.Random(self.seed)
        mr = self.m.ready.get(p)
        steps: list[tuple[str, str, Callable[[], Sent], bool]] = []
        if mr is not None:
            steps.append(("a copy of Mission_Ready (same seq and bytes)", "MCP-ACK-1",
                          lambda: pl._record(drv.resend(mr.first)), True))
        steps += [
            ("Mission_Ready broadcast", "MCP-ACK-4",
             lambda: pl.send(Action.MISSION_READY, None, p, dst=self.broadcast_id), False),
            ("Mission_Ready to another ID", "MCP-ACK-5",
             lambda: pl.send(Action.MISSION_READY, None, p, dst=self.outsider()), False),
            ("an ACK of nothing", "MCP-ACK-6",
             lambda: pl.send(Action.ACK, (rnd.getrandbits(16) | 0x4000) & 0xFFFF, p), False),
        ]

        def raw(data: bytes) -> Callable[[], Sent]:
            return lambda: pl.send_raw(data, p)

        def seq() -> int:
            return pl.next_seq(p)

        steps += [("empty datagram", "MCP-ROB-1", raw(b""), False),
                  ("preamble only", "MCP-ROB-1", raw(PREAMBLE), False),
                  ("16 bytes", "MCP-ROB-1", raw(build_datagram(MANAGER_ID, p, seq(), _READY)[:HEADER_SIZE - 1]), False)]
        first = pl._seq[p]
        corpus = malformed_corpus(self.seed, PER_KIND, dst=MANAGER_ID, src=p, first_seq=first,
                                  kinds=["short", "bad_preamble", "unknown_action", "wrong_payload_length",
                                         "count_mismatch"])
        with pl._lock:
            pl._seq[p] = (first + len(corpus) + 1) & 0xFFFF
        rule_of = {"short": "MCP-ROB-1", "bad_preamble": "MCP-ROB-2", "unknown_action": "MCP-ROB-3",
                   "wrong_payload_length": "MCP-ROB-4", "count_mismatch": "MCP-ROB-4"}
        steps += [(f"{kind} #{i}", rule_of[kind], raw(data), False) for i, (kind, data) in enumerate(corpus)]
        steps += [(f"action {a}", "MCP-ROB-3", raw(build_datagram(MANAGER_ID, p, seq(), a)), False)
                  for a in (int(Action.ANY), 10, 0xFFFF)]
        steps += [("Mission_Ready with a 3-byte payload", "MCP-ROB-4",
                   raw(build_datagram(MANAGER_ID, p, seq(), _READY, b"\x00\x01\x02")), False),
                  ("Start_Mission from a drone", "MCP-ROB-5",
                   lambda: pl.send(Action.START_MISSION, None, p), False),
                  ("WP_List from a drone", "MCP-ROB-5", lambda: pl.send(Action.WP_LIST, (), p), False)]
        head = build_datagram(MANAGER_ID, p, seq(), _READY, b"\x00\x01")
        # bytes(rnd.getrandbits(8) for _ in range(n)), the same bytes and draws, ~30x cheaper
        # (the top byte of each 32-bit draw: tests/sim/test_random_bytes.py)
        big = head + rnd.getrandbits(32 * (MAX_DATAGRAM - len(head))).to_bytes(
            4 * (MAX_DATAGRAM - len(head)), "little")[3::4]
        steps += [(f"{len(big)}-byte Mission_Ready", "MCP-ROB-6", raw(big), False),
                  (f"{MAX_DATAGRAM} random bytes", "MCP-ROB-6",
                   raw(rnd.getrandbits(32 * MAX_DATAGRAM).to_bytes(4 * MAX_DATAGRAM, "little")[3::4]), False)]
        for label, rule, make, expect in steps:
            if not self._input(label, rule, make(), p, expect_ack=expect):
                return
        if not self._side_socket_input(p):
            return
        self._flood(p, corpus)

    def _side_socket_input(self, p: int) -> bool:
        """MCP-TRN-2: a Mission_Ready from another source port is ACKed (to either socket)."""
        sock = self.driver.open_side_socket()
        try:
            sent = self.players.send(Action.MISSION_READY, None, p, sock=sock)
            inp = Input("Mission_Ready from another source port", "MCP-TRN-2", sent, expect_ack=True)
            self.m.inputs.append(inp)
            match = self.acks_of(sent)
            for n in range(MAX_ACK_COPIES):
                deadline = self.clock.monotonic() + self.rto
                while self.clock.monotonic() < deadline and inp.reply is None:
                    inp.reply = self.driver.wait_for(match, 0.02, self.driver.mark_before(sent))
                    try:
                        data, addr = sock.recvfrom(65535)
                    except (TimeoutError, BlockingIOError, OSError):
                        continue
                    d = Datagram(-1, self.clock.monotonic(), self.clock.time_ns(), data, addr, None, None, read_header(data))
                    if d.names_seq(sent.seq):
                        inp.reply = d
                if inp.reply is not None or n == MAX_ACK_COPIES - 1:
                    break
                self.driver.resend(sent, sock=sock)
        finally:
            sock.close()
        inp.probe = self._probe(p)
        inp.died = not self.alive()
        return not inp.died and inp.probe.acked

    def _flood(self, p: int, corpus: list[tuple[str, bytes]]) -> None:
        """MCP-ROB-7: 10 000 malformed datagrams as fast as loopback takes them, then a probe."""
        data = [d for k, d in corpus if k in ("bad_preamble", "unknown_action", "count_mismatch")] or [PREAMBLE]
        sock = self.driver.open_side_socket()
        sent = 0
        deadline = self.clock.monotonic() + 30.0
        try:
            while sent < FLOOD_COUNT and self.clock.monotonic() < deadline:
                try:
                    sock.sendto(data[sent % len(data)], self.driver.target)
                    sent += 1
                except OSError:
                    self.clock.sleep(0.001)
        finally:
            sock.close()
        flood = Sent(self.clock.monotonic(), self.clock.time_ns(), data[0], self.driver.target, -1, -1, -1, -1)
        inp = Input(f"a flood of {sent} malformed datagrams", "MCP-ROB-7", flood)
        self.m.inputs.append(inp)
        # the probe once the manager has read the flood, as the drone role's case does (a loaded
        # CI host: the reference manager's backlog outlasted the probe's 5 copies, MCP-ACK-1)
        if not self.clock.virtual:
            wait_read(*self.driver.target[:2], FLOOD_READ_S)
        inp.probe = self._probe(p)
        inp.died = not self.alive()

    # ------------------------------------------------------------------ Start_Mission withheld
    def _is_start(self, drone: int | None = None) -> Callable[[Datagram], bool]:
        def match(d: Datagram) -> bool:
            h = d.header
            return (h is not None and d.preamble_ok and h[3] == _START and h[1] == MANAGER_ID
                    and (h[0] in self.m.drones if drone is None else h[0] == drone))
        return match

    def _withhold_start(self) -> None:
        m, drv, w = self.m, self.driver, self.m.withheld
        start_wait = max(3.0, 3 * self.rto + self.ack_window)
        first = self.wait_for(self._is_start(), start_wait, m.start)
        if first is None or first.header is None:
            m.notes.append(f"no Start_Mission within {start_wait:g} s of the last Mission_Ready")
            self.players.release()
            return
        w.drone = self.players.start_drone if self.players.start_drone is not None else first.header[0]
        is_copy = self._is_start(w.drone)
        # MCP-RTX-1, "Observed: at least 3 copies while the ACK is withheld" (spec min_copies: "a
        # retry limit of 2 is the rule's 'configurable' limit, no violation"): the third copy is
        # answered as it arrives. Held longer, a limit of 2 gives up (its third copy plus its
        # timeout) and a manager that ends every mission there fails MCP-FLOW-2/3/4 for the
        # runner's doing (the Go manager's -exit-on-give-up; what follows a give-up: MCP-FLOW-7)
        deadline = first.t + MIN_COPIES * self.rto * 1.5 + 1.0
        while True:
            since = drv.mark()  # before the count: a copy arriving in between ends the wait at once
            copies = [d for d in drv.received(m.start) if is_copy(d)]
            now = self.clock.monotonic()
            if len(copies) >= MIN_COPIES or now >= deadline or not self.alive():
                break
            drv.wait_for(is_copy, min(0.05, deadline - now), since)
        w.copies = copies
        gaps = w.gaps()
        gap = statistics.median(gaps) if gaps else self.rto
        # MCP-RTX-2 on the next new unicast (``DronePlayers.arm_again``), armed before the right
        # ACK leaves (that unicast may follow it at once): the wrong ACKs after its second copy,
        # its third answered as it arrives; the copies here proved the limit reaches a third
        w.wrong_ack_wait = max(2.5 * gap, 0.3) + 0.2
        if len(w.copies) >= MIN_COPIES:
            self.players.arm_again(w.wrong_ack_wait, self.outsider(), None, len(w.copies))
        latest = w.copies[-1]
        # released and answered in one step: the one ACK of the latest copy, whichever thread
        # runs first, and ``acks`` keeps the earliest (``DronePlayers.answer``)
        right = self.players.answer(latest, release=True)
        assert right is not None, "the drone players withhold each copy of it until the release"
        w.right_ack = right
        w.stop_watch = max(self.ack_window, 1.5 * gap)
        grace = 0.05
        drone = w.drone

        def past_right() -> list[Datagram]:
            self.drain()  # a copy the watch saw arrive, read late, is seen
            return [d for d in drv.received(m.start) if is_copy(d) and d.t > right.t + grace
                    and (d.header is None or (drone, d.header[2]) not in m.acks
                         or m.acks[(drone, d.header[2])].t > right.t + grace)]

        w.watch_after_right_ack(past_right, gap, self.clock.sleep)

    def _owed(self, expect: tuple[int, ...], rx: list[Datagram]) -> list[int]:
        """The drones of ``expect`` a quiet manager, alive and mid-mission, may still send
        commands to: it sent some drone a command, and these have no End_Mission ACKed --
        MCP-FLOW-3 ("End_Mission is the last command the manager sends each drone") and
        MCP-FLOW-4/5/6 are not broken by a pause, however long (a waypoint held active longer
        than the idle window: H-cmanager's ``--hold``), so the record waits for them up to its
        cap, where a manager that never goes on fails them as before. Not owed: a drone whose
        last command is a message the runner withheld (its first Start_Mission, RTX-2's second
        observation) -- the manager gave it up, or would be retransmitting."""
        m = self.m
        cmds = [d for d in rx if d.header is not None and d.header[3] != _ACK and d.header[0] in m.drones]
        if not cmds:
            return []
        withheld = {_what(w.copies[0]) for w in (m.withheld, m.withheld_again) if w.copies}
        last = {_what(d)[0]: _what(d) for d in cmds}
        return [d for d in expect if _END not in self.players.acked_actions.get(d, set())
                and last.get(d) not in withheld]

    def _settle_again(self) -> None:
        """MCP-RTX-2's second observation (``DronePlayers.arm_again``) ended where no copy came
        in time: its held message answered once what the socket held is read, its next copy
        overdue -- ``wrong_ack_wait`` after the wrong ACKs, or after its first copy when no
        second came (``DronePlayers.again_overdue``: never while the receiver thread is sending
        the wrong ACKs). (A copy after the wrong ACKs is answered by the drone players at once.)
        Released only if that observation is still the one held and still overdue after the
        drain: the receiver, reading on, may have spoiled it and begun the next try, or be
        sending that one's wrong ACKs (seed 176 of ``preempt=(0.3, 0.3)``: its right ACK went
        out between them, a false MCP-RTX-2)."""
        a = self.players.again_overdue()
        if a is None:
            return
        if self.backlog():
            self.drain()  # a copy the receiver has not read yet is read first
        self.players.release_again(held=a)

    def _end_again(self) -> None:
        """The record does not end in the middle of MCP-RTX-2's observation: a message still held
        is answered where :meth:`_settle_again` would, once its next copy is overdue (waited for
        at most twice ``wrong_ack_wait`` and 1 s; then it is answered all the same). Answered as the mission ended, before the
        window after the wrong ACKs did, it left "no copy after them" void (the case says so):
        the simulator's wrong-seq-ack, its mission over 0.40 s after them, seed 2."""
        end = self.clock.monotonic() + 2 * self.m.withheld_again.wrong_ack_wait + 1.0
        while self.players.again_held() and self.clock.monotonic() < end:
            self._settle_again()
            self.driver.wait_for(lambda d: False, 0.05, self.driver.mark())

    # ------------------------------------------------------------------ the end
    def _await_end(self, expect: tuple[int, ...] | None = None, cap: float | None = None) -> None:
        """Until every drone of ``expect`` had its End_Mission ACKed (then a tail watched for
        commands after it), the manager exits, stays idle owing no drone a command
        (:meth:`_owed`), or the cap is reached; then once the receiver has read what the socket
        holds (a manager that exited with its last commands unread by a receiver seconds behind
        had them left out of the record: a false MCP-FLOW-3, simulator seed 18 of
        ``preempt=(0.5, 0.5)``)."""
        m = self.m
        expect = m.drones if expect is None else expect
        idle = max(2.5 * self.rto, 2 * self.ack_window, 1.0)
        tail = max(self.ack_window, 1.5 * self.rto, 0.3)
        cap = cap if cap is not None else max(60.0, 40 * self.rto)
        t_cap = self.clock.monotonic() + cap
        while True:
            now = self.clock.monotonic()
            if all(_END in self.players.acked_actions.get(d, set()) for d in expect):
                self.clock.sleep(tail)
                m.ended_by = "end_mission"
                break
            if not self.alive():
                self.clock.sleep(0.1)
                m.ended_by = "exited"
                break
            rx = self.driver.received(m.start)
            last = rx[-1].t if rx else m.t0
            if now - max(last, m.t0) > idle and now < t_cap and self.backlog():
                self.drain()  # idle as far as the receiver has read: it may be behind
                continue
            if now - max(last, m.t0) > idle and not self._owed(expect, rx):
                m.ended_by = "idle"
                break
            if now >= t_cap:
                m.ended_by = "cap"
                break
            self._settle_again()
            self.driver.wait_for(lambda d: False, 0.05, self.driver.mark())
        self._end_again()
        self.players.release_again()  # nothing more is withheld once the record ends
        if self.backlog():
            self.drain()
        m.end = self.driver.mark()
        m.t_end = self.clock.monotonic()
        m.rx = self.driver.received(m.start, m.end)

    # ------------------------------------------------------------------ silent
    def run_silent(self) -> bool:
        """Every drone ready at once; the first drone goes silent after its Start_Mission."""
        m = self.m
        self._mark()
        m.silent_drone = m.drones[0]
        self.players.silent_after_start = m.silent_drone
        ex = self.mission_ready(m.drones[0], first=True)
        m.ready[m.drones[0]] = ex
        if not ex.acked:
            if not self._ready_unacked(ex, hold_back=False):
                return False
            others = tuple(d for d in m.drones if d != m.silent_drone)
            self._await_end(others, cap=min(max(25 * self.rto, 5.0), 60.0))
            return True
        for d in m.drones[1:]:
            m.ready[d] = self.mission_ready(d)
        others = tuple(d for d in m.drones if d != m.silent_drone)
        self._await_end(others, cap=min(max(25 * self.rto, 5.0), 60.0))
        return True

"""The runner's drones against a Mission Manager under test (``--role manager``): who they
are and what a scenario recorded.

The runner plays every drone of ``--drones`` from its one socket. A ``DronePlayers`` object
answers the manager from the driver's receiver thread, as drones would: it ACKs every
unicast addressed to one of its drones (MCP-ACK-1) — leniently, malformed payloads
included, so that one bad payload does not stall the mission and every later rule can
still be judged (the payload itself is judged by MCP-PAY-3/5) — except where a scenario
withholds an ACK on purpose or a drone has gone silent. It never ACKs an ACK or a
broadcast.

One answer per copy: each datagram of the manager is ACKed at most once by the runner,
whichever thread answers it — the drone players from the driver's receiver thread, or the
case thread that withheld a Start_Mission and answers its latest copy (:meth:`DronePlayers.
answer`). The copy is claimed under the players' lock before its ACK leaves, so the other
thread, however late it runs, finds it answered. ``Mission.acks`` keeps, per (drone, seq
named), the earliest ACK sent, whichever thread recorded its ACK first: a thread taken off
the CPU after its ACK left records it late, and the record is still the one the manager got
first (MCP-BLK-1's "its ACK"; issue 38's false MCP-BLK-1, ``tests/sim/test_manager_blk_sim.py``).
The lock is never held while a datagram leaves (the simulator's scheduler switches threads
only where one blocks on its clock, a send among those places).

A *scenario* is one mission from the manager's first Mission_Ready to its last
End_Mission, recorded in a :class:`Mission`; the cases judge those records.
:mod:`harness.mission_script` drives the scenarios (``main``, ``silent``). Everything here
runs on the driver's clock and transport (``harness.clock``, ``harness.transport``): the
host's by default, the simulator's virtual time in ``sim.manager_runner``.
"""

from __future__ import annotations

import socket
import threading
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.harness.driver import Datagram, Exchange, Sent, TargetDriver
from mcp_conform.harness.session_base import WithheldCopies
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import HEADER_SIZE, Action

__all__ = ["MANAGER_ID", "DronePlayers", "Input", "Mission", "Withheld"]

MANAGER_ID = int(SPEC.protocol["manager_id"])
_ACK = int(Action.ACK)
_START = int(Action.START_MISSION)


# ---------------------------------------------------------------------- records
@dataclass
class Input:
    """One receiver-side input sent to the manager, and the liveness probe after it."""

    label: str
    rule: str  # the rule it exercises
    sent: Sent
    probe: Exchange | None = None  # a fresh Mission_Ready, awaited across retransmissions
    died: bool = False
    expect_ack: bool = False  # a well-formed unicast: its own ACK is expected (ACK-1, TRN-2)
    reply: Datagram | None = None  # the ACK of ``sent`` itself, where one is expected


@dataclass
class Withheld(WithheldCopies):
    """The first Start_Mission, its ACK withheld (RTX-1/3, SEQ-2, BLK-1/3); ``copies`` are
    those to ``drone`` before its right ACK (the main mission sends it no wrong ACKs: they
    are the next new unicast's). Also MCP-RTX-2's observation
    (``Mission.withheld_again``: :meth:`DronePlayers.arm_again`)."""

    drone: int | None = None


@dataclass
class Mission:
    """What one scenario sent and saw (the cases judge it)."""

    kind: str
    drones: tuple[int, ...]
    challenge: int
    waypoints: tuple[Any, ...] | None  # the items the manager was handed (None: unknown)
    obstacles: tuple[Any, ...] | None
    start: int = 0  # driver index of the first datagram of the mission
    end: int = 0
    t0: float = 0.0
    t_end: float = 0.0
    ready: dict[int, Exchange] = field(default_factory=dict)  # each drone's first Mission_Ready
    held_back: int | None = None
    all_ready_t: float | None = None  # when the last drone's first Mission_Ready left
    duplicate: Exchange | None = None  # a second Mission_Ready (new seq) from another drone
    #: why the drones announced readiness without the manager's ACKs ("": it ACKed the first
    #: Mission_Ready); the receiver-side inputs, which need an ACKed probe, were not sent
    ready_unacked: str = ""
    inputs: list[Input] = field(default_factory=list)
    withheld: Withheld = field(default_factory=Withheld)
    #: MCP-RTX-2's second observation (:meth:`DronePlayers.arm_again`): the next new unicast
    #: to a drone after the first Start_Mission's wrong ACKs, its ACK withheld, the wrong ACKs
    #: sent after its second copy (``drone`` None: none was withheld)
    withheld_again: Withheld = field(default_factory=Withheld)
    #: its earlier tries, spoiled: the wrong ACKs went out after as many copies as the first
    #: Start_Mission had (a receiver behind), where a retry limit may end them too
    again_spoiled: list[Withheld] = field(default_factory=list)
    silent_drone: int | None = None
    silent_from: float | None = None
    #: (drone, seq named) -> the earliest ACK the runner sent of a copy with that seq
    #: (``DronePlayers.answer``; not RTX-2's wrong ACKs nor the receiver-side inputs)
    acks: dict[tuple[int, int], Sent] = field(default_factory=dict)
    sent_by_drones: dict[tuple[int, int], Sent] = field(default_factory=dict)  # (drone, seq) -> what we sent
    #: copies the drone players found answered already by the case thread (``DronePlayers.answer``)
    declined: int = 0
    ended_by: str = ""
    exit_code: int | None = None
    output: str = ""
    rx: list[Datagram] = field(default_factory=list)  # everything received during the mission
    monitor: list[Any] = field(default_factory=list)  # the trace monitor's violations of the manager
    monitor_trace: list[str] = field(default_factory=list)  # the trace as fed to it
    notes: list[str] = field(default_factory=list)
    _memo: Any = field(default=None, repr=False, compare=False)

    def from_manager(self) -> list[Datagram]:
        """The manager's datagrams in arrival order: everything the runner received during
        the mission (the drones' own datagrams go to the manager, not to the runner)."""
        return list(self.rx)

    def commands(self) -> list[Datagram]:
        """The manager's non-ACK datagrams with a readable header (copies included)."""
        return list(self._commands()[0])

    def to_drone(self, drone: int) -> list[Datagram]:
        """The manager's commands to ``drone`` (copies included), in arrival order."""
        return list(self._commands()[1].get(drone, ()))

    def _commands(self) -> tuple[list[Datagram], dict[int, list[Datagram]]]:
        """``commands`` and ``to_drone``'s lists, made once for what ``rx`` holds (it is only
        appended to, or replaced whole): the cases ask them for every message of the mission
        (``conformance.manager_case.runner_ack_time``), and rebuilding them each time made a
        150-waypoint mission's cases quadratic in its datagrams."""
        rx, n = self.rx, len(self.rx)
        if self._memo is None or self._memo[0] is not rx or self._memo[1] != n:
            cmds = [d for d in rx[:n] if d.header is not None and d.header[3] != _ACK]
            by: dict[int, list[Datagram]] = {}
            for d in cmds:
                by.setdefault(d.header[0], []).append(d)  # type: ignore[index]
            self._memo = (rx, n, cmds, by)
        return self._memo[2], self._memo[3]

    def ack_latencies(self) -> list[float]:
        out = [ex.latency() for ex in self.ready.values()]
        out += [i.probe.latency() for i in self.inputs if i.probe is not None]
        return [x for x in out if x is not None]


# ---------------------------------------------------------------------- the drones
class DronePlayers:
    """Every drone of the mission, answering from the driver's receiver thread."""

    def __init__(self, driver: TargetDriver, drones: tuple[int, ...], seq_base: int) -> None:
        self.driver = driver
        self.drones = drones
        self._lock = threading.Lock()
        self._seq = {d: (seq_base + 0x200 * n) & 0xFFFF for n, d in enumerate(drones)}
        self.mission: Mission | None = None
        self.withhold_first_start = False
        self.start_drone: int | None = None
        self.released = False
        self.silent_after_start: int | None = None
        self.silent: set[int] = set()
        self.acked_actions: dict[int, set[int]] = {d: set() for d in drones}
        self._answered: set[int] = set()  # driver indexes of the copies answered (one ACK each)
        self.hold_again = False  # MCP-RTX-2's second observation armed (:meth:`arm_again`)
        self._again_key: tuple[int, int, bytes] | None = None
        self._again_outsider = 0
        #: drones named by a wrong-source ACK -> their first command since (None: not yet)
        self._again_stale: dict[int, tuple[int, int, bytes] | None] = {}
        self._again_limit = 0  # copies the first observation saw: a spoiled try has as many before them
        self._again_tries = 0
        self._again_done: set[tuple[int, int, bytes]] = set()  # the spoiled tries' messages
        #: the receiver thread is sending the wrong ACKs (:meth:`_send_wrong_acks`; recorded once
        #: both left): the observation is not over, whatever the record says yet
        self._again_sending = False

    def reset(self, mission: Mission) -> None:
        with self._lock:
            self.mission = mission
            self.withhold_first_start = False
            self.start_drone = None
            self.released = False
            self.silent_after_start = None
            self.silent = set()
            self.acked_actions = {d: set() for d in self.drones}
            self._answered = set()
            self.hold_again = False
            self._again_key = None
            self._again_sending = False

    def next_seq(self, drone: int) -> int:
        with self._lock:
            seq = self._seq.get(drone, 0)
            self._seq[drone] = (seq + 1) & 0xFFFF
            return seq

    def _record(self, s: Sent) -> Sent:
        if self.mission is not None:
            self.mission.sent_by_drones.setdefault((s.src, s.seq), s)
        return s

    def send(self, action: Action, payload: Any, drone: int, *, dst: int = MANAGER_ID,
             seq: int | None = None, sock: socket.socket | None = None) -> Sent:
        seq = self.next_seq(drone) if seq is None else seq
        return self._record(self.driver.send(action, payload, dst, src=drone, seq=seq, sock=sock))

    def send_raw(self, data: bytes, drone: int) -> Sent:
        return self._record(self.driver.send_raw(data))

    def ack(self, drone: int, seq: int, *, dst: int = MANAGER_ID) -> Sent:
        """An ACK from ``drone`` naming ``seq`` (to the manager's receive address)."""
        return self.send(Action.ACK, seq, drone, dst=dst)

    def release(self) -> None:
        with self._lock:
            self.released = True

    def answer(self, d: Datagram, *, release: bool = False) -> Sent | None:
        """The runner's one ACK of the manager's datagram ``d`` (MCP-ACK-1), from its
        destination drone to its source: sent unless ``d`` was answered already (then None).
        ``release``: the withheld Start_Mission's drone is released in the same step (the case
        thread's right ACK of its latest copy): the receiver thread, answering that copy after
        the release, finds it answered."""
        h = d.header
        assert h is not None
        dst, src, seq, action = h
        with self._lock:
            if release:
                self.released = True
            if not self._claim(d):
                return None
        return self._answered_with(self.ack(dst, seq, dst=src), dst, seq, action)

    def _claim(self, d: Datagram) -> bool:
        """``d`` is to be answered by the caller (the players' lock held): False when it was."""
        if d.index in self._answered:
            return False
        self._answered.add(d.index)
        return True

    def _answered_with(self, sent: Sent, drone: int, seq: int, action: int, *, go_silent: bool = False) -> Sent:
        """Record ``sent``, the ACK of a copy: ``Mission.acks`` keeps the earliest per (drone,
        seq) whatever the order the threads record them in."""
        with self._lock:
            if self.mission is not None:
                had = self.mission.acks.get((drone, seq))
                if had is None or sent.t < had.t:
                    self.mission.acks[(drone, seq)] = sent
            self.acked_actions.setdefault(drone, set()).add(action)
            if go_silent:
                self.silent.add(drone)
                if self.mission is not None:
                    self.mission.silent_from = sent.t
        return sent

    def on_datagram(self, d: Datagram) -> None:
        h = d.header
        if h is None or not d.preamble_ok:
            return
        dst, src, seq, action = h
        if action == _ACK or dst not in self.drones:
            return  # never an ACK of an ACK (MCP-ACK-6), nor of a broadcast (MCP-ACK-4)
        with self._lock:
            if dst in self.silent:
                return
            if action == _START and self.withhold_first_start and not self.released:
                if self.start_drone is None:
                    self.start_drone = dst
                if self.start_drone == dst:
                    return
            again = self._again_step(d, dst, action) if self.hold_again and self.mission is not None else None
            if again == "held":
                return
            if again in (None, "spoiled") and not self._claim(d):
                if self.mission is not None:
                    self.mission.declined += 1
                return
            go_silent = action == _START and self.silent_after_start == dst
        if again == "wrong":
            self._send_wrong_acks(dst, seq)
        elif again == "after":
            self.release_again(d)
        elif again == "spoiled":
            self._answered_with(self.ack(dst, seq, dst=src), dst, seq, action)
        else:
            self._answered_with(self.ack(dst, seq, dst=src), dst, seq, action, go_silent=go_silent)

    # ------------------------------------------------------------ MCP-RTX-2's second observation
    def arm_again(self, wait: float, outsider: int, stale_src: int | None, limit: int, tries: int = 3) -> None:
        """MCP-RTX-2's observation (the manager's main mission arms it once the first
        Start_Mission's third copy came: that one is answered as it arrives, no wrong ACKs
        before it, so that a retry limit of 2 is not made to give up; ``stale_src`` None).
        Armed after a first observation with wrong ACKs, it is the second (that one's copies
        stopped right after them: taking them, or its retry limit, both stop there).
        The next new unicast to a drone (not a copy of that Start_Mission) is withheld in
        ``Mission.withheld_again``; after its second copy the same two wrong ACKs go out (its
        seq plus 0x8000 from its drone; its seq from another drone, ``outsider`` when there is
        none); the first copy after them, within ``wait`` s, is answered at once (the right
        ACK) and proves the manager goes on past a wrong ACK: the first observation proved its
        limit reaches a third copy. No copy after them: the script's :meth:`release_again`.
        Not the first command to ``stale_src`` (where one is given), the drone of the first
        observation's wrong-source ACK (it names the Start_Mission's seq), nor to a try's: a manager that
        takes any ACK from the destination may take that stale one for it and send it once
        (the simulator's wrong-seq-ack: RTX-2 skipped, "came once"). A try is spoiled where a
        copy read after the wrong ACKs had reached the socket before them and makes ``limit``
        copies (the first observation's) before them (a receiver behind): it is answered, kept
        in ``Mission.again_spoiled``, and the next new unicast is tried, ``tries`` in all."""
        with self._lock:
            if self.mission is None:
                return
            self.hold_again = True
            self._again_key = None
            self._again_outsider = outsider
            self._again_stale = {} if stale_src is None else {stale_src: None}
            self._again_limit, self._again_tries, self._again_done = limit, tries, set()
            self.mission.withheld_again = Withheld(wrong_ack_wait=wait)
            self.mission.again_spoiled = []

    def _again_step(self, d: Datagram, dst: int, action: int) -> str | None:
        """(lock held) What becomes of ``d`` while the second observation is armed: None, not
        its business (answered as usual); "held"; "wrong": its second copy, the wrong ACKs to
        send; "after": the first copy after them, to answer and release; "spoiled": to answer,
        the try over (:meth:`arm_again`)."""
        assert self.mission is not None
        w = self.mission.withheld_again
        key = (dst, action, bytes(d.data[HEADER_SIZE:]))
        if key in self._again_done:
            return None  # a spoiled try's message: answered as usual
        if w.drone is None:
            if action == _START and dst == self.start_drone:
                return None  # a copy of the first observation's Start_Mission
            if dst in self._again_stale:
                if self._again_stale[dst] in (None, key):
                    self._again_stale[dst] = key  # that command and its copies: answered as usual
                    return None
                del self._again_stale[dst]
            w.drone, self._again_key = dst, key
        elif key != self._again_key:
            return None
        if not w.wrong_acks:  # (this, the receiver thread, sends them before it reads on)
            w.copies.append(d)
            if len(w.copies) != 2:
                return "held"
            self._again_sending = True
            return "wrong"
        if d.t > w.wrong_acks[0].t:
            if d.t <= w.wrong_acks[0].t + w.wrong_ack_wait:
                w.copy_after_wrong_acks = d
            return "after"
        w.copies.append(d)  # a copy that reached the socket before them, read late
        if len(w.copies) < self._again_limit:
            return "held"
        self._again_tries -= 1
        self._again_done.add(key)
        if self._again_tries > 0:
            self.mission.again_spoiled.append(w)
            self.mission.withheld_again = Withheld(wrong_ack_wait=w.wrong_ack_wait)
            self._again_key = None
        else:
            self.hold_again = False  # the last try: kept as it is, the case says why it tells nothing
        return "spoiled"

    def _send_wrong_acks(self, drone: int, seq: int) -> None:
        """(the receiver thread, ``_again_sending`` set) The two wrong ACKs, recorded once both
        left; until then no :meth:`release_again` of the script's ends the observation."""
        others = [x for x in self.drones if x != drone]
        try:
            wrong = [self.ack(drone, (seq + 0x8000) & 0xFFFF),
                     self.ack(others[0] if others else self._again_outsider, seq)]
            with self._lock:
                self._again_stale[wrong[1].src] = None  # for a later try (a spoiled one's)
                if self.mission is not None:
                    self.mission.withheld_again.wrong_acks = wrong
        finally:
            with self._lock:
                self._again_sending = False

    def _again_due(self) -> float | None:
        """(lock held) When the held message's next copy is overdue -- ``wrong_ack_wait`` after
        the wrong ACKs, or after its first copy when no second came -- or None: nothing held,
        or its wrong ACKs on their way (a thread taken off the CPU between the two: recorded
        only after both, the record alone reads "no second copy" then)."""
        if not self.hold_again or self.mission is None or self._again_sending:
            return None
        w = self.mission.withheld_again
        if w.drone is None or not w.copies:
            return None
        return (w.wrong_acks[0].t if w.wrong_acks else w.copies[0].t) + w.wrong_ack_wait

    def again_held(self) -> bool:
        """A message is held for the observation now (its copies came, no right ACK yet)."""
        with self._lock:
            return bool(self.hold_again and self.mission is not None and self.mission.withheld_again.copies)

    def again_overdue(self) -> Withheld | None:
        """The observation held now (``Mission.withheld_again``) where its next copy is overdue
        (:meth:`_again_due`), else None: what the script ends with ``release_again(held=...)``."""
        with self._lock:
            due = self._again_due()
            if due is None or self.driver.clock.monotonic() <= due or self.mission is None:
                return None
            return self.mission.withheld_again

    def release_again(self, latest: Datagram | None = None, *, held: Withheld | None = None) -> None:
        """The second observation over: its held message's ``latest`` copy (default: the last
        held) answered with the right ACK, and nothing more is withheld. ``held``: the
        observation the caller found overdue (:meth:`again_overdue`), ended only where it is
        still the one held and still overdue -- not a later try begun since (a spoiled one's
        successor) nor one whose wrong ACKs are on their way: its right ACK sent between them,
        before the copy they wait for was due, made a correct manager look as if it took one
        (a false MCP-RTX-2, simulator seed 176 of ``preempt=(0.3, 0.3)``)."""
        with self._lock:
            if not self.hold_again or self.mission is None:
                return
            w = self.mission.withheld_again
            if held is not None:
                due = self._again_due()
                if w is not held or due is None or self.driver.clock.monotonic() <= due:
                    return
            self.hold_again = False
            latest = latest or (w.copies[-1] if w.copies else None)
        if latest is not None:
            w.right_ack = self.answer(latest)

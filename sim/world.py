"""One simulated mission: the parties (:mod:`sim.models`), the runner's seeded link per
direction (:mod:`sim.link`: ``harness.impair``'s decisions and delay queue) and stalls, on one
virtual clock (:mod:`sim.clock`) -- issue 38, item 2.

The manager's datagrams go down the link to the drone their MCP header names (the broadcast
ID: to every drone; any other ID: nowhere, as on a shared port nobody listens there); a
drone's go up its own link to the manager. Every copy the links let through waits in one bounded
``harness.impair.DelayQueue`` (as in ``mcp-soak``'s medium) until it is due. A party may be *stalled* (its process off the
CPU): inside one of its stall windows it reads nothing and its timers do not fire; both
happen at the window's end, in the order they fell due. From the first thing that fell due
inside a window (a datagram to read or a timer) to the window's end the party was runnable but
not running: that time is added to its run delay (what ``harness.run_delay`` measures on a real
host from schedstat, D-7), which goes with each datagram it sends to the judge (MCP-RTX-3 and
the veto excuse what the host made late). A stall with nothing due adds nothing, as on a host.

Each party's *view* is what its own socket saw: what it sent as it entered the link, and what
the link delivered as the party read it -- the capture of ``mcp-node --capture`` or
``mcp-soak``'s medium, complete for what that party took part in. The judges
(:mod:`sim.judges`) read the views; the links keep their own record of what they made.
"""

from __future__ import annotations

import math
import random
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

from mcp_conform.harness.impair import DelayQueue, Impairment, ImpairSpec, replace_seed
from mcp_conform.sim.clock import Clock, EventQueue
from mcp_conform.sim.link import Link, check_spec
from mcp_conform.sim.models import DroneModel, ManagerModel, NodeModel
from mcp_conform.spec.codec import BROADCAST_ID, MANAGER_ID, peek_header

__all__ = ["StallParams", "ViewRecord", "World"]

NS = 1_000_000_000
#: the least time between two things one party does, as its capture stamps them: reading a
#: datagram and sending one take a host some microseconds, so a party's stamps never tie (the
#: virtual clock lets a stalled party read a backlog at one instant, whose order a tie would hide)
STEP_NS = 1_000


class ViewRecord(NamedTuple):
    """One datagram as a party's socket saw it (what ``judge.explain_records`` and the monitor
    take: ``t_ns`` and ``data``, the addresses, and the sender's run delay when it is ours)."""

    t_ns: int
    src_addr: Any
    dst_addr: Any
    data: bytes
    tx: bool
    run_delay: int | None


@dataclass(frozen=True)
class StallParams:
    """Up to ``count`` stalls per party, each up to ``max_len`` s, starting within ``span`` s."""

    count: int = 0
    max_len: float = 0.0
    span: float = 0.0

    def windows(self, rng: random.Random) -> list[tuple[float, float]]:
        if not self.count or not self.max_len:
            return []
        out = []
        for _ in range(rng.randint(0, self.count)):
            a = rng.uniform(0.0, self.span)
            out.append((a, a + rng.uniform(0.0, self.max_len)))
        return sorted(out)


class World:
    """Run :meth:`run` once; then read ``views``, ``links`` and the parties' outcomes."""

    def __init__(self, manager: ManagerModel, drones: Sequence[DroneModel], down: ImpairSpec, up: ImpairSpec,
                 seed: int, *, stalls: StallParams = StallParams(), max_time: float = math.inf,
                 max_events: int = 200_000) -> None:
        self.clock = Clock()
        self.queue = EventQueue(self.clock)
        self.manager = manager
        self.drones = {d.node_id: d for d in drones}
        self.parties: dict[int, NodeModel] = {MANAGER_ID: manager, **self.drones}
        rng = random.Random(seed)
        # one link seed for the mission, as mcp-soak gives each mission one; the spec's own is not used
        link_seed = rng.getrandbits(64)
        down_imp = Impairment(replace_seed(check_spec(down), link_seed))
        up_imp = Impairment(replace_seed(check_spec(up), link_seed))
        #: the copies on their way: (due, (to, data, src_addr)), one bounded queue for the links
        self.held: DelayQueue[tuple[int, bytes, Any]] = DelayQueue()
        self.links: dict[tuple[int, int], Link] = {}
        for d in self.drones:
            self.links[(MANAGER_ID, d)] = Link(f"drone{d}:down", down_imp, self.held)
            self.links[(d, MANAGER_ID)] = Link(f"drone{d}:up", up_imp, self.held)
        self.stalls = {p: stalls.windows(random.Random(rng.getrandbits(64))) for p in self.parties}
        self.views: dict[int, list[ViewRecord]] = {p: [] for p in self.parties}
        self.run_delay_ns = {p: 0 for p in self.parties}
        self._armed: dict[int, float | None] = {p: None for p in self.parties}
        self._gen = {p: 0 for p in self.parties}
        #: when something first fell due for a stalled party (runnable, not running), by party
        self._waiting: dict[int, float] = {}
        self._last_ns = {p: -STEP_NS for p in self.parties}
        self.max_time = max_time
        self.max_events = max_events
        self.events = 0
        self.end = 0.0
        self.truncated = False

    # ------------------------------------------------------------------ running
    def run(self) -> World:
        q, held = self.queue, self.held
        for pid, party in self.parties.items():
            party.start(0.0)
            self._arm(pid)
        while True:
            t_ev, t_held = q.peek_time(), held.next_due()
            t = t_ev if t_held is None or (t_ev is not None and t_ev < t_held) else t_held
            if t is None:
                break
            if t > self.max_time or self.events >= self.max_events:
                self.truncated = True
                break
            if t == t_held:  # copies fall due: each is read as its party's next event
                for to, data, src_addr in held.pop_due(t):
                    q.push(t, "rx", to, data, src_addr)
                continue
            t, kind, args = q.pop()
            self.events += 1
            pid = args[0]
            party = self.parties[pid]
            if party.closed:
                continue
            resume = self._stalled(pid, t)
            if resume is not None:
                self._waiting[pid] = min(self._waiting.get(pid, t), t)
                q.push(resume, kind, *args)
                continue
            since = self._waiting.pop(pid, None)
            if since is not None:
                self.run_delay_ns[pid] += int((t - since) * NS)
            if kind == "rx":
                _, data, src_addr = args
                self.views[pid].append(ViewRecord(self._stamp(pid, t), src_addr, party.addr, data, False, None))
                party.receive(data, src_addr, t)
            else:  # "timer"
                _, gen, due = args
                if gen != self._gen[pid]:
                    continue
                self._armed[pid] = None
                party.on_timer(t)
            self._flush(pid, t)
            if not party.closed:
                self._arm(pid)
        if self.truncated or any(not p.closed for p in self.parties.values()):
            # a party still open at the end lives on until the run is cut: its socket (its
            # view) stays open, silent, to ``max_time``
            self.truncated = True
            self.end = self.max_time if self.max_time != math.inf else self.clock.now
        else:
            self.end = self.clock.now
        return self

    def view_end(self, pid: int) -> float:
        """When the party's view ends: it closed, or the run did."""
        closed = self.parties[pid].closed_at
        return self.end if closed is None else closed

    def _stamp(self, pid: int, t: float) -> int:
        """The party's capture time of something it read or sent at ``t``: its own clock's, at
        least ``STEP_NS`` after its last (one party does one thing at a time)."""
        ns = max(round(t * NS), self._last_ns[pid] + STEP_NS)
        self._last_ns[pid] = ns
        return ns

    def _stalled(self, pid: int, t: float) -> float | None:
        for a, b in self.stalls[pid]:
            if a <= t < b:
                return b
        return None

    def _arm(self, pid: int) -> None:
        t = self.parties[pid].timer()
        if t == self._armed[pid]:
            return
        self._gen[pid] += 1
        self._armed[pid] = t
        if t is not None and t != math.inf:
            self.queue.push(t, "timer", pid, self._gen[pid], t)

    def _flush(self, pid: int, now: float) -> None:
        party = self.parties[pid]
        for data in party.outbox(now):
            self._send(pid, party, data, now)

    def _send(self, pid: int, party: NodeModel, data: bytes, now: float) -> None:
        if pid == MANAGER_ID:
            head = peek_header(data, require_preamble=False)
            dst = head[0] if head is not None else BROADCAST_ID
            targets = list(self.drones) if dst == BROADCAST_ID else [dst] if dst in self.drones else []
            dst_addr = self.drones[dst].addr if dst in self.drones else None
        else:
            targets, dst_addr = [MANAGER_ID], self.manager.addr
        self.views[pid].append(ViewRecord(self._stamp(pid, now), party.addr, dst_addr, data, True,
                                          self.run_delay_ns[pid]))
        src_addr = party.addr
        for to in targets:
            self.links[(pid, to)].send(data, now, lambda body, to=to: (to, body, src_addr))  # type: ignore[misc]  # mypy: a default argument

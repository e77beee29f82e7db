"""The judges on a simulated mission (issue 38, item 3): each party's view (``World.views``)
fed to the project's trace monitor (:class:`judge.monitor.Monitor`) and to the explanation
judge (:mod:`judge.explain`, through :mod:`judge.explain_records`), as ``mcp-capture check``
judges a node's own capture (``judge.judging``: complete for what that node took part in,
``party`` = its ID, its own datagrams with its run delay, and its run delay as its view ends,
``Monitor.run_delay``) and as ``mcp-soak`` reads the
verdicts: each node is judged in its own view only, since the other end is seen through the
link (copies lost, duplicated, held back).

The link's own record goes where the judge takes it: ``judge.explain``'s
:attr:`Bounds.copy_capacity` ("ACKs one copy may draw: 1 + the copies the link may make of
it") is 1 + the most extra copies the link into a sender made of one datagram (see
:func:`_explain`). The monitor takes no link record; what its veto dropped is kept
(:attr:`Judged.vetoed`: the old judge's verdict, which a regression seed shows).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any

from mcp_conform.judge.explain import Bounds, Verdict, decide_receiver, decide_sender
from mcp_conform.judge.explain_model import RANK
from mcp_conform.judge.explain_records import traces_from_datagrams
from mcp_conform.judge.monitor import Monitor, Violation
from mcp_conform.sim.world import NS, ViewRecord, World

__all__ = ["Judged", "judge_world"]


@dataclass
class Judged:
    """Per party: the monitor's violations blamed on it (in its own view), its verdict table,
    and the explanation judge's verdicts (MCP-ACK-1/2, MCP-RTX-1/2 and their disjunctions)."""

    violations: dict[int, list[Violation]] = field(default_factory=dict)
    verdicts: dict[int, dict[str, str]] = field(default_factory=dict)
    explained: dict[int, dict[str, Verdict]] = field(default_factory=dict)
    #: the MCP-RTX-1/2 failures judge.explain's veto dropped (``Monitor.vetoed``), per party
    vetoed: dict[int, list[Violation]] = field(default_factory=dict)
    #: the judges that ran (``monitor``, ``explain``): one left out has no verdict here, and
    #: ``sim.search.check`` refuses to read a property of it
    judges: tuple[str, ...] = ("monitor", "explain")

    def failed(self, pid: int) -> set[str]:
        """The MUST rules the monitor failed for ``pid``."""
        return {r for r, v in self.verdicts.get(pid, {}).items() if v == "failed"}

    def warned(self, pid: int) -> set[str]:
        return {r for r, v in self.verdicts.get(pid, {}).items() if v == "warned"}

    def proven(self, pid: int) -> set[str]:
        return {r for r, v in self.explained.get(pid, {}).items() if v.status == "proven"}

    def summary(self) -> dict[str, Any]:
        return {str(p): {"failed": sorted(self.failed(p)), "warned": sorted(self.warned(p)),
                         "proven": sorted(self.proven(p)),
                         "violations": [f"{v.rule}: {v.actual}" for v in vs]}
                for p, vs in sorted(self.violations.items())}


def judge_world(w: World, *, rto: float, challenge: int, items: tuple[Any, ...],
                explain: bool = True, monitor: bool = True) -> Judged:
    """Judge every party's view of ``w`` (see the module docstring) by the monitor and
    ``judge.explain``, or one of them (``monitor=False`` / ``explain=False``: a caller that
    reads one judge's verdicts does not pay for the other's; neither reads the other's)."""
    out = Judged(judges=tuple(name for name, on in (("monitor", monitor), ("explain", explain)) if on))
    drones = tuple(w.drones)
    window = max(0.5, 2 * rto)  # mcp-soak's ACK window for a mission's views
    for pid, view in w.views.items():
        if monitor:
            _monitor(out, w, pid, view, rto=rto, window=window, drones=drones, challenge=challenge, items=items)
        if explain and view:
            out.explained[pid] = _explain(w, pid, view, window, rto)
    return out


def _monitor(out: Judged, w: World, pid: int, view: list[ViewRecord], *, rto: float, window: float,
             drones: tuple[int, ...], challenge: int, items: tuple[Any, ...]) -> None:
    """The trace monitor on ``pid``'s own view: its violations, vetoed failures and verdicts into ``out``."""
    mon = Monitor(rto=rto, ack_window=window, drones=drones, challenge=challenge, waypoints=items,
                  complete=True, party=pid, rto_declared=True)  # every model's timeout is rto
    found: list[Violation] = []
    for r in view:
        if r.tx:
            found += mon.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data, run_delay=r.run_delay)
        else:
            found += mon.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data)
    end = int(w.view_end(pid) * NS)
    # its run delay as its view ends (D-7): a stall after its last datagram is known too
    mon.run_delay(end, pid, w.run_delay_ns[pid])
    found += mon.finish(end)
    out.violations[pid] = [v for v in found if v.node == pid]
    out.vetoed[pid] = [x.violation for x in mon.vetoed if x.violation.node == pid]
    out.verdicts[pid] = mon.verdicts().get(pid, {})


def _explain(w: World, pid: int, view: list[ViewRecord], window: float, rto: float) -> dict[str, Verdict]:
    """``judge.explain``'s verdicts of ``pid`` in its own view: MCP-ACK-1/2 where it receives,
    MCP-RTX-1/2 where it sends. Its own view shows each copy the link delivered to it (a
    duplicate is a copy it must ACK) and each ACK it sent once, so as a receiver one copy draws
    one ACK; as a sender it sees the ACKs the link delivered, so one copy may draw one more
    for each extra copy the link into it made (:attr:`Bounds.copy_capacity`). Its stalls are the
    observer's lag (``copy_early`` / ``ack_early``: read late) and its run delay (``rto_slack``:
    a copy sent late), as ``harness.run_delay`` measures them on a real host (D-7): the run
    delay its own datagrams carry and the one read as its view ends (as ``Monitor.run_delay``
    takes it), over which ``judge.explain`` judges a silence (:attr:`Trace.run_delay`)."""
    capacity = max((link.max_copies for (_, b), link in w.links.items() if b == pid), default=1)
    # a stalled party reads late (what reached its socket is seen when it is read): the
    # observer's lag; it sends late (its timers fire late) by its run delay, which its readings
    # carry to judge.explain, not a bound here
    lag = max((b - a for a, b in w.stalls[pid]), default=0.0)
    slack = Bounds.rto_slack + lag
    as_receiver = Bounds(ack_window=window, rto=rto, copy_early=lag, rto_slack=slack)
    as_sender = Bounds(ack_window=window, rto=rto, ack_early=lag, copy_capacity=capacity)
    # the view goes on to the party's end, not its last datagram: a silence is seen
    end_ns = int(w.view_end(pid) * NS)
    end = (end_ns - view[0].t_ns) / NS
    samples = {pid: [(end_ns, w.run_delay_ns[pid])]}
    mine: dict[str, Verdict] = {}
    for (s, r), t in sorted(traces_from_datagrams(view, complete=True, samples=samples).items()):
        t = replace(t, end=max(t.end, end))
        found = {}
        if r == pid:
            found.update(decide_receiver(t, as_receiver))
        if s == pid:
            found.update(decide_sender(t, as_sender))
        for rule, v in found.items():
            old = mine.get(rule)
            if old is None or RANK[v.status] > RANK[old.status]:
                mine[rule] = v
    return mine

"""Whether an Nsqd input made the difference, and what a campaign may spend on triage (issue 36
items 2 and 5).

A hit is tied to its input only when the same observation without the input shows nothing:
before an input is replayed, the backend is watched on a connection sent nothing
(:func:`watch_stream`, the observation of mcp-conform's FRM/test_backend_frames_are_well_formed
and MSG/test_update_stream_keeps_its_period: every frame the backend sends breaks neither
NSQD-FRM-1 nor NSQD-MSG-2, "the first [UPDATE] soon after accepting it, and no gap longer than
update_gap_max_s", NSQD-MSG-1) and, for what a probe showed (a hang, a lost stream, a command
without its effect), the probe is sent on a fresh backend with no case before it
(:func:`baseline`: the valid command in the input's place). A baseline that fails is the
target's behaviour: reported under the rule the baseline broke, with no input blamed
(``finding.json`` ``"no_input": true``, replayed by the same baseline).

The budget (``fuzz.budget``): ``--duration`` bounds the whole campaign, triage included, within
``GRACE_S``; triage may spend ``TRIAGE_SHARE`` of the campaign (``budget_left``,
``over_budget``); once spent, a new signature's hits are counted in the summary
(``untriaged``), not replayed.

One observation of triage lives here too: :func:`leak_check` observes NSQD-CON-3 as its rule does (descriptors over
connect/close cycles with nothing sent) before the first case.
"""

from __future__ import annotations

import time
from typing import Any

from mcp_conform.fuzz.budget import check_late
from mcp_conform.fuzz.confirm import confirm_n
from mcp_conform.fuzz.loop import triage_time
from mcp_conform.fuzz.nsqd_backend import Backend, Hit
from mcp_conform.fuzz.nsqd_oracles import Signature
from mcp_conform.spec import NSQD

__all__ = ["PROBED", "baseline", "leak_check", "watch_stream"]

PROBED = "(the probe with no case before it)"  # a baseline hit's detail ends so when the probe showed it
STREAM_UPDATES = 3  # UPDATEs a baseline connection reads (mcp-conform's FRM-1 case reads three)


def watch_stream(b: Backend, updates: int = STREAM_UPDATES) -> Hit | None:
    """A new connection, sent nothing, watched until ``updates`` UPDATEs came with no gap over
    update_gap_max_s (None), or until the stream breaks a rule: a frame against NSQD-FRM-1 or
    NSQD-MSG-2 (the runner's own judgement, ``Conn.violation``), a gap (from the accept to the
    first UPDATE too) over update_gap_max_s (NSQD-MSG-1), the process's death, or no
    connection accepted (NSQD-ROB-1)."""
    b._drop()
    conn = b._connect()
    if conn is None:
        return b.death_hit(0.3) or Hit(Signature("hang", "not accepting", (), "NSQD-ROB-1"),
                                       "a new connection was not accepted (sent nothing)")
    gap_max = float(NSQD.params["update_gap_max_s"])

    def last() -> float:
        ups = conn.updates()
        return ups[-1].t if ups else conn.opened

    while (conn.violation() is None and len(conn.updates()) < updates and conn.closed_at is None
           and time.monotonic() - last() <= gap_max):
        conn.pump(min(0.05, max(0.0, last() + gap_max - time.monotonic()) + 0.01))
    n = len(conn.updates())
    dead = b.death_hit(0.03 if conn.closed_at is not None else 0.0)
    if dead is not None:
        return dead
    v = conn.violation()
    if v is not None:
        return Hit(Signature("protocol", v.rule, (), v.rule),
                   f"{v.expected}; {v.actual} (on a connection sent nothing)")
    times = [conn.opened] + [u.t for u in conn.updates()]
    gaps = [y - x for x, y in zip(times, times[1:], strict=False)] + ([time.monotonic() - times[-1]] if n < updates else [])
    worst = max(gaps)
    if worst > gap_max:
        return Hit(Signature("hang", "UPDATE stream stopped", (), "NSQD-MSG-1"),
                   f"UPDATE at least every {gap_max:g} s while connected: a gap of {worst:.2f} s "
                   f"({n} UPDATE(s)) on a connection sent nothing")
    if conn.closed_at is not None:
        return Hit(Signature("hang", "closed a connection sent nothing", (), "NSQD-MSG-1"),
                   f"UPDATE while a client is connected: the backend closed a connection sent nothing "
                   f"after {n} UPDATE(s)")
    return None


def needs_probe(sig: Signature) -> bool:
    """What a probe showed (its baseline is the probe on a backend sent nothing before it): a
    hang, a lost stream. (A command's own effect is the command's: its finding is the command
    alone, ``StreamTriage._triage``.)"""
    return sig.oracle in ("hang", "desync")


def baseline(b: Backend, sig: Signature, *, probe: bool) -> Hit | None:
    """The observation behind ``sig`` without its input, on ``b`` (a fresh backend): the
    stream watched on a connection sent nothing, then (``probe``, or a hit a probe shows) the
    probe command with no case before it. A hit: the target's behaviour."""
    hit = watch_stream(b)
    if hit is None and (probe or needs_probe(sig)):
        hit = b.probe()
        if hit is not None:
            hit = Hit(hit.signature, f"{hit.detail} {PROBED}", hit.stderr)
    return hit


def leak_check(self: Any, backend: Backend) -> Backend:  # noqa: PLR0914 - self: the triage
    """NSQD-CON-3 as its rule observes it, before the first case: open descriptors over
    connect/close cycles with nothing sent (``StreamSession.cycle_connections``: twice
    ``fd_growth_max`` + 1, within an eighth of ``--duration``, at most 10 s), on a process of
    its own; confirmed on ``n_of_n`` fresh ones, within the deadline and triage's share. (Checked
    over the campaign, every 400 cases once 50 connections were made, it never showed on a
    real backend that dies every 15 cases or so.)"""
    grow_max = int(NSQD.params["fd_growth_max"])
    # its share of a short campaign small (a --duration 4 campaign spent it all on a loaded host)
    within = min(10.0, self.duration / 8) if self.duration is not None else 10.0

    def grown(b: Backend) -> tuple[int, str] | None:
        before = b.session.settled_fds(quiet=0.1, limit=within / 4)
        done = b.session.cycle_connections(2 * (grow_max + 1), within=within)
        after = b.session.settled_fds(limit=within / 2)
        if before is None or after is None or b.session.death() is not None:
            return None
        return after - before, f"{before} -> {after} open descriptors over {done} connect/close cycles"

    first = grown(backend)
    if first is None or first[0] <= grow_max:
        return backend
    sig = Signature("leak", "open descriptors grow with connections", (), "NSQD-CON-3")

    def once() -> tuple[int, str] | None:
        # not HitTriage.confirm_logged's replay nor HitTriage.fresh: these cycles have never been
        # counted as triage's replays or its "triage replay" restarts (summary.json's counts)
        check_late(self)
        self.current = self.current.fresh()
        again = grown(self.current)
        return again if again is not None and again[0] > grow_max else None

    self.current = backend
    with triage_time(self, sig.describe()):
        conf = confirm_n(once, self.n_of_n, until_miss=False)
        if not conf.confirmed:
            self.not_confirmed(sig.rule, None, conf, shape=sig.describe(), actual=first[1],
                               why="a process's descriptors grew over the cycles, then not on every fresh one")
        else:
            self.add_found(sig, first[1], conf.replays, "connect/close cycles")
        return self.restart(self.current)
    return self.current

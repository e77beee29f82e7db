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

The budget: ``--duration`` bounds the whole campaign, triage included. No replay starts after
the deadline; one under way is not cut, so a campaign ends within ``--duration`` plus
``fuzz.budget.GRACE_S`` (the longest one replay takes: a backend restarted, a connection's
timeout, a probe's two effect windows, a sanitizer report read whole), the one bound of both
protocols' campaigns and of their ``--jobs`` parents. Triage may spend
:data:`TRIAGE_SHARE` of the campaign (of ``--duration``, or of the time so far under
``--max-cases``); once spent, a new signature's hits are counted in the summary
(``untriaged``), not replayed.
"""

from __future__ import annotations

import time
from typing import Any

from fuzz.budget import GRACE_S, Late
from fuzz.stream_backend import Backend, Hit
from fuzz.stream_oracles import Signature
from spec import NSQD

__all__ = ["GRACE_S", "PROBED", "TRIAGE_SHARE", "UNCONFIRMED_TRIES", "Late", "baseline", "watch_stream"]

TRIAGE_SHARE = 0.25  # of the campaign's time, triage's budget
UNCONFIRMED_TRIES = 2  # a signature that did not reproduce this many times is counted, not triaged again
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
    alone, ``StreamCampaign._triage``.)"""
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


def budget_left(campaign: Any, now: float) -> bool:
    """Whether triage may start on a new signature: its seconds so far under
    :data:`TRIAGE_SHARE` of the campaign (``--duration``, else the time so far), and the
    deadline not passed."""
    if campaign.duration is not None and now >= campaign.started + campaign.duration:
        return False
    base = campaign.duration if campaign.duration is not None else max(now - campaign.started, 1.0)
    return campaign.triage_s == 0.0 or campaign.triage_s < TRIAGE_SHARE * base

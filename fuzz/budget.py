"""The time a campaign may take, one bound for both protocols (issue 36 item 2: "``--duration``
bounds the whole campaign, triage included").

A campaign counts ``--duration`` from its start (with ``--jobs N``, the parent's: its workers'
deadlines are the parent's, so their process and target start lie inside the duration). No
replay starts after the deadline (:class:`Late`); the one under way is not cut, so a campaign
ends within ``--duration`` plus :data:`GRACE_S`, the longest one replay takes (a target
restarted, a connection's timeout, a probe's effect windows, a sanitizer's report read
whole). Both campaigns state the two in ``summary.json`` and on their last line. A ``--jobs``
parent stops waiting for its workers at that same bound (:func:`campaign_end`): a worker still
running then is killed and reported as having given no result. ``--engine both`` shares the
budget out between its engines, time and cases alike (:func:`engine_turns`). Triage may
spend :data:`TRIAGE_SHARE` of the campaign (of ``--duration``, or of the time so far under
``--max-cases``): a new triage starts under 90 % of it (:func:`budget_left`), and one that
reaches it ends there (:func:`over_budget`); a campaign given to these (Nsqd's) counts, not
replays, a new signature's hits once it is spent. MCP's triage is bounded by the deadline
alone so far (``fuzz.triage``).
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

__all__ = ["GRACE_S", "TRIAGE_SHARE", "UNCONFIRMED_TRIES", "Late", "budget_left", "campaign_end", "check_late",
           "engine_turns", "over_budget", "past_deadline"]

GRACE_S = 10.0  # s past --duration a campaign may take: the replay under way at the deadline
TRIAGE_SHARE = 0.25  # of the campaign's time, triage's budget
UNCONFIRMED_TRIES = 2  # a signature that did not reproduce this many times is counted, not triaged again


class Late(Exception):
    """The campaign's deadline passed: no further replay starts."""


def campaign_end(started: float, duration: float | None) -> float:
    """The monotonic time by which a campaign started at ``started`` has ended: ``--duration``
    plus :data:`GRACE_S`; no bound (inf) when the campaign has none (``--max-cases`` alone)."""
    return float("inf") if duration is None else started + duration + GRACE_S


def engine_turns(engine: str, started: float, duration: float | None, max_cases: int | None,
                 ) -> Iterator[tuple[str, float, int | None]]:
    """Each engine ``--engine`` runs (``both``: the stateless one, then the stateful one) with
    its deadline (the campaign's ``duration`` split evenly, counted from ``started``) and the
    cases the campaign may have reached by the end of its turn (``max_cases`` split alike,
    cumulative: an engine that ended early leaves the rest to the next)."""
    engines = ["stateless", "stateful"] if engine == "both" else [engine]
    for k, name in enumerate(engines):
        share = (k + 1) / len(engines)
        yield (name, float("inf") if duration is None else started + duration * share,
               None if max_cases is None else max_cases * (k + 1) // len(engines))


def past_deadline(t: Any, now: float) -> bool:
    """Whether ``--duration`` (``t.duration``, counted from ``t.started``) has passed."""
    return t.duration is not None and now >= t.started + t.duration


def check_late(t: Any, *, share: bool = True) -> None:
    """Before a replay: :class:`Late` once the campaign's deadline passed, or (``share``) once
    the triage under way took triage past its budget (:func:`over_budget`)."""
    now = time.monotonic()
    if past_deadline(t, now) or (share and over_budget(t, now)):
        raise Late


def budget_left(campaign: Any, now: float) -> bool:
    """Whether triage (``campaign``: its ``seconds`` so far, the campaign's ``started`` and
    ``duration``) may start on a new signature: its seconds so far under
    :data:`TRIAGE_SHARE` of the campaign (``--duration``, else the time so far), and the
    deadline not passed."""
    if past_deadline(campaign, now):
        return False
    base = campaign.duration if campaign.duration is not None else max(now - campaign.started, 1.0)
    # room left for the triage it starts (a real backend's took 5-10 s): the share is a bound
    # (``over_budget`` ends a triage that would pass it)
    return campaign.seconds == 0.0 or campaign.seconds < 0.9 * TRIAGE_SHARE * base


def over_budget(campaign: Any, now: float) -> bool:
    """Whether the triage in progress (begun at ``campaign.triage_from``) has taken the
    campaign's triage past :data:`TRIAGE_SHARE` of its ``--duration``: it ends there (``Late``),
    unless it is the campaign's first, as :func:`budget_left` lets the first begin."""
    if campaign.duration is None or campaign.triage_from is None or campaign.seconds == 0.0:
        return False  # the campaign's first triage ends as it ends (a 12 s campaign's 3 s of share held none)
    return campaign.seconds + (now - campaign.triage_from) > TRIAGE_SHARE * campaign.duration

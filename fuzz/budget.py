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
budget out between its engines, time and cases alike (:func:`engine_turns`).
"""

from __future__ import annotations

from collections.abc import Iterator

__all__ = ["GRACE_S", "Late", "campaign_end", "engine_turns"]

GRACE_S = 10.0  # s past --duration a campaign may take: the replay under way at the deadline


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

"""N of N, one rule for both protocols' triage (issue 18 item 9; issue 37: one triage).

The loop every protocol's campaign runs, protocol-neutral (MCP: ``fuzz.campaign`` with
``fuzz.triage``; Nsqd: ``fuzz.nsqd_triage`` with ``fuzz.nsqd_blame``):

1. draw a case from an engine (stateless mutators, or a stateful program), play it through
   the target, run the oracles on what it did;
2. on a hit: counted, not triaged, when its group (rule and shape, or signature) is already
   a finding, when it did not reproduce before (Nsqd: ``UNCONFIRMED_TRIES``) or when
   triage's time is spent (``fuzz.budget``: ``TRIAGE_SHARE``, the deadline; ``Late``);
3. else blame by a baseline: the same observation without the input, on a fresh target, once
   per worker; a baseline that breaks the rule, confirmed N of N, is the target's behaviour
   (a finding with no input blamed) and the hit is counted there;
4. else the suspects of the hit (the culprit, a death's usual killers, the cases since the last
   good probe), each replayed alone on a fresh process, then all, then delta debugging
   (``fuzz.ddmin``) down to a minimal input;
5. the minimal input replayed N more times on fresh processes (:func:`confirm_n`): every one
   shows the hit's signature, or there is no finding -- a hit seen in triage and not in every
   confirming replay is named environment-dependent (``fuzz.environment``), with how often
   it showed (:meth:`Confirmation.note`);
6. the finding kept in the store (``fuzz.findings``), progress ticked, and on a signal or the
   budget's end the campaign writes what it has.

Steps 2-5 are ``fuzz.triage_core``'s, each protocol's triage declaring its parts; step 5 is
this module's, run by ``fuzz.triage_core.HitTriage.confirm_logged`` for MCP's minimal sequence,
MAVLink's minimal cases and Nsqd's, and by Nsqd's descriptor leak and a stateful program's ops.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Generic, TypeVar

from mcp_conform.fuzz.environment import EnvironmentLog

__all__ = ["Confirmation", "confirm_n"]

R = TypeVar("R")


@dataclass
class Confirmation(Generic[R]):
    """What ``n`` confirming replays showed: each replay's result (None: the hit's signature
    did not show), in order."""

    results: list[R | None]
    n: int

    @property
    def hits(self) -> list[R]:
        """The replays that showed it, in order."""
        return [r for r in self.results if r is not None]

    @property
    def confirmed(self) -> bool:
        """N of N: every one of the ``n`` replays showed it."""
        return len(self.hits) == self.n

    @property
    def replays(self) -> str:
        """As ``finding.json`` states it: ``"3 of 3"``."""
        return f"{len(self.hits)} of {self.n}"

    def note(self, log: EnvironmentLog, rule: str, shape: str, actual: str, why: str) -> None:
        """Not N of N: named environment-dependent in ``log``, counting the replay that showed
        it in triage with the confirming ones (seen 1 + hits of 1 + tries)."""
        log.note(rule, shape, actual, 1 + len(self.hits), 1 + len(self.results), why)


def confirm_n(replay: Callable[[], R | None], n: int, *, until_miss: bool = True) -> Confirmation[R]:
    """``replay`` (one replay on a fresh target: its result when the hit's signature shows,
    else None) ``n`` times; ``until_miss``: none after the first that does not show it (N of N
    is lost then), else all ``n`` (how often it shows, for the environment note). ``Late``
    from ``replay`` (the deadline) passes through."""
    results: list[R | None] = []
    for _ in range(n):
        results.append(replay())
        if results[-1] is None and until_miss:
            break
    return Confirmation(results, n)

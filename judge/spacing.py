"""MCP-RTX-3's spacing judgement, one function for the trace monitor and the runner's case
(``conformance``'s ``expect_even_spacing``): "every gap between successive copies lies within
±20 % of the median gap, and no gap is shorter than 50 ms".

A loaded host can keep a correct node off the CPU, so it really sends a copy late. Where the
node's run delay (time runnable but waiting for a CPU, ``harness.run_delay``) is known at each
copy, a gap longer than the allowance is excused when the run delay accrued over it accounts
for the excess, and a short gap right after such an excused one when the two together keep the
schedule (a node on an absolute schedule catching up). The 50 ms floor is never excused, and
nothing is where the run delay is unknown (attach mode, pcaps): the verdict is then the plain
rule's (decision D-7, docs/spec.md).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

from mcp_conform.judge._monitor_base import JITTER_NS, RTX_MIN_GAP_NS, RTX_TOLERANCE, median

__all__ = ["Spacing", "judge_spacing"]


class Spacing(NamedTuple):
    """The judgement of one message's gaps (ns)."""

    median: int
    allowance: float  # a gap may differ from the median by this much
    bad: list[int]  # the gaps that break the rule, unexcused
    excused: int  # outlying gaps excused by the host's load
    starved: int  # the run delay (ns) over the excused long gaps


def judge_spacing(gaps: Sequence[int], run_delays: Sequence[int | None] | None = None) -> Spacing:
    """MCP-RTX-3 over ``gaps`` (ns between successive copies, at least two); ``run_delays``:
    the sender's cumulative run delay at each copy (one more than ``gaps``), None where unknown.
    The gap between copies k and k+1 was starved by ``run_delays[k+1] - run_delays[k]``.

    The median the gaps are held to is the observed gaps' or, where run delays are known, that
    of the gaps less the run delay over each (the schedule the node kept while it could run) or
    that of the gaps no run delay accrued over, whichever leaves fewer gaps unexcused: a node
    kept off the CPU before most of its copies has a median stretched by the host, and its one
    copy sent on time is then no short gap (seen at load ~16: gaps of 300 ms, the node's --rto
    0.2, and one of 200.1 ms warned); a run delay may exceed the lateness it caused (the node ran
    late at other work too), so the unstarved gaps' median is the schedule's where the net one
    is too short (the sweep: gaps 5,000 and 17,011 ms, 14,760 of run delay over the second).
    Each is an explanation of the trace; a gap breaks the rule only under the one that keeps
    the most gaps."""
    g = list(gaps)
    rd = list(run_delays or ())
    starved = [_starved(rd, k) for k in range(len(g))]
    best = _judge(g, starved, median(g))
    if any(starved):
        free = [x for x, s in zip(g, starved, strict=True) if not s]
        for schedule in ([x - s for x, s in zip(g, starved, strict=True)], free):
            other = _judge(g, starved, median(schedule)) if schedule and best.bad else best
            if len(other.bad) < len(best.bad):
                best = other
    return best


def _starved(rd: list[int | None], k: int) -> int:
    """The run delay (ns) accrued over gap ``k``, 0 where unknown."""
    a, b = (rd[k], rd[k + 1]) if k + 1 < len(rd) else (None, None)
    return b - a if a is not None and b is not None and b > a else 0


def _judge(g: list[int], starved_over: list[int], med: int) -> Spacing:
    """The gaps ``g`` held to ``med``."""
    allowance = RTX_TOLERANCE * med + JITTER_NS
    bad: list[int] = []
    excused = starved_total = 0
    after_excused_long = False
    for k, x in enumerate(g):
        was_long, after_excused_long = after_excused_long, False
        if x < RTX_MIN_GAP_NS:
            bad.append(x)  # a storm: never the host's doing
            continue
        if abs(x - med) <= allowance:
            continue
        if x > med:
            starved = starved_over[k]
            if starved and x - starved <= med + allowance:
                excused += 1
                starved_total += starved
                after_excused_long = True
                continue
        elif was_long and abs(g[k - 1] + x - 2 * med) <= allowance:
            excused += 1  # catching up after a late copy: the schedule is kept
            continue
        bad.append(x)
    return Spacing(med, allowance, bad, excused, starved_total)

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
    The gap between copies k and k+1 was starved by ``run_delays[k+1] - run_delays[k]``."""
    g = list(gaps)
    med = median(g)
    allowance = RTX_TOLERANCE * med + JITTER_NS
    rd = list(run_delays or ())
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
            a, b = (rd[k], rd[k + 1]) if k + 1 < len(rd) else (None, None)
            starved = b - a if a is not None and b is not None and b > a else 0
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

"""MCP-RTX-3 under host load (``judge.spacing``): a gap between a node's copies is excused only
as far as the node's run delay (time the host kept it runnable but off the CPU) accounts for
it; the 50 ms floor never is; unknown delays excuse nothing. The same helper judges in the
trace monitor and in the runner's case (``expect_even_spacing``)."""

from __future__ import annotations

import pytest

from mcp_conform.conformance._case_base import DatagramCaseBase
from mcp_conform.harness.errors import CaseFailure
from mcp_conform.judge.spacing import judge_spacing
from mcp_conform.spec.codec import Action, peek_header
from tests.judge.monitor_faults import _finish, _started
from tests.judge.monitor_scripts import MANAGER_ADDR, Script

MS = 10**6
EVEN = [300 * MS, 300 * MS, 385 * MS, 300 * MS]  # one copy 85 ms late: outside 300 ± 75 ms


# ---------------------------------------------------------------- the excusal function
def test_a_long_gap_is_excused_only_by_enough_starvation():
    assert judge_spacing(EVEN).bad == [385 * MS]  # no run delays: the plain rule
    starved = judge_spacing(EVEN, [0, 0, 0, 90 * MS, 90 * MS])
    assert starved.bad == [] and starved.excused == 1 and starved.starved == 90 * MS
    # 5 ms of run delay cannot account for 85 ms of lateness (385 - 5 > 375)
    assert judge_spacing(EVEN, [0, 0, 0, 5 * MS, 5 * MS]).bad == [385 * MS]
    # starvation over another gap excuses nothing here
    assert judge_spacing(EVEN, [0, 90 * MS, 90 * MS, 90 * MS, 90 * MS]).bad == [385 * MS]


def test_a_short_catch_up_gap_right_after_an_excused_late_copy_is_excused():
    gaps = [300 * MS, 300 * MS, 390 * MS, 210 * MS, 300 * MS]  # an absolute schedule catching up
    assert judge_spacing(gaps).bad == [390 * MS, 210 * MS]
    sp = judge_spacing(gaps, [0, 0, 0, 90 * MS, 90 * MS, 90 * MS])
    assert sp.bad == [] and sp.excused == 2
    # a short gap with no late copy before it is not a catch-up
    short = [300 * MS, 210 * MS, 300 * MS, 300 * MS]
    assert judge_spacing(short, [0, 0, 0, 0, 0]).bad == [210 * MS]
    # after an excused late copy, a catch-up that overshoots the schedule is not excused
    over = [300 * MS, 300 * MS, 390 * MS, 100 * MS, 300 * MS]
    assert judge_spacing(over, [0, 0, 0, 90 * MS, 90 * MS, 90 * MS]).bad == [100 * MS]


def test_a_node_kept_off_the_cpu_before_most_copies_is_held_to_its_own_schedule():
    """Most copies late by the host (their gaps' median stretched from the node's 200 ms to
    300 ms) and one on time: the on-time gap is no short gap (a false MCP-RTX-3 warning at load
    ~16 in test_schedule_interleave); the median the gaps are held to is the one of the gaps
    less their run delay, where that leaves fewer outliers."""
    gaps = [300 * MS, 300 * MS, 300 * MS, 200 * MS, 300 * MS]
    assert judge_spacing(gaps).bad == [200 * MS]  # no run delays: the plain rule
    sp = judge_spacing(gaps, [0, 100 * MS, 200 * MS, 300 * MS, 300 * MS, 400 * MS])
    assert sp.bad == [] and sp.median == 200 * MS and sp.excused == 4 and sp.starved == 400 * MS
    # starvation too small to bring the long gaps to the short one's schedule excuses nothing
    assert judge_spacing(gaps, [0, 20 * MS, 40 * MS, 60 * MS, 60 * MS, 80 * MS]).bad == [200 * MS]
    # more run delay than lateness (the node ran late at other work too): the gaps no run delay
    # accrued over keep the schedule (a sweep's correct manager: 5,000 and 17,011 ms, 14,760 ms
    # of run delay over the second)
    assert judge_spacing([5000 * MS, 17011 * MS], [0, 0, 14760 * MS]).bad == []
    assert judge_spacing([5000 * MS, 17011 * MS], [0, 0, 0]).bad == [5000 * MS, 17011 * MS]
    # an uneven node the host did not hold back stays uneven whatever the median
    uneven = [300 * MS, 200 * MS, 300 * MS, 200 * MS, 300 * MS]
    assert judge_spacing(uneven, [0, 0, 0, 0, 0, 0]).bad == [200 * MS, 200 * MS]


def test_the_floor_is_never_excused():
    gaps = [60 * MS, 40 * MS, 60 * MS]  # 40 ms: a storm, however starved the node was
    assert judge_spacing(gaps, [0, 10**9, 2 * 10**9, 3 * 10**9]).bad == [40 * MS]


def test_unknown_run_delays_excuse_nothing():
    assert judge_spacing(EVEN, [None] * 5).bad == [385 * MS]
    assert judge_spacing(EVEN, [0, 0, 0, None, 90 * MS]).bad == [385 * MS]
    assert judge_spacing(EVEN, [0, 0, None, 90 * MS, 90 * MS]).bad == [385 * MS]


# ---------------------------------------------------------------- the trace monitor
def _script(gaps: list[float]) -> Script:
    s = _started()
    s.exchange(0, 1, Action.WP_OFF, deaf=len(gaps), gaps=gaps)
    return _finish(s)


def _rtx3(s: Script, starve_ns: int | None, late_copy: int = 3) -> list[str]:
    """Feed ``s`` with the manager's run delay on each of its messages: ``starve_ns`` accrued
    just before its WP_Off copy number ``late_copy`` (0-based; None: no run delays)."""
    wp_off = next(r.data for r in s.datagrams() if r.src_addr == MANAGER_ADDR
                  and (peek_header(r.data) or (0, 0, 0, -1))[3] == Action.WP_OFF)
    copies = [r for r in s.datagrams() if r.data == wp_off]
    assert len(copies) == 5
    t_late = copies[late_copy].t_ns
    m = s.monitor()
    out = []
    for r in sorted(s.datagrams(), key=lambda r: r.t_ns):
        rd = None
        if starve_ns is not None and r.src_addr == MANAGER_ADDR:
            rd = 1_000_000 + (starve_ns if r.t_ns >= t_late else 0)
        out += m.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data, r.origin, run_delay=rd)
    out += m.finish(s.end_ns())
    return [v.rule for v in out]


def test_the_monitor_excuses_a_copy_the_host_made_late():
    s = _script([0.2, 0.2, 0.28, 0.2])  # the third gap 80 ms late: outside 200 ± 55 ms
    assert _rtx3(s, None) == ["MCP-RTX-3"]  # no run delays (attach mode, pcaps)
    assert _rtx3(s, 0) == ["MCP-RTX-3"]  # known, and the node was not kept waiting
    assert _rtx3(s, 70 * MS) == []  # kept off the CPU 70 ms: 280 - 70 is on time
    assert _rtx3(s, 70 * MS, late_copy=2) == ["MCP-RTX-3"]  # starved over another gap


def test_the_monitor_still_fails_a_badly_spaced_sender():
    s = _script([0.2, 0.2, 0.5, 0.2])
    assert _rtx3(s, 0) == ["MCP-RTX-3"]
    assert _rtx3(s, 70 * MS) == ["MCP-RTX-3"]  # 70 ms of load does not make 500 ms even


# ---------------------------------------------------------------- the runner's case
def _ctx() -> DatagramCaseBase:
    return DatagramCaseBase(None, "RTX/x", ("MCP-RTX-3",))


def test_the_case_excuses_the_same_gaps_and_says_so():
    gaps = [0.3, 0.3, 0.385, 0.3]
    with pytest.raises(CaseFailure, match="385.0 ms"):
        _ctx().expect_even_spacing(gaps)
    with pytest.raises(CaseFailure, match="385.0 ms"):
        _ctx().expect_even_spacing(gaps, run_delays=[None] * 5)
    ctx = _ctx()
    ctx.expect_even_spacing(gaps, run_delays=[0, 0, 0, 90 * MS, 90 * MS])
    assert any("1 gap(s) excused" in n and "90.0 ms" in n for n in ctx.notes), ctx.notes
    with pytest.raises(CaseFailure, match="none under"):
        _ctx().expect_even_spacing([0.06, 0.04, 0.06], run_delays=[0, 10**9, 2 * 10**9, 3 * 10**9])

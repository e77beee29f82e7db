"""The veto's lag is the failure's own (``judge/veto.py`` ``_window_lag``, D-7): the run delay
a sender accrued between its datagrams that bracket the failure's evidence, not the largest
stall anywhere in its trace. A long CPU stall late in a loaded run excuses no early, real
MCP-RTX-2 fault; a stall inside the failure's window still explains a correct sender.

The conversation: the runner plays drones 1 and 2 (``mcp-conform --role manager``); the
manager's Start_Mission to drone 1 goes out twice unACKed, drone 1's wrong-seq ACK
comes, no copy follows, and the right ACK comes 2 s later; then the manager goes on to the
mission's end. Its datagrams carry its run delay (``harness.run_delay``; an ACK none)."""

from __future__ import annotations

from collections.abc import Callable

from mcp_conform.judge.monitor import TESTER, Monitor
from mcp_conform.spec.codec import Action, peek_header
from tests.judge.monitor_scripts import T0_NS, Script

NS = 1_000_000_000
MANAGER = 0
#: the right ACK's delay after the wrong one (s): past any un-stalled retransmission time
RIGHT_ACK_AFTER = 2.0
#: a stall (s) longer than RIGHT_ACK_AFTER, so it would excuse the stop if it counted
STALL = 5.0


def _taken_wrong_ack(stall_at: str) -> tuple[Script, Callable[[int], int]]:
    """The conversation, and the manager's run delay (ns) at each time: ``stall_at`` is
    ``"late"`` (a STALL between two of its datagrams near the mission's end, long after the
    fault) or ``"window"`` (off the CPU from the wrong ACK until the right one came: a
    shorter stall, between the last copy and its next datagram)."""
    s = Script((1, 2), vehicle=False)
    for d in s.drones:
        s.exchange(d, 0, Action.MISSION_READY, origin=TESTER)
        s.tick(0.02)
    kw = {"acker_origin": TESTER}
    seq, data = s.send(0, 1, Action.START_MISSION)
    for _ in range(1):  # two copies: after min_copies a retry limit would explain the stop too
        s.tick(s.rto)
        s.raw(0, data, to=1)
    s.tick(0.01)
    s.ack(1, 0, (seq + 0x8000) & 0xFFFF, origin=TESTER)  # the wrong seq from drone 1
    t_wrong = s.t
    s.tick(RIGHT_ACK_AFTER)
    s.ack(1, 0, seq, origin=TESTER)  # the right ACK: no copy since the wrong one
    s.tick(0.05)
    s.exchange(0, 2, Action.START_MISSION, **kw)
    s.tick(0.01)
    for d in s.drones:
        s.exchange(0, d, Action.WP_LIST, tuple(s.items), **kw)
        s.tick(0.01)
    t_late = s.t
    s.tick(STALL + 0.1)  # the manager off the CPU (late case) or just idle (window case)
    for d in s.drones:
        s.exchange(0, d, Action.END_MISSION, **kw)
    late = stall_at == "late"
    stall_from = T0_NS + int((t_late if late else t_wrong) * NS)
    stall_ns = int((STALL if late else RIGHT_ACK_AFTER) * NS)
    return s, lambda t: stall_ns if t >= stall_from + stall_ns else 0


def _judged(stall_at: str) -> Monitor:
    """The conversation judged by the monitor, the manager's datagrams with their run delay."""
    s, rd = _taken_wrong_ack(stall_at)
    mon = s.monitor(complete=True)
    for r in sorted(s.records, key=lambda r: r.t_ns):
        head = peek_header(r.data, require_preamble=False)
        carries = r.origin is None and head is not None and head[1] == MANAGER and head[3] != Action.ACK
        mon.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data, r.origin,
                     run_delay=rd(r.t_ns) if carries else None)
    mon.finish(s.end_ns())
    return mon


def test_a_stall_long_after_the_fault_does_not_excuse_it() -> None:
    """The stall is late in the run, after the mission's commands; the stop after the wrong
    ACK stands as MCP-RTX-2 (before: the whole trace's largest stall, 5 s, bounded how late
    the manager may have read the right ACK, so the ACK 2 s later 'may have ended it')."""
    mon = _judged("late")
    assert mon.verdicts()[MANAGER]["MCP-RTX-2"] == "failed"
    assert not [x for x in mon.vetoed if x.violation.rule == "MCP-RTX-2"]


def test_a_stall_inside_the_failures_window_still_excuses_it() -> None:
    """A stall between the wrong ACK and the manager's next datagram (2 s, less than the late
    one): a correct manager off the CPU when its copy fell due, which then read the right ACK
    -- vetoed, the ACK named."""
    mon = _judged("window")
    assert mon.verdicts()[MANAGER]["MCP-RTX-2"] == "passed"
    (x,) = [x for x in mon.vetoed if x.violation.rule == "MCP-RTX-2"]
    assert x.sender == MANAGER and "may have ended it" in x.explanation


def test_the_window_is_bracketed_by_the_datagrams_around_the_evidence() -> None:
    """``_window_lag``: from the last datagram at or before the first evidence to the first
    after the last; the whole growth there; the tail only when none came after."""
    from mcp_conform.judge.veto import _window_lag

    s = NS
    known = [(1 * s, 0), (2 * s, s // 10), (3 * s, s // 10), (9 * s, 4 * s)]
    assert _window_lag(known, 2 * s, 2 * s, None) == 0.0  # 2 s .. 3 s: no growth
    assert _window_lag(known, 1 * s, 2 * s, None) == 0.1  # 1 s .. 3 s
    assert _window_lag(known, 3 * s, 3 * s, None) == 3.9  # 3 s .. 9 s: the stall
    assert _window_lag(known, 1 * s, 9 * s, (9 * s, 1.0)) == 5.0  # all, and the tail after
    assert _window_lag(known, 1 * s, 8 * s, (9 * s, 1.0)) == 4.0  # a datagram after: no tail
    assert _window_lag(known[:2], 2 * s, 2 * s, (3 * s, 1.0)) == 0.0  # sent after (an ACK): no tail
    assert _window_lag([], 0, s, (0, 1.0)) == 0.0

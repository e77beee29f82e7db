"""A silence, or a late copy, is excused by exactly the run delay (D-7) the sender's readings
show over it -- the growth between the readings that bracket it, never more (issue 38; the
sweep's seeds ``explain-rtx1-drone-short-stalls``, ``monitor-rtx1-drone-stalled-long``,
``monitor-rtx1-manager-stalled-single-copy``, ``monitor-rtx1-ack-read-at-a-stalls-end``):

- ``judge.explain`` judges the silence after a message's last copy in the time its sender could
  run (:attr:`Trace.run_delay`, :func:`run_delay_over`), not with one bound for the whole trace
  (the simulator's largest stall was 0.226 s where two overlapping ones held the drone 0.330 s);
- the veto (``judge/veto.py``) weighs the violation's own message, and each gap -- between copies,
  from the last copy to the ACK -- in the sender's running time: a late copy carrying the run
  delay, then the ACK, excuses a failure; the same timings without the run delay, or with it
  accrued over another gap, do not (a sender that paused 24 s between copies, unstalled, stopped
  retransmitting for that long).
"""

from __future__ import annotations

from collections.abc import Callable

from mcp_conform.judge.explain import PROVEN, UNOBSERVABLE, Bounds, Copy, Trace, decide_sender
from mcp_conform.judge.explain_model import run_delay_over
from mcp_conform.spec.codec import Action
from tests.judge.monitor_faults import _started
from tests.judge.monitor_scripts import MANAGER_ADDR, T0_NS, Script

NS = 10**9


# ------------------------------------------------------------------ the readings


def test_run_delay_over_is_the_growth_between_the_readings_that_bracket_the_span() -> None:
    rd = [(0.0, 0.0), (1.0, 0.0), (3.0, 1.5), (4.0, 1.5)]
    assert run_delay_over(rd, 1.0, 3.0) == 1.5  # readings at both ends
    assert run_delay_over(rd, 2.0, 2.5) == 1.5  # somewhere between 1.0 and 3.0: maybe here
    assert run_delay_over(rd, 0.0, 1.0) == 0.0  # accrued after the span
    assert run_delay_over(rd, 3.0, 4.0) == 0.0  # accrued before it
    assert run_delay_over(rd, 3.5, 9.0) == 0.0  # nothing read after: nothing assumed
    assert run_delay_over([], 0.0, 9.0) == 0


# ------------------------------------------------------------------ judge.explain


def _two_copies(readings: tuple[tuple[float, float], ...]) -> str:
    """The explain seed's shape: two copies 0.3 s apart (--rto 0.3), no ACK, the trace's end
    0.630 s after the last; MCP-RTX-1's status with the sender's ``readings``."""
    trace = Trace([Copy(7, 0, 0.0), Copy(7, 0, 0.3)], [], 0.93, run_delay=readings)
    return decide_sender(trace, Bounds(rto=0.3, ack_window=0.6))["MCP-RTX-1"].status


def test_explain_weighs_the_run_delay_read_over_the_silence() -> None:
    # 0.330 s of it off the CPU (read as its view ends): it could run 0.300 s, its next copy
    # was not yet overdue (0.375 s)
    assert _two_copies(((0.0, 0.0), (0.3, 0.0), (0.93, 0.33))) == UNOBSERVABLE
    # no reading over the silence: 0.630 s, past the timeout -- it stopped after 2 copies
    assert _two_copies(((0.0, 0.0), (0.3, 0.0))) == PROVEN
    assert _two_copies(()) == PROVEN
    # the same run delay accrued before the last copy (another gap) excuses nothing here
    assert _two_copies(((0.0, 0.0), (0.3, 0.33), (0.93, 0.33))) == PROVEN


# ------------------------------------------------------------------ the veto


def _judge(s: Script, rd: Callable[[float], int] | None, end: float,
           sample: tuple[float, float] | None = None) -> tuple[str, list[str]]:
    """The manager's MCP-RTX-1 verdict and the veto's notes; its run delay ``rd(t)`` (ns, t in
    s of the script) on each datagram it sends (None: unknown), ``sample``: (t, s) read at
    its view's end (``Monitor.run_delay``)."""
    m = s.monitor()
    for r in sorted(s.datagrams(), key=lambda r: r.t_ns):
        d = rd((r.t_ns - T0_NS) / NS) if rd is not None and r.src_addr == MANAGER_ADDR else None
        m.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data, r.origin, run_delay=d)
    if sample is not None:
        m.run_delay(T0_NS + int(sample[0] * NS), 0, int(sample[1] * NS))
    m.finish(T0_NS + int(end * NS))
    return m.verdicts()[0]["MCP-RTX-1"], [x.note() for x in m.vetoed]


def _stalled_at(at: float, s_off: float, before: float = 0.0) -> Callable[[float], int]:
    """``before`` s of run delay from the start, ``s_off`` more from just before ``at``."""
    return lambda t: int((before + (s_off if t >= at - 1e-6 else 0.0)) * NS)


LATE = 9.0  # s from the first copy to the second: past the one-copy deadline (1.5 x 5 s + 0.25 s)


def _late_copy_then_ack() -> tuple[Script, float]:
    """The drone seed's shape, its roles played by the manager: one copy of WP_Off to drone 1,
    the next one LATE s later, drone 1's ACK right after it, then 2 s of nothing to the end
    (the manager ACKs nothing more and sends no new message)."""
    s = _started()
    seq, data = s.send(0, 1, Action.WP_OFF)
    s.tick(LATE)
    s.raw(0, data, to=1)
    t_late = s.t
    s.tick(0.004)
    s.ack(1, 0, seq)
    return s, t_late


def test_a_late_copy_carrying_its_run_delay_then_the_ack_is_no_give_up() -> None:
    s, t_late = _late_copy_then_ack()
    verdict, notes = _judge(s, _stalled_at(t_late, LATE - 0.2), end=s.t + 2.0)
    assert verdict == "passed"
    (note,) = notes
    assert "WP_Off" in note and "8.800 s of run delay" in note and "may have ended it" in note


def test_a_late_copy_is_excused_by_no_run_delay_but_its_own() -> None:
    s, t_late = _late_copy_then_ack()
    assert _judge(s, None, end=s.t + 2.0)[0] == "failed"  # unknown
    assert _judge(s, lambda t: 0, end=s.t + 2.0)[0] == "failed"  # never kept waiting
    # accrued before the first copy (a stall elsewhere in the run): the gap stands
    assert _judge(s, _stalled_at(0.0, LATE - 0.2), end=s.t + 2.0)[0] == "failed"
    # 1 s of the 9: it could run 8 s of the gap, past a lone copy's deadline (1.5 x the
    # description's 5 s + the 0.25-s ACK window)
    assert _judge(s, _stalled_at(t_late, 1.0), end=s.t + 2.0)[0] == "failed"


def _single_copy_then_another_message(rd_late: float) -> Script:
    """The manager seed's shape: one copy of WP_Off to drone 1, an ACK of the manager's to
    drone 2 4.5 s later (its run delay still 0), the second copy 24 s after the first, drone
    1's ACK, then WP_Off to drone 2, twice, and a silence the view's end reads a stall over."""
    s = _started()
    seq, data = s.send(0, 1, Action.WP_OFF)
    s.tick(4.5)
    s.ack(0, 2, 7)
    s.tick(24.0 - 4.5)
    s.raw(0, data, to=1)
    s.tick(0.004)
    s.ack(1, 0, seq)
    s.tick(0.004)
    _seq2, data2 = s.send(0, 2, Action.WP_OFF)
    s.tick(0.2)
    s.raw(0, data2, to=2)
    return s


def test_the_violations_own_message_is_weighed_in_its_senders_running_time() -> None:
    s = _single_copy_then_another_message(19.0)
    t1 = s.records[-1].t_ns / NS - T0_NS / NS  # the last copy to drone 2
    t_copy2 = t1 - 0.208
    rd = _stalled_at(t_copy2, 19.0)
    # the silence after WP_Off to drone 2: 10 s to the end, 9.9 s of it off the CPU (read
    # at the end): no give-up either
    verdict, notes = _judge(s, rd, end=t1 + 10.0, sample=(t1 + 10.0, 19.0 + 9.9))
    assert verdict == "passed" and len(notes) == 2
    assert any("to ID 1" in n and "19.000 s of run delay" in n for n in notes)


def test_a_sender_that_paused_between_copies_unstalled_stopped_retransmitting() -> None:
    """The same conversation with no run delay at all: 24 s between two copies at --rto 0.2
    is a sender that stopped retransmitting for that long, though the ACK came after its
    second copy (the veto excused it before: the ACK came soon after the last copy)."""
    s = _single_copy_then_another_message(0.0)
    t1 = s.records[-1].t_ns / NS - T0_NS / NS
    verdict, notes = _judge(s, lambda t: 0, end=t1 + 0.3)
    assert verdict == "failed"
    assert not [n for n in notes if "to ID 1" in n]


def test_an_ack_read_at_a_stalls_end_is_excused_by_the_next_reading() -> None:
    """The seed ``monitor-rtx1-ack-read-at-a-stalls-end``'s shape: one copy, then the sender
    off the CPU while its next one fell due; it read the ACK as it ran again and sent nothing
    until 13.8 s later, that datagram carrying the stall. Where between the two readings it
    waited is not known: an explanation that puts the wait inside the silence keeps the rule.
    The same trace with the growth read before the copy does not."""
    s = _started()
    seq, data = s.send(0, 1, Action.WP_OFF)
    t_copy = s.t
    s.tick(19.48)
    s.ack(1, 0, seq)
    s.tick(13.77)
    s.exchange(0, 2, Action.WP_OFF)
    end = s.t + 0.5
    verdict, notes = _judge(s, _stalled_at(t_copy + 1.0, 15.28), end=end)
    assert verdict == "passed" and len(notes) == 1 and "15.280 s of run delay" in notes[0]
    assert _judge(s, _stalled_at(0.0, 15.28), end=end)[0] == "failed"

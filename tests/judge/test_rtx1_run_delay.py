"""MCP-RTX-1 under host load (D-7, ``judge/veto.py``'s ``_starved_in_time``): a copy that fell
due while its sender was off the CPU goes out late, its run delay carrying the lateness; the
monitor's deadline counts wall time and fails it as the copy is read, and judge.explain's veto
drops the failure when, in the time the sender could run, every copy came within the deadline
(the simulator's seed ``monitor-rtx1-late-copy-carries-its-run-delay``). The excuse needs the
run delay: none where it is unknown, too small, accrued over another gap, or not known up to
the end of the silence."""

from __future__ import annotations

from collections.abc import Callable

from mcp_conform.spec.codec import Action, peek_header
from tests.judge.monitor_faults import _started
from tests.judge.monitor_scripts import MANAGER_ADDR, T0_NS, Script

NS = 10**9
LATE = 2.0  # s: the second gap, the stall (--rto 0.2, ACK window 0.25: due within 0.55 s)


def _late_copy() -> tuple[Script, float]:
    """The manager's WP_Off to drone 1, never ACKed (its ACKs lost, as in the seed): five
    copies, the third 2 s after the second; returns the script and when the late copy went (s)."""
    s = _started()
    _seq, data = s.send(0, 1, Action.WP_OFF)
    for gap in (0.2, LATE, 0.2, 0.2):
        s.tick(gap)
        s.raw(0, data, to=1)
        if gap == LATE:
            t_late = s.t
    s.tick(0.2)
    return s, t_late


def _judge(s: Script, rd: Callable[[float], int] | None, tail: float = 10.0) -> tuple[dict[str, str], list[str]]:
    """The manager's verdicts and the notes of what the veto dropped, its run delay ``rd(t)``
    (ns, at each of its datagrams; None: unknown, attach mode)."""
    m = s.monitor()
    for r in sorted(s.datagrams(), key=lambda r: r.t_ns):
        d = rd((r.t_ns - T0_NS) / NS) if rd is not None and r.src_addr == MANAGER_ADDR else None
        m.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data, r.origin, run_delay=d)
    m.finish(s.end_ns(tail))
    return m.verdicts()[0], [x.note() for x in m.vetoed]


def _starved(at: float, ns: float) -> Callable[[float], int]:
    """A run delay of ``ns`` s accrued just before ``at`` (s)."""
    return lambda t: 1_000_000 + (int(ns * NS) if t >= at - 1e-6 else 0)


def test_a_copy_its_run_delay_made_late_is_not_a_give_up():
    s, t_late = _late_copy()
    verdicts, notes = _judge(s, _starved(t_late, 1.9))
    assert verdicts["MCP-RTX-1"] == "passed"
    (note,) = notes
    assert "MCP-RTX-1" in note and "1.900 s of run delay" in note and "D-7" in note


def test_the_excuse_needs_the_run_delay():
    s, t_late = _late_copy()
    assert _judge(s, None)[0]["MCP-RTX-1"] == "failed"  # unknown (attach mode, pcaps)
    assert _judge(s, lambda t: 0)[0]["MCP-RTX-1"] == "failed"  # known: never kept waiting
    # 1 s of 2: the copy still came 1 s after the last in the time it could run (> 0.55 s)
    assert _judge(s, _starved(t_late, 1.0))[0]["MCP-RTX-1"] == "failed"
    # accrued over the gap before (by the second copy): it does not excuse this one
    assert _judge(s, _starved(t_late - LATE, 1.9))[0]["MCP-RTX-1"] == "failed"


def _two_copies_then(after: Callable[[Script], None]) -> tuple[Script, float]:
    """The manager's WP_Off to drone 1: two copies 0.2 s apart, then ``after`` 2 s later."""
    s = _started()
    seq, data = s.send(0, 1, Action.WP_OFF)
    s.tick(0.2)
    s.raw(0, data, to=1)
    s.tick(LATE)
    t = s.t
    after(s)
    return s, t


def test_a_silence_its_run_delay_covers_only_in_part_is_a_give_up():
    # its stall ends with another datagram (an ACK to drone 2) carrying the run delay, then
    # no copy of WP_Off for the 10 s the trace goes on: it gave up
    s, t = _two_copies_then(lambda s: s.ack(0, 2, 7))
    assert _judge(s, _starved(t, 1.9))[0]["MCP-RTX-1"] == "failed"


def test_an_ack_read_at_the_stalls_end_needs_a_later_datagram_of_the_sender():
    def acked(s: Script) -> None:
        s.ack(1, 0, peek_header(s.records[-1].data)[2])  # the ACK came during the stall

    s, t = _two_copies_then(acked)
    # the manager read it at the stall's end and sent nothing more: no run delay of the stall known
    assert _judge(s, _starved(t, 1.9))[0]["MCP-RTX-1"] == "failed"
    s.tick(0.01)
    s.exchange(0, 2, Action.WP_OFF)  # its next message carries the stall's run delay
    verdicts, notes = _judge(s, _starved(t, 1.9))
    assert verdicts["MCP-RTX-1"] == "passed" and len(notes) == 1
    assert _judge(s, None)[0]["MCP-RTX-1"] == "failed"


def test_a_trace_cut_after_the_late_copy_is_judged_to_its_end():
    s = _started()
    _seq, data = s.send(0, 1, Action.WP_OFF)
    s.tick(LATE)
    s.raw(0, data, to=1)
    t_late = s.t
    # two copies (MCP-RTX-1 asks for 3), the trace ends 0.1 s after the late one: its next copy
    # was not due yet
    assert _judge(s, _starved(t_late, 1.9), tail=0.1)[0]["MCP-RTX-1"] != "failed"
    # ... and 10 s after it, with no copy and no run delay known after it: a give-up (past even
    # the description's 5 s timeout's deadline, no gap being known to pace it)
    assert _judge(s, _starved(t_late, 1.9), tail=10.0)[0]["MCP-RTX-1"] == "failed"


def _silence_to_the_end(sample: tuple[float, float] | None, tail: float = 10.0) -> tuple[dict[str, str], list[str]]:
    """The manager's WP_Off to drone 1, two copies 0.2 s apart, then nothing for ``tail`` s to
    the trace's end; ``sample``: a run delay read without a datagram, (when, s after the last
    copy; how much, s), as a view's end or the node's stop reads it (``Monitor.run_delay``)."""
    s = _started()
    _seq, data = s.send(0, 1, Action.WP_OFF)
    s.tick(0.2)
    s.raw(0, data, to=1)
    t_last = s.t
    m = s.monitor()
    for r in sorted(s.datagrams(), key=lambda r: r.t_ns):
        m.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data, r.origin,
                   run_delay=1_000_000 if r.src_addr == MANAGER_ADDR else None)
    if sample is not None:
        at, rd = sample
        m.run_delay(T0_NS + int((t_last + at) * NS), 0, 1_000_000 + int(rd * NS))
    m.finish(s.end_ns(tail))
    return m.verdicts()[0], [x.note() for x in m.vetoed]


def test_a_silence_to_the_end_that_a_reading_shows_starved_is_no_give_up():
    """A stalled manager (a view's end or its stop reads 9.9 s of run delay after its last
    copy, D-7) could run 0.1 s of the 10 s silence: less than its deadline (0.55 s). The
    sweep's false MCP-RTX-1 on a correct drone stalled to its view's end (judge.explain: the
    trace ends before the retransmission could be seen, UNOBSERVABLE)."""
    verdicts, notes = _silence_to_the_end((9.95, 9.9))
    assert verdicts["MCP-RTX-1"] == "passed" and len(notes) == 1 and "9.900 s of run delay" in notes[0]


def test_a_silence_to_the_end_is_a_give_up_unless_a_reading_before_the_end_covers_it():
    assert _silence_to_the_end(None)[0]["MCP-RTX-1"] == "failed"  # nothing read: it gave up
    assert _silence_to_the_end((9.95, 5.0))[0]["MCP-RTX-1"] == "failed"  # ran 5 s of it
    assert _silence_to_the_end((10.5, 9.9))[0]["MCP-RTX-1"] == "failed"  # read after the end

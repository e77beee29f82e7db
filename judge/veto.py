"""The explanation judge's veto over the trace monitor's MCP-RTX-1/2 failures (issue 38,
item 1): a failure stands only where :mod:`judge.explain` cannot explain the trace without it.

The monitor (:mod:`judge.monitor`) judges incrementally, by special cases; some of them blamed
correct nodes -- a node stalled past its retransmission time (its run delay not weighed), a
manager that read another drone's ACK, or an ACK sent before its message, naming its number
(the regression seeds ``tests/sim/seeds/monitor-rtx1-starved-*``,
``monitor-rtx2-{stale,wrong-source}-ack``). Jepsen's checkers report an anomaly only when no
valid explanation of the history exists; so does this, in one place, which every consumer
gets: the monitor's ``finish`` calls :func:`veto`, so the runner's live monitor
(``judge.run_monitor``), ``mcp-capture check`` (``judge.judging``), the fuzzer and the
simulator judge alike.

How: the datagrams the monitor was fed (:class:`Recorder`) are made into
:mod:`judge.explain`'s traces (:func:`judge.explain_records.traces_from_datagrams`), one per
direction, with each sender's run delay readings (D-7); a violation of MCP-RTX-1 or MCP-RTX-2
by node ``S`` is about the message its first evidence datagram is a copy of, sent to ``R``,
and :func:`judge.explain.decide_message` decides that message -- not the direction's worst
(another message's proof does not make this failure right) -- with the bounds the monitor knows
(:func:`sender_bounds`: ``--rto``, the ACK window). The violation is dropped when the rule is
``consistent`` or ``unobservable`` there and no disjunction naming it (``MCP-RTX-1 or
MCP-RTX-2``) is proven, and the monitor's stop is explained: by a right ACK it did not credit
(:func:`_answered_in_time`) or, for MCP-RTX-1's "none for N s", by the run delay over the
silence (:func:`_starved_in_time`: a copy sent late because its sender was off the CPU, D-7, as
MCP-RTX-3 excuses it; the seed ``monitor-rtx1-late-copy-carries-its-run-delay``), or, for
MCP-RTX-2's silence after ``min_copies`` copies, by a retry limit (:func:`_limit_reached`). So the veto
never adds a violation and never drops one explain proves. A dropped violation is kept with
the explanation that keeps the rule (:class:`Vetoed`), for the report.

Run delay. ``S``'s run delay (cumulative, ns: ``harness.run_delay`` on a real host, the
simulator's stalls) grows by the time ``S`` was runnable but off the CPU; it is read off each
datagram ``S`` sent that carries it, and without a datagram (:meth:`Recorder.sample`,
``Monitor.run_delay``: at the end of its view, or as the runner stopped it -- a stall after
its last datagram, the seed ``monitor-rtx1-starved-then-closed``). A silence -- between two
copies, from the last copy to the ACK, or to the trace's end -- is judged in the time ``S``
could run (:func:`_ran`): its span less the growth between the readings that bracket that
span (``judge.explain_model.run_delay_over``: where between them ``S`` waited is not known, and
an explanation that puts it inside the silence is consistent with the trace), so a stall
outside them excuses nothing (a long one late in a loaded run does not explain an early stop
after a wrong ACK, nor does one before a message's first copy a 24-s pause between its copies)
and a silence no reading covers is judged as it was seen.
``judge.explain`` judges the silence after each message's last copy the same way
(:attr:`judge.explain.Trace.run_delay`). How late ``S`` may have read an ACK (``ack_early``) is
the growth over the failure's window (:func:`_window_lag`, :func:`_tail_lags`). Where no run
delay is known the bounds are spec/mcp.yaml's with a perfect observer. The link is not known
to the monitor: one copy draws one ACK (a link that duplicates ACKs may leave a false failure
standing, never hide a true one).

Cost: one record per datagram fed, up to :data:`RECORD_CAP`; past it the veto is off for the
trace (its failures stand, and :attr:`Recorder.note` says why). Explain runs only at
``finish`` and only for the directions of the violations it may veto.
"""

from __future__ import annotations

from bisect import bisect_right
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

from mcp_conform.judge._monitor_base import JITTER_NS, MIN_COPIES, median
from mcp_conform.judge._monitor_rtx import DESCRIPTION_TIMEOUT_NS
from mcp_conform.judge.explain import (
    CONSISTENT,
    EITHER_RTX,
    PROVEN,
    UNOBSERVABLE,
    Bounds,
    Trace,
    decide_message,
)
from mcp_conform.judge.explain_model import run_delay_over
from mcp_conform.judge.explain_records import traces_from_datagrams
from mcp_conform.spec.codec import HEADER_SIZE, Action, peek_header

__all__ = ["RECORD_CAP", "VETOED_RULES", "Record", "Recorder", "Vetoed", "sender_bounds", "veto"]

NS = 1_000_000_000
#: The rules a violation of which explain may veto, and the disjunction that keeps it standing.
VETOED_RULES: dict[str, str] = {"MCP-RTX-1": EITHER_RTX, "MCP-RTX-2": EITHER_RTX}
#: Each of them, and the other rule of the disjunction (``_reported_by_the_other``).
OTHER_RTX: dict[str, str] = {"MCP-RTX-1": "MCP-RTX-2", "MCP-RTX-2": "MCP-RTX-1"}
#: Datagrams recorded per trace at most (a long soak, a million-datagram capture: issue 17).
RECORD_CAP = 200_000


class Record(NamedTuple):
    """One datagram as the monitor was fed it (what ``traces_from_datagrams`` reads)."""

    t_ns: int
    data: bytes
    tester: bool
    run_delay: int | None


class Vetoed(NamedTuple):
    """A monitor violation dropped, and the explanation that keeps its rule."""

    violation: Any
    sender: int
    receiver: int
    explanation: str

    def note(self) -> str:
        v = self.violation
        return (f"{v.rule} not failed for node {v.node} ({v.actual}): judge.explain explains the "
                f"trace from ID {self.sender} to ID {self.receiver} without it: {self.explanation}")


@dataclass
class Recorder:
    """The datagrams a monitor was fed (:class:`Record`), up to :data:`RECORD_CAP`."""

    records: list[Record] = field(default_factory=list)
    note: str | None = None
    #: per node ID, run delays known without a datagram (``Monitor.run_delay``): ``(t_ns, ns)``
    samples: dict[int, list[tuple[int, int]]] = field(default_factory=dict)

    def sample(self, t_ns: int, node: int, run_delay: int) -> None:
        """Node ``node``'s run delay was ``run_delay`` ns at ``t_ns`` (its view's end: a stall
        after its last datagram, D-7); it ends the window of a failure whose evidence comes
        after the node's last datagram (:func:`_tail_lags`)."""
        self.samples.setdefault(node, []).append((t_ns, run_delay))

    def add(self, t_ns: int, data: bytes, tester: bool, run_delay: int | None) -> None:
        if self.note is not None:
            return
        if len(self.records) >= RECORD_CAP:
            self.note = (f"more than {RECORD_CAP} datagrams: MCP-RTX-1/2 failures are not checked "
                         "against judge.explain")
            self.records = []
            return
        self.records.append(Record(t_ns, bytes(data), tester, run_delay))

    def mark_tester(self, index: int) -> None:
        """Datagram ``index`` turned out to be the harness's (a wrong src, an ID outside the
        mission): input to the others, as the monitor takes it."""
        if self.note is None and index < len(self.records):
            self.records[index] = self.records[index]._replace(tester=True)


def _sent(records: list[Record]) -> dict[int, list[tuple[int, int]]]:
    """Per node, (t_ns, run delay) of each datagram it sent that carries its run delay."""
    seen: dict[int, list[tuple[int, int]]] = {}
    for r in records:
        if r.run_delay is None or r.tester:
            continue
        head = peek_header(r.data, require_preamble=False)
        if head is not None:
            seen.setdefault(head[1], []).append((r.t_ns, r.run_delay))
    return seen


def _window_lag(known: list[tuple[int, int]], t_first: int, t_last: int,
                tail: tuple[int, float] | None) -> float:
    """The run delay a node's datagrams ``known`` (:func:`_sent`: ``(t_ns, run delay)``, in
    order) show it accrued over one failure's window (s): from its last datagram at or before
    ``t_first`` (the failure's first evidence; its first datagram when none is) to its first
    after ``t_last`` (the last evidence), or, when none came after, to the run delay known
    after its last datagram (``tail``, :func:`_tail_lags`, when the failure's evidence ends at
    or after the node's last datagram of any kind). The whole growth, not its largest step:
    one stall or several inside the window, the time the node could not run there. A stall
    outside the window -- a long one late in a loaded run -- excuses nothing of the failure."""
    if not known:
        return 0.0
    times = [t for t, _ in known]
    start = max(bisect_right(times, t_first) - 1, 0)
    after = bisect_right(times, t_last)
    stop = min(after, len(known) - 1)
    growth = sum(max(b - a, 0) for (_, a), (_, b) in zip(known[start:stop], known[start + 1:stop + 1], strict=True))
    lag = growth / NS
    if after == len(known) and tail is not None and t_last >= tail[0]:
        lag += tail[1]  # none after the evidence: the growth read after the node's last datagram
    return lag


def _tail_lags(records: list[Record], samples: dict[int, list[tuple[int, int]]]) -> dict[int, tuple[int, float]]:
    """Per node, the time of its last datagram (of any kind: an ACK carries no run delay,
    ``harness.run_delay.delay_for``) and the growth of its run delay from the last datagram
    that carried one to a run delay known without a datagram after it (``samples``,
    :meth:`Recorder.sample`: read as its view ended or as the runner stopped it). It speaks of
    the time after the node's last datagram only, so it is weighed only for a failure whose
    copies are the last the node sent: a stall late in a run excuses nothing of a message sent
    long before it, however much the node only ACKed since."""
    last_any: dict[int, int] = {}
    for r in records:
        head = peek_header(r.data, require_preamble=False) if not r.tester else None
        if head is not None:
            last_any[head[1]] = max(last_any.get(head[1], r.t_ns), r.t_ns)
    out: dict[int, tuple[int, float]] = {}
    sent = _sent(records)
    for node, extra in samples.items():
        known = sent.get(node)
        if not known or node not in last_any:
            continue  # no run delay on any datagram: no growth to measure from
        t_last, rd_last = known[-1]
        growth = max((rd - rd_last for t, rd in extra if t >= t_last), default=0)
        if growth > 0:
            out[node] = (last_any[node], growth / NS)
    return out


def sender_bounds(rto: float, ack_window: float, lag: float) -> Bounds:
    """The bounds of a sender off the CPU for ``lag`` s in a failure's window: it may read an
    ACK that much late (``ack_early``). How late its copies went is not a bound: each silence
    is judged in the time it could run, by its readings (:attr:`Trace.run_delay`)."""
    return Bounds(ack_window=ack_window, rto=rto, ack_early=lag)


class _Readings(NamedTuple):
    """A node's run delay as read, ``(t_ns, ns)`` in time order, and their times."""

    at: list[tuple[int, int]]
    times: list[int]

    def over(self, t_a: int, t_b: int) -> int:
        """The run delay (ns) the readings bound from ``t_a`` to ``t_b`` (``run_delay_over``)."""
        return int(run_delay_over(self.at, t_a, t_b, self.times))


NO_READINGS = _Readings([], [])


def _readings(records: list[Record], samples: dict[int, list[tuple[int, int]]], end_ns: int
              ) -> dict[int, _Readings]:
    """Per node, its run delay as read up to the trace's end ``end_ns`` (a reading after it is
    not part of the trace): off each datagram it sent that carries one (:func:`_sent`), and
    without a datagram (:meth:`Recorder.sample`)."""
    out = {node: list(known) for node, known in _sent(records).items()}
    for node, extra in samples.items():
        out.setdefault(node, []).extend(extra)
    kept = {node: sorted(r for r in known if r[0] <= end_ns) for node, known in out.items()}
    return {node: _Readings(known, [t for t, _ in known]) for node, known in kept.items()}


def _ran(readings: _Readings, t_a: int, t_b: int) -> int:
    """The time (ns) the node could run from ``t_a`` to ``t_b`` in some explanation: the span
    less the run delay its readings that bracket it show (``judge.explain_model.run_delay_over``):
    what excuses a silence, never more than was measured around it."""
    return (t_b - t_a) - readings.over(t_a, t_b)


def _direction(v: Any, records: list[Record]) -> tuple[int, int] | None:
    """``(S, R)``: the violation's message, its first evidence datagram that ``S`` sent ``R``
    (not an ACK)."""
    for i, _t in v.evidence:
        if not 0 <= i < len(records):
            continue
        head = peek_header(records[i].data, require_preamble=False)
        if head is not None and head[1] == v.node and head[3] != Action.ACK:
            return v.node, head[0]
    return None


def _first_copy(v: Any, way: tuple[int, int], records: list[Record]) -> int | None:
    """The index of the violation's first evidence datagram that ``S`` sent ``R`` (not an
    ACK): a copy of the message the violation is about."""
    s, r = way
    for i, _t in v.evidence:
        h = peek_header(records[i].data, require_preamble=False) if 0 <= i < len(records) else None
        if h is not None and h[1] == s and h[0] == r and h[3] != Action.ACK:
            return i
    return None


def _answered_in_time(v: Any, way: tuple[int, int], records: list[Record], b: Bounds,
                      broadcast_id: int, readings: _Readings) -> str | None:
    """Whether an ACK from ``R`` naming the violation's message came before ``S``'s next
    copy was overdue (``Bounds.rto_max`` after its last, and each copy from the first evidence
    on within that of the one before, in the time ``S`` could run: :func:`_ran`, its
    ``readings``) and ``S`` moved on to another message only once it could have read it
    (``ack_early``: how late ``S`` may read one). Explain keeps
    MCP-RTX-2 by other stops too -- a give-up at a retry limit after a wrong ACK (a faulty
    sender that stops on any ACK; after ``min_copies`` copies: :func:`_limit_reached`), a stop that broke MCP-BLK-1 instead
    (``tests/judge/test_explain_beside_monitor.py``'s ``rtx2-stops-on-wrong-ack``,
    ``rtx2-manager-takes-a-stale-ack``): there the monitor's failure stands, a faulty
    sender's only one. The veto is for a right ACK the monitor did not credit: it is named
    (None: no such ACK)."""
    s, r = way
    first = _first_copy(v, way, records)
    if first is None:
        return None
    seq = peek_header(records[first].data, require_preamble=False)[2]  # type: ignore[index]
    named = seq.to_bytes(2, "big")
    last = records[first].t_ns
    t_ack = None
    most = int(b.rto_max * NS)
    for rec in records[first + 1:]:
        h = peek_header(rec.data, require_preamble=False)
        if h is None or rec.tester and h[1] == s:
            continue
        dst, src, n, action = h
        if action == Action.ACK:
            if t_ack is None and src == r and dst == s and len(rec.data) == HEADER_SIZE + 2 \
                    and rec.data[HEADER_SIZE:] == named:
                t_ack = rec.t_ns
        elif src == s and dst == r and n == seq:
            if t_ack is None and _ran(readings, last, rec.t_ns) > most:
                return None  # a copy overdue in the time S could run: it stopped a while
            last = rec.t_ns
        elif src == s and dst != broadcast_id:  # S moved on
            if t_ack is None or rec.t_ns < t_ack - b.ack_early * NS:
                return None
            break
    if t_ack is None or t_ack > last and _ran(readings, last, t_ack) > most:
        return None
    t0 = records[0].t_ns
    off = readings.over(records[first].t_ns, max(t_ack, last)) / NS
    ran = (f"; each copy within that of the one before, the ACK within it of the last, in the "
           f"time ID {s} could run ({off:.3f} s of run delay over them, D-7)") if off > 0 else ""
    return (f"the ACK of seq {seq} from ID {r} seen at {(t_ack - t0) / NS:.3f} s, "
            f"{(t_ack - last) / NS:.3f} s after its last copy (a retransmission may come "
            f"{b.rto_max:.3f} s after one: --rto, tolerance){ran}, may have ended it")


def _resumed_in_time(v: Any, way: tuple[int, int], records: list[Record], *, rto: float,
                     readings: _Readings) -> str | None:
    """MCP-RTX-2's silence after a wrong ACK (``_wrong_ack_deadline``: "not retransmitted for
    N s after a wrong ACK") judged in the sender's running time (D-7): the monitor's deadline
    (the wrong ACK + 1.5 gaps + 3 x the jitter) counts wall time, and a copy that fell due
    while ``S`` was off the CPU goes out when it runs again. The failure is explained (a text;
    None: it stands) when ``S``'s next datagram after the wrong ACK other than an ACK is a copy
    of the same message (the retransmission went on: the wrong ACK did not end it), sent
    within that deadline in the time ``S`` could run (:func:`_ran`: less the run delay its
    ``readings`` bracketing the silence show) -- and some run delay was needed for it. A
    sender that moved on first, or stayed silent past the deadline in its running time, is
    not explained (the seed monitor-rtx2-stalled-then-retransmitted: the ack-copies-wrong-seq
    drone's "seq + 1" ACK read just before the manager stalled)."""
    s, r = way
    span = _copy_then_wrong(v, way, records)
    if span is None:
        return None
    first, i_wrong = span
    h0 = peek_header(records[first].data, require_preamble=False)
    hw = peek_header(records[i_wrong].data, require_preamble=False)
    if h0 is None or hw is None or hw[3] != Action.ACK or hw[0] != s:
        return None
    seq = h0[2]
    copies = []
    for rec in records[:first + 1]:
        h = peek_header(rec.data, require_preamble=False)
        if h is not None and not rec.tester and h[:3] == (r, s, seq) and h[3] != Action.ACK:
            copies.append(rec.t_ns)
    g = [b - a for a, b in zip(copies, copies[1:], strict=False)]
    est = median(g) if g else int(rto * NS)
    due = 3 * est // 2 + 3 * JITTER_NS
    t_wrong = records[i_wrong].t_ns
    for rec in records[i_wrong + 1:]:
        h = peek_header(rec.data, require_preamble=False)
        if h is None or rec.tester or h[1] != s or h[3] == Action.ACK:
            continue
        if h[:3] != (r, s, seq) or rec.data != records[first].data:
            return None  # it moved on (or sent another message) first
        ran = _ran(readings, t_wrong, rec.t_ns)
        if ran > due or rec.t_ns - t_wrong <= due:
            return None  # overdue in the time it could run, or not late at all
        off = readings.over(t_wrong, rec.t_ns)
        return (f"seq {seq} from ID {s}: its next copy came {(rec.t_ns - t_wrong) / NS:.3f} s after "
                f"the wrong ACK, {ran / NS:.3f} s in the time ID {s} could run ({off / NS:.3f} s of "
                f"run delay over the silence, D-7): the retransmission went on")
    return None


def _copy_then_wrong(v: Any, way: tuple[int, int], records: list[Record]) -> tuple[int, int] | None:
    """An MCP-RTX-2 violation's (first copy, wrong ACK) record indexes, the copy before the ACK
    (its evidence: the copy, then the wrong ACK); None when the records do not show them so."""
    first = _first_copy(v, way, records)
    if first is None or len(v.evidence) < 2:
        return None
    i_wrong = v.evidence[1][0]
    return (first, i_wrong) if first < i_wrong < len(records) else None


def _limit_reached(v: Any, way: tuple[int, int], records: list[Record]) -> str | None:
    """MCP-RTX-2's silence after a wrong ACK (``_wrong_ack_deadline``) where ``S`` had sent
    ``MIN_COPIES`` copies or more of the message before it, and nothing but ACKs since up to the
    failure: a retry limit of ``MIN_COPIES - 1`` -- MCP-RTX-1's configurable limit, "no
    violation" (spec/mcp.yaml's ``min_copies``) -- ends its copies there as taking the wrong ACK
    does, and one trace cannot tell which (the C drone's ``--retries 2`` failed so). The runner's
    case tells them on a restarted node, the wrong ACKs after its second copy
    (``harness.drone_rtx2``): there, fewer copies than any such limit, the failure stands
    ("MCP-RTX-1 or MCP-RTX-2" proven). A sender that moved on at once after the wrong ACK is
    not explained (its give-up would come at its timer: ``_check_stop_and_wait``)."""
    s, r = way
    span = _copy_then_wrong(v, way, records)
    if span is None:
        return None
    first, i_wrong = span
    seq = peek_header(records[first].data, require_preamble=False)[2]  # type: ignore[index]
    n = 0
    for k, rec in enumerate(records):
        h = peek_header(rec.data, require_preamble=False)
        if h is None or rec.tester or h[1] != s or h[3] == Action.ACK:
            continue
        if k > i_wrong and rec.t_ns <= v.t_ns:
            return None  # a copy, or a move on, after the wrong ACK: not a silence
        n += k < i_wrong and h[:3] == (r, s, seq)
    if n < MIN_COPIES:
        return None
    return (f"seq {seq} from ID {s}: {n} copies before the wrong ACK, then none: a retry limit of {n - 1} "
            f"(MCP-RTX-1's configurable limit; at least min_copies - 1 = {MIN_COPIES - 1}) ends them there too")


def _starved_in_time(v: Any, way: tuple[int, int], records: list[Record], *, rto: float,
                     ack_window: float, end_ns: int, readings: _Readings) -> str | None:
    """MCP-RTX-1's silence judged in the sender's running time (D-7, as ``judge.spacing``
    judges MCP-RTX-3's gaps): the monitor's deadline (``_rtx_deadline``: the last copy + 1.5
    gaps + the ACK window) counts wall time; a copy that fell due while ``S`` was off the CPU
    goes out when it runs again, late by the run delay its own datagram carries. The failure
    is explained (a text; None: it stands) when, each span in the time ``S`` could run
    (:func:`_ran`: less the run delay its ``readings`` bracketing it show), every copy
    came within that deadline of the one before up to :data:`MIN_COPIES` of them, or up to a
    right ACK (from ``R``, naming the message) or the trace's end within it, and no datagram of
    ``S`` in between shows it past the deadline -- and some run delay was needed for it. Run
    delay counts only where a reading shows it: a datagram of ``S`` that carries it, or one read
    without a datagram (at its stop, at a view's end); a silence no reading covers excuses
    nothing (attach mode, pcaps: nothing at all). Only the deadline's form of the failure (its
    evidence all copies of the message), not a sender seen moving on (``_gave_up``)."""
    s, r = way
    ev = [i for i, _t in v.evidence if 0 <= i < len(records)]
    if not ev or len(ev) != len(v.evidence):
        return None
    first = records[ev[0]]
    h0 = peek_header(first.data, require_preamble=False)
    if h0 is None or h0[:2] != (r, s) or h0[3] == Action.ACK:
        return None
    seq = h0[2]
    if any(records[i].data != first.data for i in ev):
        return None
    named = seq.to_bytes(2, "big")
    window_ns = int(ack_window * NS)
    t_last = first.t_ns
    runs: list[int] = []  # each gap between copies, in the time S could run
    copies = 1
    how = ""

    def deadline() -> int:
        est = median(runs) if runs else max(int(rto * NS), DESCRIPTION_TIMEOUT_NS)
        return 3 * est // 2 + window_ns

    for rec in records[ev[0] + 1:]:
        h = peek_header(rec.data, require_preamble=False)
        if h is None:
            continue
        dst, src, n, action = h
        if src == r and dst == s and action == Action.ACK and rec.data[HEADER_SIZE:] == named:
            if _ran(readings, t_last, rec.t_ns) > deadline():
                return None  # the ACK came after a copy was overdue in the time S could run
            t_stop = rec.t_ns
            how = f", and the ACK from ID {r} seen at {(t_stop - records[0].t_ns) / NS:.3f} s may have ended it"
            break
        if src != s or rec.tester:
            continue
        if _ran(readings, t_last, rec.t_ns) > deadline():
            return None  # past the deadline in the time S could run, and no copy
        if dst == r and n == seq and action != Action.ACK and rec.data == first.data:
            runs.append(_ran(readings, t_last, rec.t_ns))
            copies += 1
            t_last = rec.t_ns
            if copies >= MIN_COPIES:
                t_stop = rec.t_ns
                break
    else:  # the trace's end, fewer copies: the silence since the last, less the run delay read
        # by then (a reading without a datagram: the stall a view's end or its stop found)
        t_stop = max(end_ns, records[-1].t_ns)
        if _ran(readings, t_last, t_stop) > deadline():
            return None
    starved = readings.over(first.t_ns, t_stop)
    if starved <= 0:
        return None
    return (f"seq {seq} from ID {s}: {copies} cop{'y' if copies == 1 else 'ies'}, each within its "
            f"deadline (the last + 1.5 gaps + the ACK window) in the time ID {s} could run: its "
            f"readings show {starved / NS:.3f} s of run delay over the gaps (D-7){how}")


def veto(violations: list[Any], recorder: Recorder, *, rto: float, ack_window: float,
         end_ns: int, broadcast_id: int, complete_for: Any) -> list[Vetoed]:
    """The violations of :data:`VETOED_RULES` that :mod:`judge.explain` explains away (see the
    module docstring). ``complete_for(S, R)``: the trace holds every datagram between them."""
    mine = [v for v in violations if v.rule in VETOED_RULES]
    records = recorder.records
    if not mine or recorder.note is not None or not records:
        return []
    traces = traces_from_datagrams(records, complete=True, broadcast_id=broadcast_id,
                                   tester=lambda r: r.tester, samples=recorder.samples)
    t0 = next((r.t_ns for r in records if peek_header(r.data, require_preamble=False)), 0)
    end = (end_ns - t0) / NS
    sent = _sent(records)
    readings = _readings(records, recorder.samples, max(end_ns, records[-1].t_ns))
    tails = _tail_lags(records, recorder.samples)
    out: list[Vetoed] = []
    #: MCP-RTX-1 failures that stand only on a proven disjunction ("MCP-RTX-1 or MCP-RTX-2") or
    #: on explain's MCP-RTX-2 of their message: (violation, its direction, its message's seq, why)
    paired: list[tuple[Any, tuple[int, int], int, str]] = []
    for v in mine:
        way = _direction(v, records)
        trace: Trace | None = traces.get(way) if way is not None else None
        if way is None or trace is None:
            continue
        seen = [records[i].t_ns for i, _t in v.evidence if 0 <= i < len(records)]
        lag = _window_lag(sent.get(way[0], []), min(seen), max(seen), tails.get(way[0])) if seen else 0.0
        b = sender_bounds(rto, ack_window, lag)
        t = replace(trace, end=max(trace.end, end), complete=bool(complete_for(*way)))
        # the violation's own message: another message's proof does not make this one right
        i0 = _first_copy(v, way, records)
        head = peek_header(records[i0].data, require_preamble=False) if i0 is not None else None
        found = decide_message(t, b, head[2], (records[i0].t_ns - t0) / NS) if head and i0 is not None else None
        if found is None:
            continue
        kept = found.get(v.rule)
        either = found.get(VETOED_RULES[v.rule])
        if kept is None or kept.status not in (CONSISTENT, UNOBSERVABLE):
            continue
        other = found.get(OTHER_RTX[v.rule])
        if head is not None and (either is not None and either.status == PROVEN
                                 or v.rule == "MCP-RTX-1" and other is not None and other.status == PROVEN):
            # the rule itself is not proven for the message (an explanation keeps it), only the
            # pair is (or MCP-RTX-2 alone): a standing failure of the other rule may report it
            # (``_reported_by_the_other``)
            how = other if other is not None and other.status == PROVEN else either
            assert how is not None
            paired.append((v, way, head[2], f"{how.rule} proven for the message, {v.rule} {kept.status}: "
                                            f"{how.evidence}"))
        if either is not None and either.status == PROVEN and not (
                v.rule == "MCP-RTX-1" and other is not None and other.status == PROVEN):
            continue  # the disjunction proven may rest on this rule; not where explain proves
            # MCP-RTX-2 itself for the message (the wrong-seq-ack manager that took a wrong ACK
            # as it woke from a stall: its lone copy's MCP-RTX-1 deadline fell in the stall)
        # explain finds no proof either way where the trace ends before a retransmission could
        # be seen (UNOBSERVABLE): only the sender's own measured starvation explains that one
        mine_rd = readings.get(way[0], NO_READINGS)
        answered = (_answered_in_time(v, way, records, b, broadcast_id, mine_rd)
                    if kept.status == CONSISTENT else None)
        if answered is None and v.rule == "MCP-RTX-1":
            answered = _starved_in_time(v, way, records, rto=rto, ack_window=ack_window, end_ns=end_ns,
                                        readings=mine_rd)
        if answered is None and v.rule == "MCP-RTX-2":
            answered = _resumed_in_time(v, way, records, rto=rto, readings=mine_rd)
        if answered is None and v.rule == "MCP-RTX-2" and kept.status == CONSISTENT:
            answered = _limit_reached(v, way, records)
        if answered is None:
            continue
        out.append(Vetoed(v, way[0], way[1], f"{answered}; {kept.evidence}"))
    return out + _reported_by_the_other(paired, mine, out, records)


def _reported_by_the_other(paired: list[tuple[Any, tuple[int, int], int, str]], mine: list[Any],
                           vetoed: list[Vetoed], records: list[Record]) -> list[Vetoed]:
    """The failures of ``paired`` -- a rule explain does not prove for its message, where it
    proves "MCP-RTX-1 or MCP-RTX-2" (or MCP-RTX-2 alone, for an MCP-RTX-1 failure) -- that a
    standing failure of the other rule reports. A rule fails only where every explanation
    breaks it: the stop is a wrong ACK taken or a give-up too early, one violation, not two.

    - An MCP-RTX-1 failure whose message has a standing MCP-RTX-2 failure too: the MCP-RTX-2
      one reports the stop (the wrong-seq-ack manager whose lone copy fell due in a stall, that
      took a wrong ACK as it woke and moved on at once: seeds
      monitor-rtx1-beside-rtx2-after-a-stall, monitor-rtx1-beside-either-rtx-after-a-stall).
    - Then an MCP-RTX-2 failure of a node with a standing MCP-RTX-1 failure (of any message): the
      node's MCP-RTX-1 verdict covers the pair (the give-up-after-two manager whose timer
      expired as it read a wrong ACK: seed monitor-rtx2-beside-a-give-up).

    Without such a failure the paired one stands: the disjunction may rest on it."""
    gone = {id(x.violation) for x in vetoed}

    def standing(rule: str) -> set[tuple[int, int, int]]:
        out: set[tuple[int, int, int]] = set()
        for v in mine:
            if v.rule != rule or id(v) in gone:
                continue
            way = _direction(v, records)
            i0 = _first_copy(v, way, records) if way is not None else None
            head = peek_header(records[i0].data, require_preamble=False) if i0 is not None else None
            if way is not None and head is not None:
                out.add((*way, head[2]))
        return out

    dropped: list[Vetoed] = []
    rtx2 = standing("MCP-RTX-2")
    for v, way, seq, why in paired:
        if v.rule == "MCP-RTX-1" and id(v) not in gone and (*way, seq) in rtx2:
            dropped.append(Vetoed(v, way[0], way[1], f"reported as MCP-RTX-2 of the same message: {why}"))
            gone.add(id(v))
    failing_rtx1 = {s for s, _r, _q in standing("MCP-RTX-1")}
    for v, way, _seq, why in paired:
        if v.rule == "MCP-RTX-2" and id(v) not in gone and way[0] in failing_rtx1:
            dropped.append(Vetoed(v, way[0], way[1], f"the node's MCP-RTX-1 failure reports it: {why}"))
            gone.add(id(v))
    return dropped

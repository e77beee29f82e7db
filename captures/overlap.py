"""Where a run's cases overlapped in time, and how ``mcp-capture diff`` reads their traffic there.

The runner marks each case's start and end in its capture (``/conformance/case``:
``traceio.records.CaseMark``). Most cases run alone, but the schedule's batch
(``conformance.schedule``, ``conformance._batch``) runs its cases side by side, each in a
thread of its own, all sending from the runner's one socket: where one case's datagram falls
among another's in the manager's stream, and which of two ACKs the node sends first, is the
threads' race and carries no meaning. Two whole-suite runs of the reference drone
(``mcp-conform --mavlink``) differed in 8 pairs of 8, by 19–37 divergences each: the four
MCP-ROB cases' malformed datagrams and liveness WP_Offs interleave differently in each run.

An *overlap span* (:func:`overlap_spans`) is a stretch of time covered by case intervals that
overlap one another, at least two cases: the batch. Inside one, each entry of a conversation
is read in its *lane* (:func:`lane`), what the capture tells of the case it belongs to:

- a runner's passthrough probe: the case its token names (``conformance.drone_case.Case.probe``:
  ``<case id tail>-<n>-<seq>``; the lane is ``<case id tail>``, so a case's probes #1 and #2
  keep their order);
- a malformed datagram: the rule it breaks (each MCP-ROB case sends its own kind of malformed
  input, ``spec.generators.malformed_corpus``), in its own order;
- an ACK: the lane of the message it acknowledges;
- any other message: its own content. Identical messages of several cases (the ROB cases'
  liveness WP_Offs, MCP-ROB-5) are one lane: which of them was whose cannot be told, nor does
  it matter, since they are the same message.

:func:`aligned_order` gives the order in which the diff aligns a sender's entries: outside
spans the time order; inside one, lane after lane (lanes in a fixed order), each lane in its
time order. So the interleaving of lanes in a span is not compared; the order within a lane
is, and so is everything outside spans; a datagram missing, added or changed in a span still
differs, and so does one that moved into or out of it. Entries keep their time order in the
conversation: reports and charts show the wire as it was.

What a span does not show: the order of one case's messages of two lanes (an MCP-ROB case's
malformed datagram before or after its own liveness WP_Off). The capture does not say which
case sent a datagram; were the runner to record the sending case with each datagram it
sends, lanes would be exactly cases. A capture without case marks (a pcap, a node's own
capture) has no spans and is compared in time order throughout.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any, NamedTuple

from mcp_conform.captures.conversation import Entry, ProbeKey

__all__ = ["BEGIN", "END", "SPAN_EDGES", "Span", "aligned_order", "lane", "overlap_spans", "spans_text"]

_OPEN = 2**63 - 1  # a case started and never ended (a capture cut short): open to the end
BEGIN, END = -1, -2  # a span's edges among positions (aligned_order)
#: what the diff aligns a span's edges by (an entry's key never starts with a str)
SPAN_EDGES = {BEGIN: ("overlap", "begin"), END: ("overlap", "end")}


class Span(NamedTuple):
    """A stretch of time in which cases ran side by side."""

    start_ns: int
    end_ns: int
    cases: tuple[str, ...]


def overlap_spans(marks: Iterable[Any]) -> list[Span]:
    """The overlap spans of a capture's case marks (``CaseMark``: ``t_ns``, ``case``,
    ``event`` "start" | "end", ``segment``), in time order: each case's interval from its
    start to its end, intervals that overlap merged, those of two cases or more kept."""
    opened: dict[tuple[Any, str], int] = {}
    intervals: list[tuple[int, int, str]] = []
    for m in marks:
        who = (m.segment, m.case)
        if m.event == "start":
            opened[who] = m.t_ns
        elif m.event == "end" and who in opened:
            intervals.append((opened.pop(who), m.t_ns, m.case))
    intervals.extend((t, _OPEN, case) for (_seg, case), t in opened.items())
    intervals.sort()
    merged: list[tuple[int, int, list[str]]] = []
    for start, end, case in intervals:
        if merged and start <= merged[-1][1]:
            s, e, cases = merged[-1]
            cases.append(case)
            merged[-1] = (s, max(e, end), cases)
        else:
            merged.append((start, end, [case]))
    return [Span(s, e, tuple(cases)) for s, e, cases in merged if len(cases) > 1]


def lane(key: tuple[Any, ...]) -> tuple[Any, ...]:
    """The lane of an entry by its key (module docstring)."""
    if key[2] is None:  # malformed: (src, dst, None, rule, bytes)
        return ("malformed", key[0], key[1], key[3])
    content = key[3]
    if isinstance(content, tuple) and len(content) == 2 and content[0] == "ack":
        return key if content[1] is None else lane(content[1])
    if isinstance(content, ProbeKey) and content.stem is not None:
        return ("probe", key[0], key[1], content.stem.rpartition("-")[0])
    return key


def aligned_order(entries: Sequence[Entry], positions: list[int], spans: Sequence[Span]) -> list[int]:
    """``positions`` (one sender's entries, in time order) as the diff aligns them: those
    inside a span lane by lane (module docstring) between the span's two edges (``BEGIN``,
    ``END``: every span has them, entries or not, so a message that moved into or out of a
    span is out of place), the rest as they are."""
    if not spans:
        return positions
    out: list[int] = []
    inside: list[int] = []
    k = 0
    for n in positions:
        t = entries[n].t_ns
        while k < len(spans) and t > spans[k].end_ns:  # span k is over
            out += [BEGIN, *_by_lane(entries, inside), END]
            inside = []
            k += 1
        (inside if k < len(spans) and t >= spans[k].start_ns else out).append(n)
    for _ in range(k, len(spans)):
        out += [BEGIN, *_by_lane(entries, inside), END]
        inside = []
    return out


def _by_lane(entries: Sequence[Entry], run: list[int]) -> list[int]:
    """Lanes in a fixed order (their text: the same in every run), each in its time order."""
    order = {n: repr(lane(entries[n].key)) for n in run}
    return sorted(run, key=order.__getitem__)  # stable: time order within a lane


def spans_text(spans: Sequence[Span]) -> str:
    """``1 span of cases run side by side (10 cases, 0.583 s): ...``, for the report."""
    def one(s: Span) -> str:
        length = "" if s.end_ns == _OPEN else f", {(s.end_ns - s.start_ns) / 1e9:.3f} s"
        return f"{len(s.cases)} cases{length}"
    parts = "; ".join(one(s) for s in spans)
    return (f"{len(spans)} span{'s' if len(spans) != 1 else ''} of cases run side by side "
            f"({parts}): the order across their cases not compared, each case's own is")

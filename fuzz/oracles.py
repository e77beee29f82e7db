"""Oracles: what the node did with the fuzzer's inputs, judged by the spec's rules.

Every judgement names the one rule the node broke, judged on what the node itself did (the
reply it sent, the frame it forwarded, its death), never on a consequence one step removed:

- replies (:func:`judge_replies`): an ACK names the sequence number of what it answers
  (MCP-ACK-2), so each ACK is attributed to the inputs it can answer. An ACK of a datagram the
  codec rejects breaks the rule the rejection cites — MCP-ROB-1 (short), ROB-2 (preamble),
  ROB-3 (action code), ROB-4 (payload, D-4; a Mav_Passthrough without one good MAVLink frame
  is such a payload, MCP-PAY-6); an ACK of a broadcast breaks MCP-ACK-4, of a message to
  another ID MCP-ACK-5, of an ACK MCP-ACK-6. A well-formed unicast to the node left without
  an ACK, while the probe behind it was ACKed, breaks MCP-ACK-1. An ACK explained by any
  input it may legitimately answer is no violation (no false alarms).
- liveness and the process (:func:`judge_liveness`): a node that dies or stops answering
  after an input breaks MCP-ROB-1 when the input was shorter than the header ("no crash"),
  MCP-ROB-6 when it was larger than one Ethernet frame can carry ("survives datagrams of any
  size"), MCP-ROB-5 otherwise ("stays live after any malformed or unexpected input").
- the vehicle (:class:`DeliveryLedger`): passthrough frames carry probe tokens; the spec's
  duplicate rules say how often each may reach the autopilot (MCP-DUP-1/2/3, MCP-SEQ-3,
  MCP-PAY-8, MCP-ACK-5, MCP-ROB-4; ``fuzz.delivery``).
- the trace monitor (:class:`MonitorOracle`, ``judge.monitor``): every datagram in and
  out, for the rules judged from traffic alone (HDR, ACK-2/3/7, SEQ, RTX, BLK, PAY ...). Only
  violations by the node under test count (the fuzzer's datagrams are fed as the tester's:
  they break rules on purpose), and the reply rules above stay judge_replies's.

Each judgement observes as its rule's text says, never on less (issue 36): a missing ACK is
MCP-ACK-1 only once the input was retransmitted every --rto up to the rule's 5 copies, none
answered ("the runner retransmitting it every --rto as a manager would, up to 5 copies (a
node may be deaf while busy, D-6)", ``fuzz.observation``); the liveness probe is awaited
across as many copies (MCP-ROB-5/6 depend on MCP-ACK-1); a delivery count is judged against
what the node was shown to have received (an ACK, or the frame's own delivery), since a
datagram the kernel dropped from a full receive buffer never reached it (MCP-DUP-1: "the
same (src, seq) as the one last delivered from that src").
"""

from __future__ import annotations

import struct
from collections.abc import Iterable, Sequence
from dataclasses import replace
from typing import Any

from mcp_conform.fuzz.delivery import DeliveryLedger
from mcp_conform.fuzz.flaws import Flaw, Input, rule_level
from mcp_conform.fuzz.observation import retransmit_unanswered
from mcp_conform.harness.driver import Datagram
from mcp_conform.harness.session_base import (
    MIN_COPIES,  # MCP-RTX-1: at least 3 copies while the ACK is withheld
)
from mcp_conform.judge import copies_by_number
from mcp_conform.spec.codec import HEADER_SIZE, Action

__all__ = [
    "OVERSIZE",
    "DeliveryLedger",
    "Flaw",
    "Input",
    "MonitorOracle",
    "judge_exchange",
    "judge_liveness",
    "judge_withheld",
    "judge_replies",
    "rule_level",
]

_ACK = int(Action.ACK)
_PASSTHROUGH = int(Action.MAV_PASSTHROUGH)
_U16 = struct.Struct("!H")
#: Larger than one Ethernet frame's UDP payload (1500 - 20 - 8): "oversized" for MCP-ROB-6.
OVERSIZE = 1472
#: Rules judge_replies decides, attributing each ACK within the batch that provoked it (the
#: fuzzer's mutations may reuse any sequence number, so an ACK matched across batches by the
#: monitor could be another input's): the monitor's verdicts on these are left to it.
REPLY_RULES = frozenset({"MCP-ACK-1", "MCP-ACK-2", "MCP-ACK-3", "MCP-ACK-4", "MCP-ACK-5", "MCP-ACK-6", "MCP-ROB-1",
                         "MCP-ROB-2", "MCP-ROB-3", "MCP-ROB-4"})
#: The rule a reply to a rejected datagram breaks, by the rule the codec's rejection cites.
_REJECTED_REPLY_RULE = {"MCP-PAY-6": "MCP-ROB-4"}


def expected_silent_rule(inp: Input, node_id: int, broadcast_id: int) -> str | None:
    """The rule an ACK of ``inp`` would break, or None when the node must (or may) ACK it."""
    if inp.msg is None:
        assert inp.error is not None
        return _REJECTED_REPLY_RULE.get(inp.error.rule, inp.error.rule)
    m = inp.msg
    if m.action == _ACK:
        return "MCP-ACK-6"
    if m.dst == broadcast_id:
        return "MCP-ACK-4"
    if m.dst != node_id:
        return "MCP-ACK-5"
    return None


def acked_seq(d: Datagram) -> int | None:
    """The seq an ACK from the node names (its first two payload bytes, big-endian)."""
    if d.header is None or d.header[3] != _ACK or len(d.data) < HEADER_SIZE + 2:
        return None
    return int(_U16.unpack_from(d.data, HEADER_SIZE)[0])


def judge_replies(inputs: Sequence[Input], replies: Iterable[Datagram], node_id: int,
                  broadcast_id: int, probe_acked: bool, ignore_seqs: Iterable[tuple[int, int]] = (),
                  probe_copies: int = 0) -> list[Flaw]:
    """ACKs sent for ``inputs`` (the node's datagrams in ``replies``), judged per input.

    What one copy shows, up to the probe's ACK (a node handles its datagrams in order):
    an ACK that should not be there (MCP-ACK-4/5/6, ROB-1..4: "discarded silently") or is
    misformed (MCP-ACK-2/3) stands as seen; one ACK answers one copy ("every copy,
    retransmissions included", MCP-ACK-1), and an input it marks ``received``. A missing
    ACK is only a candidate here: MCP-ACK-1 is "observed ... the runner retransmitting it
    every --rto as a manager would, up to 5 copies", which :func:`observe_missing_acks` does.

    ``ignore_seqs``: (dst, seq) pairs the fuzzer knows are answered legitimately (its probe);
    ``probe_copies``: how many copies of that probe were sent after the inputs (their ACKs
    may be among ``replies`` in any form).
    """
    ignore = set(ignore_seqs)
    by_key: dict[tuple[int, int], list[int]] = {}
    for i, inp in enumerate(inputs):
        if inp.header is not None:
            by_key.setdefault((inp.header[1], inp.header[2]), []).append(i)
    acked: set[int] = set()
    flaws: list[Flaw] = []
    unmatched: list[tuple[Datagram, int]] = []
    probe_answered = False
    uses: dict[tuple[int, int], int] = {}
    for d in replies:
        seq = acked_seq(d)
        if seq is None:
            continue
        key = (d.header[0], seq)  # type: ignore[index]  # the ACK's dst is the input's src
        cands = by_key.get(key, [])
        if key in ignore:  # the probe's ACK; it may answer an input of the same seq as well
            probe_answered = True
            acked.update(i for i in cands if expected_silent_rule(inputs[i], node_id, broadcast_id) is None)
            continue
        if not cands:
            unmatched.append((d, seq))
            continue
        legit = [i for i in cands if expected_silent_rule(inputs[i], node_id, broadcast_id) is None]
        if legit:
            if uses.get(key, 0) >= len(cands):
                # more ACKs naming (src, seq) than datagrams sent with it: a node ACKs each
                # datagram once, so this one answers something else (an ACK that names a
                # constant, say) and is tied by order below
                unmatched.append((d, seq))
                continue
            uses[key] = uses.get(key, 0) + 1
            # every copy is ACKed again (MCP-ACK-1): one ACK answers one copy, in order
            acked.update(legit[:uses[key]])
            if len(d.data) != HEADER_SIZE + 2:
                flaws.append(Flaw("MCP-ACK-2", "an ACK payload of exactly 2 bytes",
                                  f"{len(d.data) - HEADER_SIZE} payload bytes in the ACK of {inputs[legit[-1]].describe()}",
                                  culprit=legit[-1], evidence=(f"reply: {d.data.hex()}",)))
            continue
        rules = {expected_silent_rule(inputs[i], node_id, broadcast_id) for i in cands}
        if len(rules) > 1:
            continue  # inputs of different kinds share this (src, seq): the ACK proves nothing
        i = cands[-1]
        rule = rules.pop()
        assert rule is not None
        flaws.append(Flaw(rule, "no ACK (discarded silently)",
                          f"ACK seq {seq} to {d.header[0]} for {inputs[i].describe()}",  # type: ignore[index]
                          culprit=i, evidence=(f"input: {inputs[i].data.hex()}",
                                               f"reply: {d.data.hex()}")))
    probe_acks = (0, 0) if probe_answered or not probe_copies else (1, probe_copies)
    flaws += _misaddressed(inputs, unmatched, acked, node_id, broadcast_id, probe_acks,
                           {k[0] for k in ignore} if probe_acks[1] else set())
    for i in acked:
        inputs[i].observed["acked"] = True
    if probe_acked:
        for i, inp in enumerate(inputs):
            m = inp.msg
            if m is not None and i not in acked and _must_ack(inp, node_id, broadcast_id):
                flaws.append(Flaw("MCP-ACK-1", f"an ACK naming seq {m.seq}",
                                  f"no ACK of {inp.describe()}, though the probe sent after it was ACKed",
                                  culprit=i, evidence=(f"input: {inp.data.hex()}",)))
    return flaws


def _must_ack(inp: Input, node_id: int, broadcast_id: int) -> bool:
    """A message a correct node ACKs: a unicast to it, not an ACK, from a real other ID (one
    bearing the node's own ID may be taken for its own looped-back broadcast, MCP-HDR-4; one
    from the broadcast ID cannot be ACKed, MCP-ACK-3)."""
    m = inp.msg
    return (m is not None and m.action != _ACK and m.dst == node_id
            and m.src not in (node_id, broadcast_id))


def _misaddressed(inputs: Sequence[Input], unmatched: list[tuple[Datagram, int]], acked: set[int],
                  node_id: int, broadcast_id: int, probe_acks: tuple[int, int] = (0, 0),
                  probe_srcs: set[int] | None = None) -> list[Flaw]:
    """ACKs that answer no input as sent, tied to the inputs still awaiting their ACK.

    1. When they are exactly as many as the waiting inputs (plus the ACKs of the probe's
       copies, ``probe_acks`` = (fewest, most), when the probe's ACK was not found either):
       a node answers the datagrams of one socket in the order they came, so they pair up
       in order. Only ACKs addressed to a waiting input's src or the probe's count here (an
       ACK of a message the node may answer or not, one from its own ID, goes elsewhere). An ACK naming its input's seq went to the wrong dst (MCP-ACK-3: dst is the
       acknowledged message's src); one naming another seq has the wrong payload (MCP-ACK-2:
       the seq, big-endian, D-2) - the node's own seq, the previous one, a byte-swapped one.
    2. Otherwise only unambiguous answers are judged: an ACK naming the seq of exactly one
       waiting input (MCP-ACK-3), or whose byte-swapped seq names exactly one waiting input
       from its dst (MCP-ACK-2).
    A judged input counts as answered (one fault, one rule: not MCP-ACK-1 as well)."""
    flaws: list[Flaw] = []

    def waiting(pred) -> list[int]:  # noqa: ANN001
        return [i for i, inp in enumerate(inputs)
                if i not in acked and _must_ack(inp, node_id, broadcast_id) and pred(inp.msg)]

    def judge(d: Datagram, seq: int, i: int, how: str = "") -> None:
        m = inputs[i].msg
        assert m is not None
        if seq == m.seq:
            flaws.append(Flaw("MCP-ACK-3", f"the ACK's dst is {m.src} (the message's src)",
                              f"ACK of seq {seq} sent to {d.header[0]} for {inputs[i].describe()}",  # type: ignore[index]
                              culprit=i, evidence=(f"reply: {d.data.hex()}",)))
        else:
            swapped = ((seq & 0xFF) << 8) | (seq >> 8)
            how = ": the seq byte-swapped" if swapped == m.seq else how
            flaws.append(Flaw("MCP-ACK-2", f"an ACK naming seq {m.seq} big-endian ({m.seq:04x})",
                              f"the ACK names {seq} ({seq:04x}){how}, for {inputs[i].describe()}",
                              culprit=i, evidence=(f"reply: {d.data.hex()}",)))
        acked.add(i)

    left = waiting(lambda m: True)
    fewest, most = probe_acks
    dsts = {inputs[i].msg.src for i in left} | (probe_srcs or set())  # type: ignore[union-attr]
    pairable = [(d, seq) for d, seq in unmatched if d.header[0] in dsts]  # type: ignore[index]
    if left and len(left) + fewest <= len(pairable) <= len(left) + most:
        for (d, seq), i in zip(pairable, left, strict=False):
            want = inputs[i].msg.seq  # type: ignore[union-attr]
            off = (seq - want) & 0xFFFF
            judge(d, seq, i, f", {off if off < 0x8000 else off - 0x10000:+d} from the message's seq "
                             "(the reply paired with it by order of arrival)")
        return flaws
    for d, seq in unmatched:
        dst = d.header[0]  # type: ignore[index]
        swapped = ((seq & 0xFF) << 8) | (seq >> 8)
        by_seq = waiting(lambda m, s=seq: m.seq == s)
        by_swap = waiting(lambda m, s=swapped, t=dst: m.seq == s and m.src == t) if swapped != seq else []
        if len(by_seq) == 1 and not by_swap:
            judge(d, seq, by_seq[0])
        elif len(by_swap) == 1 and not by_seq:
            judge(d, seq, by_swap[0])
    return flaws


def blame_rule(inp: Input) -> str:
    """The rule a node that died or hung after ``inp`` broke (see the module docstring)."""
    if len(inp.data) < HEADER_SIZE:
        return "MCP-ROB-1"
    if len(inp.data) > OVERSIZE:
        return "MCP-ROB-6"
    return "MCP-ROB-5"


def judge_exchange(inputs: Sequence[Input], target: Any, mark: Any, probe: Any) -> list[Flaw]:
    """What the node did with ``inputs`` and the liveness ``probe`` sent after them (every
    engine and replay judge a batch this one way): the node's replies since ``mark`` judged
    per input (:func:`judge_replies`), each missing ACK observed as MCP-ACK-1 says
    (:func:`observe_missing_acks`), then its liveness (:func:`judge_liveness`) last."""
    drv = target.driver
    if target.impairment_spoiled():
        # --impair: the link dropped, copied or reordered part of this exchange; what the
        # node did is not judged (a dropped ACK is not MCP-ACK-1), only a death stands
        dead = judge_liveness(inputs, True, target.fate())
        return [dead] if dead is not None else []
    flaws = judge_replies(inputs, drv.received(mark), target.node_id, target.broadcast_id,
                          probe.acked, ignore_seqs=[(drv.our_id, probe.sent.seq)],
                          probe_copies=probe.copies)
    dead = judge_liveness(inputs, probe.acked, target.fate())
    if dead is None:
        flaws = observe_missing_acks(flaws, inputs, target)
    return flaws + ([dead] if dead is not None else [])


def observe_missing_acks(flaws: list[Flaw], inputs: Sequence[Input], target: Any) -> list[Flaw]:
    """MCP-ACK-1 as its rule observes it: "the runner retransmitting it every --rto as a
    manager would, up to 5 copies (a node may be deaf while busy, D-6)". Each input left
    without an ACK is retransmitted (``fuzz.observation``); answered, it is no flaw (and the
    node is known to have it); unanswered through every copy, the flaw stands with the
    copies' timing. The first such input is the exchange's MCP-ACK-1; the exchange's other
    missing ACKs are then not observed, so not reported. A healthy node pays nothing."""
    kept: list[Flaw] = []
    confirmed = False
    for f in flaws:
        if f.rule != "MCP-ACK-1" or f.source != "replies" or f.culprit is None:
            kept.append(f)
            continue
        if confirmed or not _alive(target):
            continue  # not observed as the rule says (a death is judge_liveness's)
        inp = inputs[f.culprit]
        _count(target, "ack1_retransmitted")
        seen = retransmit_unanswered(target, inp.data)
        inp.observed["resent"] = inp.observed.get("resent", 0) + seen.copies - 1
        if seen.acked:
            inp.observed["acked"] = True
            _count(target, "ack1_answered_on_retransmission")
            continue
        if not _alive(target):
            continue
        confirmed = True
        kept.append(replace(f, actual=f"{f.actual}, nor any of its {seen.copies - 1} retransmissions",
                            evidence=f.evidence + (f"timing: {seen.describe()}",)))
    return kept


def _count(target: Any, what: str) -> None:
    """One more of ``what`` in the target's ``observations`` (what the oracles had to do)."""
    target.observations[what] = target.observations.get(what, 0) + 1


def _alive(target: Any) -> bool:
    return bool(target.fate().get("alive", True))


def judge_liveness(inputs: Sequence[Input], probe_acked: bool, fate: dict[str, Any]) -> Flaw | None:
    """A dead or hung node after ``inputs`` (the last input is blamed until shrinking says
    which one it was). MCP-ROB-5 "it still ACKs the next valid unicast message" (and ROB-6)
    depend on MCP-ACK-1, so "hung" is a probe unanswered through its copies every --rto, as
    many as MCP-ACK-1 observes (``fuzz.target_base.PROBE_COPIES``); a death is the process's
    exit, seen at once."""
    if probe_acked and fate.get("alive", True):
        return None
    died = not fate.get("alive", True)
    if died:
        how = (f"killed by {fate['signal']}" if fate.get("signal")
               else f"exited with code {fate.get('exit_code')}")
    else:
        how = "no ACK of the liveness probe (hung)"
    culprit = len(inputs) - 1 if inputs else None
    rule = blame_rule(inputs[culprit]) if culprit is not None else "MCP-ROB-5"
    ev = [f"input: {inputs[culprit].data.hex()}" if culprit is not None else "no input"]
    tail = str(fate.get("stderr_tail") or "")
    if tail:
        ev.append("node stderr (last lines):\n    " + tail.replace("\n", "\n    "))
    return Flaw(rule, "the node stays live and ACKs the next valid unicast",
                f"the node {how} after {inputs[culprit].describe() if culprit is not None else 'no input'}",
                culprit=culprit, evidence=tuple(ev), source="process" if died else "liveness")


def judge_withheld(copies: Sequence[Datagram], after_wrong_ack: Datagram | None, wanted: int,
                   alive: bool) -> Flaw | None:
    """A fresh node's Mission_Ready, ACK withheld for ``wanted`` copies, then an ACK naming
    another seq: it retransmits (MCP-RTX-1), each copy the same bytes (MCP-SEQ-2), and the
    wrong ACK does not end it (MCP-RTX-2). Observed as MCP-RTX-1 says, "at least 3 copies
    while the ACK is withheld" (``wanted`` up to ``MIN_COPIES``), and MCP-RTX-2 over 2.5
    periods after the wrong ACK (``fuzz.drone_target.FuzzTarget.restart_withholding``).

    Copies are counted by number, as the drone suite's cases and the trace monitor count them
    (``judge.copies_by_number``): "Retransmissions of the same message are identified by
    repeating sequence number". Seq N twice, then (given up) seq N+1 is 2 copies of N, MCP-RTX-1
    -- not MCP-SEQ-2, which took N+1 for N's third copy; N once, then the same message under new
    numbers (the ``rtx-new-seq`` fault) is a retransmission renumbered, MCP-SEQ-2."""
    if not alive:
        return None  # a death is judge_liveness's
    renumbered = copies_by_number.renumbered(copies)
    same = list(copies) if renumbered else copies_by_number.by_number(copies)
    if not renumbered and len(same) < min(wanted, MIN_COPIES):
        then = (f", then a new Mission_Ready ({copies_by_number.describe_new(copies)}): a new message, "
                "not a copy (retransmissions repeat the number)") if len(same) < len(copies) else ""
        return Flaw("MCP-RTX-1", f"Mission_Ready retransmitted while unACKed ({wanted} copies awaited)",
                    f"{len(same)} cop{'y' if len(same) == 1 else 'ies'} seen{then}", source="startup")
    if len({d.data for d in same}) > 1:
        return Flaw("MCP-SEQ-2", "every copy of Mission_Ready repeats the original's bytes",
                    "copies differ: " + ", ".join(f"seq {d.header[2]}" for d in same if d.header),
                    source="startup", evidence=tuple(d.data.hex() for d in same))
    if after_wrong_ack is None:
        return Flaw("MCP-RTX-2", "retransmission goes on after an ACK naming another seq",
                    "no copy of Mission_Ready after the ACK of another seq", source="startup")
    return None


# ---------------------------------------------------------------- trace monitor
class MonitorOracle:
    """The trace monitor over all traffic, keeping only the node under test's violations.

    ``judge.monitor`` is the shared judge of traffic (docs/design.md, "The trace monitor"),
    with the spec's own windows (MCP-ACK-7 "judged on the median of at least 3 samples",
    MCP-RTX-3's spacing tolerance, D-6's ACK window); the rules a batch's attribution decides
    (``REPLY_RULES``, MCP-ACK-1 among them) are left to judge_replies and
    :func:`observe_missing_acks`. Where it is not installed, this oracle says so
    (``available``) and judges nothing.
    """

    def __init__(self, node_id: int, rto: float, ack_window: float, broadcast_id: int,
                 local_addr: tuple[str, int]) -> None:
        self.node_id = node_id
        self.local = local_addr
        self.datagrams = 0
        self._sent_by_index: dict[int, bytes | None] = {}
        try:
            from mcp_conform.judge.monitor import TESTER, Monitor
        except ImportError:
            self.monitor: Any = None
            self.tester: Any = None
        else:
            self.monitor = Monitor(rto=rto, ack_window=ack_window, broadcast_id=broadcast_id)
            self.tester = TESTER  # the fuzzer's own datagrams: input, never blamed

    @property
    def available(self) -> bool:
        return self.monitor is not None

    def feed(self, records: Iterable[Any]) -> list[Flaw]:
        """Feed traffic records (direction, t_ns, data, addr); the node's violations."""
        if self.monitor is None:
            return []
        out: list[Flaw] = []
        for r in records:
            self._sent_by_index[self.datagrams] = r.data if r.direction == "tx" else None
            self.datagrams += 1
            if r.direction == "tx":
                vs = self.monitor.datagram(r.t_ns, self.local, r.addr, r.data, origin=self.tester)
            else:
                vs = self.monitor.datagram(r.t_ns, r.addr, self.local, r.data, origin=self.node_id,
                                           run_delay=getattr(r, "run_delay", None))
            out.extend(self._mine(vs))
        return out

    def advance(self, t_ns: int) -> list[Flaw]:
        return [] if self.monitor is None else self._mine(self.monitor.advance(t_ns))

    def finish(self, t_ns: int) -> list[Flaw]:
        return [] if self.monitor is None else self._mine(self.monitor.finish(t_ns))

    def _mine(self, violations: Iterable[Any]) -> list[Flaw]:
        out = []
        for v in violations:
            if v.node != self.node_id or v.rule in REPLY_RULES:
                continue
            # the fuzzer's datagram the violation answers (the first of ours in its evidence)
            ours = [self._sent_by_index.get(e[0]) for e in (v.evidence or ()) if isinstance(e, tuple) and e]
            culprit = next((d for d in ours if d is not None), None)
            out.append(Flaw(v.rule, str(v.expected), str(v.actual),
                            evidence=tuple(str(e) for e in (v.evidence or ())), source="monitor",
                            datagram=culprit))
        if len(self._sent_by_index) > 4096:  # evidence names recent datagrams: keep a window
            keep = sorted(self._sent_by_index)[-2048:]
            self._sent_by_index = {k: self._sent_by_index[k] for k in keep}
        return out

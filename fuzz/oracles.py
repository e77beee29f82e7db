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
  MCP-PAY-8, MCP-ACK-5, MCP-ROB-4).
- the trace monitor (:class:`MonitorOracle`, ``judge.monitor``): every datagram in and
  out, for the rules judged from traffic alone (HDR, ACK-2/3/7, SEQ, RTX, BLK, PAY ...). Only
  violations by the node under test count (the fuzzer's datagrams are fed as the tester's:
  they break rules on purpose), and the reply rules above stay judge_replies's.
"""

from __future__ import annotations

import struct
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

from harness.driver import Datagram
from harness.session_base import MIN_COPIES  # the original + MCP-RTX-1's retransmissions
from spec import SPEC
from spec.codec import HEADER_SIZE, Action, DecodeError, Message, decode

__all__ = [
    "OVERSIZE",
    "DeliveryLedger",
    "Flaw",
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


def rule_level(rule: str) -> str:
    return SPEC.rule(rule).level if rule in SPEC.rules_by_id else "MUST"


@dataclass(frozen=True)
class Flaw:
    """One thing the node did wrong: the rule, expected vs actual, and the input to blame
    (``culprit``: index into the inputs judged, None when it is the whole sequence)."""

    rule: str
    expected: str
    actual: str
    culprit: int | None = None
    evidence: tuple[str, ...] = ()
    source: str = "replies"  # replies | liveness | process | vehicle | monitor
    datagram: bytes | None = None  # the culprit's bytes, where the index alone is not enough

    @property
    def level(self) -> str:
        return rule_level(self.rule)


@dataclass(frozen=True)
class Input:
    """One datagram the fuzzer sent, decoded once."""

    data: bytes
    header: tuple[int, int, int, int] | None  # (dst, src, seq, action), whatever the preamble
    msg: Message | None
    error: DecodeError | None

    @classmethod
    def of(cls, data: bytes) -> Input:
        from harness.driver import read_header

        try:
            return cls(data, read_header(data), decode(data), None)
        except DecodeError as exc:
            return cls(data, read_header(data), None, exc)

    def describe(self) -> str:
        if self.msg is not None:
            m = self.msg
            return f"{Action(m.action).name} dst={m.dst} src={m.src} seq={m.seq} ({len(self.data)} B)"
        if self.header is not None:
            dst, src, seq, action = self.header
            return (f"malformed action={action} dst={dst} src={src} seq={seq} ({len(self.data)} B): "
                    f"{self.error}")
        return f"malformed {len(self.data)} B: {self.error}"


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
            acked.update(legit)
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
    per input (:func:`judge_replies`), then its liveness (:func:`judge_liveness`) last."""
    drv = target.driver
    spoiled = getattr(target, "impairment_spoiled", None)
    if spoiled is not None and spoiled():
        # --impair: the link dropped, copied or reordered part of this exchange; what the
        # node did is not judged (a dropped ACK is not MCP-ACK-1), only a death stands
        dead = judge_liveness(inputs, True, target.fate())
        return [dead] if dead is not None else []
    flaws = judge_replies(inputs, drv.received(mark), target.node_id, target.broadcast_id,
                          probe.acked, ignore_seqs=[(drv.our_id, probe.sent.seq)],
                          probe_copies=probe.copies)
    dead = judge_liveness(inputs, probe.acked, target.fate())
    if dead is None:
        kept: list[Flaw] = []
        rechecks = 0
        for f in flaws:
            if f.rule == "MCP-ACK-1" and f.source == "replies" and f.culprit is not None and rechecks < RECHECKS:
                rechecks += 1
                if _acked_on_retransmission(target, inputs[f.culprit]):
                    continue
            kept.append(f)
        flaws = kept
    return flaws + ([dead] if dead is not None else [])


RECHECKS = 3  # missing ACKs re-checked per exchange at most (the rest stand as seen)


def _acked_on_retransmission(target: Any, inp: Input) -> bool:
    """A missing ACK (MCP-ACK-1) is a finding only if the input was retransmitted as a manager
    would and no copy was ACKed either: UDP may lose a datagram even on loopback (a full
    receive buffer under a burst), and a lost datagram is the link's doing, not the node's
    (issue 18 item 9: correct nodes got MUST findings that replayed 0 of 3). Re-sends the
    input's bytes (a copy: the node ACKs copies and does not deliver them again, MCP-ACK-1,
    MCP-DUP-1) up to two times, every --rto; True when a copy was ACKed."""
    drv = target.driver
    mark = drv.mark()
    for _ in range(2):
        sent = drv.send_raw(inp.data)
        if drv.wait_for(drv.ack_for(sent), max(target.rto, 0.5), mark) is not None:
            return True
    return False


def judge_liveness(inputs: Sequence[Input], probe_acked: bool, fate: dict[str, Any]) -> Flaw | None:
    """A dead or hung node after ``inputs`` (the last input is blamed until shrinking says
    which one it was)."""
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
    wrong ACK does not end it (MCP-RTX-2)."""
    if not alive:
        return None  # a death is judge_liveness's
    if len(copies) < min(wanted, MIN_COPIES):
        return Flaw("MCP-RTX-1", f"Mission_Ready retransmitted while unACKed ({wanted} copies awaited)",
                    f"{len(copies)} cop{'y' if len(copies) == 1 else 'ies'} seen", source="startup")
    if len({d.data for d in copies}) > 1:
        return Flaw("MCP-SEQ-2", "every copy of Mission_Ready repeats the original's bytes",
                    "copies differ: " + ", ".join(f"seq {d.header[2]}" for d in copies if d.header),
                    source="startup", evidence=tuple(d.data.hex() for d in copies))
    if after_wrong_ack is None:
        return Flaw("MCP-RTX-2", "retransmission goes on after an ACK naming another seq",
                    "no copy of Mission_Ready after the ACK of another seq", source="startup")
    return None


# ---------------------------------------------------------------- vehicle
@dataclass
class _Sent:
    index: int
    token: str
    expect_min: int
    expect_max: int
    rule_over: str
    rule_under: str
    what: str
    data: bytes = b""
    t: float = 0.0


@dataclass
class DeliveryLedger:
    """How often each passthrough probe token may reach the autopilot, by the spec's
    duplicate rules: per source, a message with the (src, seq) of the last one delivered is
    a duplicate (MCP-DUP-1, per source MCP-DUP-3), a new seq is delivered (MCP-DUP-2; 0
    after 65535 is new, MCP-SEQ-3); a late copy of an older seq may go either way (MCP-DUP-4,
    INFO). Broadcasts are delivered but not ACKed; messages to another ID are not acted on
    (MCP-ACK-5); malformed ones neither (MCP-ROB-4, D-4)."""

    node_id: int
    broadcast_id: int
    last_delivered: dict[int, int] = field(default_factory=dict)  # src -> seq
    delivered_seqs: dict[int, set[int]] = field(default_factory=dict)
    highest: dict[int, int] = field(default_factory=dict)  # src -> numerically highest delivered
    expected: dict[str, _Sent] = field(default_factory=dict)
    checked_under: set[str] = field(default_factory=set)

    def sent(self, index: int, inp: Input, token: str | None) -> None:
        """Record one input (in sending order), with the probe token it carries, if any."""
        m = inp.msg
        if m is None or m.action == _ACK:
            if token is not None and m is None:
                self._expect(token, index, 0, 0, "MCP-ROB-4", "MCP-ROB-4", inp)
            return
        if m.src in (self.node_id, self.broadcast_id):  # no valid sender (see judge_replies)
            if token is not None:
                self._expect(token, index, 0, 1, "MCP-PAY-8", "MCP-DUP-4", inp)
            return
        if m.dst not in (self.node_id, self.broadcast_id):
            if token is not None:
                self._expect(token, index, 0, 0, "MCP-ACK-5", "MCP-ACK-5", inp)
            return
        last = self.last_delivered.get(m.src)
        if last == m.seq:  # a duplicate of the last delivered: not delivered again
            if token is not None:
                self._expect(token, index, 0, 0, "MCP-DUP-1", "MCP-DUP-1", inp, add=True)
            return
        seen = self.delivered_seqs.setdefault(m.src, set())
        older = m.seq in seen
        # a new number below one already delivered: the numbers have wrapped since (MCP-SEQ-3)
        wrapped = not older and m.seq < self.highest.get(m.src, -1)
        self.last_delivered[m.src] = m.seq
        seen.add(m.seq)
        self.highest[m.src] = max(self.highest.get(m.src, -1), m.seq)
        if token is None or m.action != _PASSTHROUGH:
            return
        if older:  # a late copy of an older seq: MCP-DUP-4 (INFO) leaves it open
            self._expect(token, index, 0, 1, "MCP-PAY-8", "MCP-DUP-4", inp, add=True)
        else:
            self._expect(token, index, 1, 1, "MCP-PAY-8",
                         "MCP-SEQ-3" if wrapped else "MCP-DUP-2", inp, add=True)

    def _expect(self, token: str, index: int, lo: int, hi: int, over: str, under: str,
                inp: Input, add: bool = False) -> None:
        prev = self.expected.get(token)
        now = time.monotonic()
        if prev is not None and add:
            # another copy of the same frame: the allowance adds up; the rule of the copy that
            # pushed the count over is the one blamed
            self.expected[token] = _Sent(index, token, prev.expect_min + lo, prev.expect_max + hi,
                                         over if hi == 0 else prev.rule_over,
                                         prev.rule_under, inp.describe(), inp.data, now)
        elif prev is None:
            self.expected[token] = _Sent(index, token, lo, hi, over, under, inp.describe(), inp.data, now)

    def expire(self, older_than: float) -> None:
        """Forget tokens sent before ``older_than`` (time.monotonic)."""
        self.expected = {k: e for k, e in self.expected.items() if e.t >= older_than}

    def judge(self, counts: dict[str, int], *, settled: bool) -> list[Flaw]:
        """Over-delivery at any time; under-delivery only once the forwards have settled."""
        flaws = []
        for token, e in self.expected.items():
            n = counts.get(token, 0)
            if n > e.expect_max:
                flaws.append(Flaw(e.rule_over, f"frame {token} reaches the autopilot at most {e.expect_max} time(s)",
                                  f"it reached the autopilot {n} times (last input: {e.what})",
                                  culprit=e.index, source="vehicle", datagram=e.data))
            elif settled and n < e.expect_min and e.rule_under != "MCP-DUP-4":
                flaws.append(Flaw(e.rule_under, f"frame {token} reaches the autopilot {e.expect_min} time(s)",
                                  f"it reached the autopilot {n} times ({e.what})",
                                  culprit=e.index, source="vehicle", datagram=e.data))
        return flaws


# ---------------------------------------------------------------- trace monitor
class MonitorOracle:
    """The trace monitor over all traffic, keeping only the node under test's violations.

    ``judge.monitor`` is the shared judge of traffic (DESIGN.md); where it is not
    installed, this oracle says so (``available``) and judges nothing.
    """

    def __init__(self, node_id: int, rto: float, ack_window: float, broadcast_id: int,
                 local_addr: tuple[str, int]) -> None:
        self.node_id = node_id
        self.local = local_addr
        self.datagrams = 0
        self._sent_by_index: dict[int, bytes | None] = {}
        try:
            from judge.monitor import TESTER, Monitor
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

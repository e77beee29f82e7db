"""The vehicle's oracle: how often each passthrough frame may reach the autopilot.

Passthrough frames carry probe tokens (``vehicle.probe``); the vehicle counts each token it
is sent. The spec's duplicate rules say how often each may arrive: per source, a message
with the (src, seq) of the last one delivered is a duplicate (MCP-DUP-1, per source
MCP-DUP-3), a new seq is delivered (MCP-DUP-2; 0 after 65535 is new, MCP-SEQ-3); a late copy
of an older seq may go either way (MCP-DUP-4, INFO); a delivered frame is forwarded exactly
once (MCP-PAY-8). Broadcasts are delivered but not ACKed; messages to another ID are not
acted on (MCP-ACK-5); malformed ones neither (MCP-ROB-4, D-4).

Observed as the rules say (issue 36): MCP-DUP-1's duplicate is one of "the one last
delivered from that src" — a message the node had. The ledger's model of the node is what
the fuzzer sent, and UDP may drop a datagram before the node ever reads it (a full receive
buffer under a burst), so a verdict that rests on the node having had a message asks for
that to be shown: its ACK (``Input.received``, set by the reply oracle and by MCP-ACK-1's
retransmissions) or its frame's own delivery. A copy of a message not shown received may be
delivered (the node may never have had the original); a frame not shown received is not
judged for under-delivery; copies MCP-ACK-1's observation retransmitted after later
messages from the same source are late copies (MCP-DUP-4). A finding carries what the
judgement needed: the vehicle's count of the frame, the node's state before the input as
the ledger knew it, and the timing.

A copy adds a delivery (MCP-DUP-1) only if the frame's count grows after it: a node that
forwards each delivered frame twice (MCP-PAY-8) shows the frame twice whether a copy follows
or not. Sent back to back, the original's forwards and the copy's cannot be told apart, so
an over-delivery then names the copy's rule as a suspicion; a replay (``fuzz.replay``, the
path of triage's confirmation) first lets the original's forwards settle and gives the count
then (``base``), as MCP-DUP-1's conformance case takes its baseline once the first delivery's
count has stopped moving (``conformance.drone_case.CaseContext.redeliver``): an excess
already there before the copy is the earlier inputs' (their rule, MCP-PAY-8 for a delivered
frame), and MCP-DUP-1 is blamed only when the count grew past it.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

from mcp_conform.fuzz.flaws import Flaw, Input
from mcp_conform.spec.codec import Action

__all__ = ["DeliveryLedger"]

_ACK = int(Action.ACK)
_PASSTHROUGH = int(Action.MAV_PASSTHROUGH)


@dataclass
class _Sent:
    """One frame's allowance: what the inputs carrying its token let it do."""

    index: int
    token: str
    expect_min: int
    expect_max: int
    rule_over: str
    rule_under: str
    what: str
    data: bytes = b""
    t: float = 0.0  # the first input's send time (time.monotonic)
    last_t: float = 0.0
    src: int | None = None
    before: str = ""  # the node's state before the first input, as the ledger knew it
    inputs: list[Input] = field(default_factory=list)
    #: (the message last delivered from the src, its token) of each copy expected to be
    #: discarded as its duplicate: the premise of that expectation
    dup_bases: list[tuple[Input, str | None]] = field(default_factory=list)
    last_index: int = 0
    #: the frame's settled count just before its first copy expected discarded (None: not
    #: taken, the copy sent right behind), the allowance and rule of the inputs before it
    base: int | None = None
    base_max: int = 0
    base_rule: str = ""
    base_index: int = 0


@dataclass
class DeliveryLedger:
    """How often each passthrough probe token may reach the autopilot (module docstring)."""

    node_id: int
    broadcast_id: int
    last_delivered: dict[int, int] = field(default_factory=dict)  # src -> seq
    delivered_seqs: dict[int, set[int]] = field(default_factory=dict)
    highest: dict[int, int] = field(default_factory=dict)  # src -> numerically highest delivered
    expected: dict[str, _Sent] = field(default_factory=dict)
    checked_under: set[str] = field(default_factory=set)
    last_input: dict[int, tuple[Input, str | None]] = field(default_factory=dict)  # src -> basis
    last_index: dict[int, int] = field(default_factory=dict)  # src -> index of its last input

    def repeats_last(self, inp: Input, token: str | None) -> bool:
        """Whether ``inp`` is a copy of the message last delivered from its src carrying a
        frame the ledger expects (a copy to be discarded, MCP-DUP-1): the replay takes the
        frame's settled count before sending it (``sent``'s ``base``)."""
        m = inp.msg
        return (token is not None and token in self.expected and m is not None and m.action == _PASSTHROUGH
                and m.src not in (self.node_id, self.broadcast_id) and m.dst in (self.node_id, self.broadcast_id)
                and self.last_delivered.get(m.src) == m.seq)

    def sent(self, index: int, inp: Input, token: str | None, *, base: int | None = None) -> None:
        """Record one input (in sending order), with the probe token it carries, if any;
        ``base``: the frame's settled count just before it was sent (``repeats_last``)."""
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
        self.last_index[m.src] = index
        last = self.last_delivered.get(m.src)
        before = self._state(m.src) if token is not None else ""
        if last == m.seq:  # a duplicate of the last delivered: not delivered again
            if token is not None:
                self._expect(token, index, 0, 0, "MCP-DUP-1", "MCP-DUP-1", inp, add=True, before=before,
                             basis=self.last_input.get(m.src), base=base)
            return
        seen = self.delivered_seqs.setdefault(m.src, set())
        older = m.seq in seen
        # a new number below one already delivered: the numbers have wrapped since (MCP-SEQ-3)
        wrapped = not older and m.seq < self.highest.get(m.src, -1)
        self.last_delivered[m.src] = m.seq
        self.last_input[m.src] = (inp, token)
        seen.add(m.seq)
        self.highest[m.src] = max(self.highest.get(m.src, -1), m.seq)
        if token is None or m.action != _PASSTHROUGH:
            return
        if older:  # a late copy of an older seq: MCP-DUP-4 (INFO) leaves it open
            self._expect(token, index, 0, 1, "MCP-PAY-8", "MCP-DUP-4", inp, add=True, before=before)
        else:
            self._expect(token, index, 1, 1, "MCP-PAY-8",
                         "MCP-SEQ-3" if wrapped else "MCP-DUP-2", inp, add=True, before=before)

    def _state(self, src: int) -> str:
        """What the node had from ``src`` before this input, as far as the ledger knows."""
        basis = self.last_input.get(src)
        if basis is None:
            return f"nothing delivered from src {src} yet"
        inp = basis[0]
        shown = "ACKed" if inp.received else "not shown received (no ACK)"
        return (f"last delivered from src {src}: seq {self.last_delivered.get(src)} "
                f"({inp.describe()}, {shown}); {len(self.delivered_seqs.get(src, ()))} seq(s) delivered")

    def _expect(self, token: str, index: int, lo: int, hi: int, over: str, under: str,
                inp: Input, add: bool = False, before: str = "",
                basis: tuple[Input, str | None] | None = None, base: int | None = None) -> None:
        prev = self.expected.get(token)
        now = time.monotonic()
        src = inp.msg.src if inp.msg is not None else None
        if prev is None:
            e = _Sent(index, token, lo, hi, over, under, inp.describe(), inp.data, now, now, src, before)
            self.expected[token] = e
        elif add:
            # another copy of the same frame: the allowance adds up; the rule of the copy that
            # pushed the count over is the one blamed
            e = prev
            if base is not None and hi == 0 and e.base is None:  # the first copy, its baseline taken
                e.base, e.base_max, e.base_rule, e.base_index = base, e.expect_max, e.rule_over, e.index
            e.index, e.expect_min, e.expect_max = index, e.expect_min + lo, e.expect_max + hi
            e.rule_over = over if hi == 0 else e.rule_over
            e.what, e.data, e.last_t = inp.describe(), inp.data, now
        else:
            return
        e.inputs.append(inp)
        e.last_index = index
        if basis is not None and hi == 0 and basis[1] != token:
            e.dup_bases.append(basis)

    def expire(self, older_than: float) -> None:
        """Forget tokens sent before ``older_than`` (time.monotonic)."""
        self.expected = {k: e for k, e in self.expected.items() if e.last_t >= older_than}

    def _unproven(self, e: _Sent, counts: dict[str, int]) -> int:
        """Deliveries the rules allow once what the node was not shown to have is counted:
        a copy of a message it may never have had may be its first (MCP-DUP-1's premise), and
        MCP-ACK-1's retransmissions sent after later messages of the src are late copies
        (MCP-DUP-4)."""
        extra = sum(1 for b, btok in e.dup_bases
                    if not (b.received or (btok is not None and counts.get(btok, 0) >= 1)))
        if e.src is not None and self.last_index.get(e.src, -1) > e.last_index:
            extra += sum(int(i.observed.get("resent", 0)) for i in e.inputs)
        return extra

    def judge(self, counts: dict[str, int], *, settled: bool) -> list[Flaw]:
        """Over-delivery at any time; under-delivery only once the forwards have settled, and
        only of a frame the node was shown to have received."""
        flaws = []
        now = time.monotonic()
        for token, e in self.expected.items():
            n = counts.get(token, 0)
            unproven = self._unproven(e, counts)
            most = e.expect_max + unproven
            if n > most:
                rule, culprit, evidence = e.rule_over, e.index, self._evidence(e, n, now, settled)
                if e.base is not None:
                    # the copies' share: the count's growth from the settled baseline
                    added = n - e.base
                    if added <= e.expect_max - e.base_max + unproven:  # the excess came before the copy
                        rule, culprit = e.base_rule, e.base_index
                    evidence += (f"before its copy: {e.base} time(s), settled (the inputs before it allow "
                                 f"{e.base_max}); after: {added} more",)
                flaws.append(Flaw(rule, f"frame {token} reaches the autopilot at most {most} time(s)",
                                  f"it reached the autopilot {n} times (last input: {e.what})",
                                  culprit=culprit, source="vehicle", datagram=e.data, evidence=evidence))
            elif (settled and n < e.expect_min and e.rule_under != "MCP-DUP-4"
                  and any(i.received for i in e.inputs)):
                flaws.append(Flaw(e.rule_under, f"frame {token} reaches the autopilot {e.expect_min} time(s)",
                                  f"it reached the autopilot {n} times ({e.what})",
                                  culprit=e.index, source="vehicle", datagram=e.data,
                                  evidence=self._evidence(e, n, now, settled)))
        return flaws

    def _evidence(self, e: _Sent, n: int, now: float, settled: bool) -> tuple[str, ...]:
        acked = sum(1 for i in e.inputs if i.received)
        return (f"vehicle link: frame {e.token} delivered {n} time(s); {len(e.inputs)} input(s) carried it, "
                f"{acked} shown received (ACKed)",
                f"node state before the input: {e.before or 'unknown'}",
                f"timing: inputs sent over {e.last_t - e.t:.3f} s, judged {now - e.t:.3f} s after the first "
                f"({'forwards settled' if settled else 'forwards still arriving'})")

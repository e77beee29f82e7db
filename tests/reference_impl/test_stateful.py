"""Stateful property test: two endpoints through a seeded lossy link (drop, duplicate, reorder).

Hypothesis drives a manager (ID 0) and a drone (ID 1) with unicasts, broadcasts, garbage
and the passing of (virtual) time, and checks after every step:

- no message is delivered to an application twice (MCP-DUP-1);
- every retransmission repeats the original's sequence number and bytes (MCP-SEQ-2);
- nothing but ACKs, broadcasts and copies of the in-flight message leaves a node while one
  of its unicasts awaits its ACK (MCP-BLK-1);
- a unicast has at most one outcome;

and at the end, once the link is quiet: every unicast was either confirmed and delivered
exactly once, or reported failed (MCP-RTX-1) and delivered at most once.
Deterministic (derandomized) and bounded: 100 programs of at most 30 steps.
"""

from __future__ import annotations

from collections import Counter

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import RuleBasedStateMachine, initialize, invariant, rule

from reference_impl import (
    DeliveryConfirmed,
    DeliveryFailed,
    Endpoint,
    MessageDelivered,
)
from spec.codec import BROADCAST_ID, Action, DecodeError, MissionItem, decode
from tests.reference_impl.helpers import Link

RTO = 1.0
ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.5, -78.25, 10.0, 1, 16, 1, 1, 3, 0, 1)
PAYLOADS = {
    Action.START_MISSION: None,
    Action.END_MISSION: None,
    Action.WP_LIST: (ITEM, ITEM),
    Action.WP_ON: ITEM,
    Action.WP_OFF: None,
    Action.OBSTACLES_LIST: (),
}


def _decode(data: bytes):
    try:
        return decode(data)
    except DecodeError:  # pragma: no cover - endpoints only send well-formed messages
        return None


class TwoEndpointsOverLossyLink(RuleBasedStateMachine):
    @initialize(seed=st.integers(0, 2**32 - 1), drop=st.sampled_from([0.0, 0.1, 0.3]),
                duplicate=st.sampled_from([0.0, 0.2]), reorder=st.sampled_from([0.0, 0.3]),
                seq0=st.sampled_from([0, 65530]), seq1=st.integers(0, 65535))
    def setup(self, seed, drop, duplicate, reorder, seq0, seq1):
        eps = [Endpoint(0, timeout=RTO, retries=4, initial_seq=seq0),
               Endpoint(1, timeout=RTO, retries=4, initial_seq=seq1)]
        self.link = Link(eps, seed=seed, drop=drop, duplicate=duplicate, reorder=reorder,
                         jitter=0.8 * RTO)
        self.handles: list[list[int]] = [[], []]

    # ------------------------------------------------------------------ what may happen
    @rule(sender=st.integers(0, 1), action=st.sampled_from(sorted(PAYLOADS)),
          retries=st.sampled_from([None, 0, 2]))
    def send_unicast(self, sender, action, retries):
        kw = {} if retries is None else {"retries": retries}
        self.handles[sender].append(self.link.send(sender, action, PAYLOADS[action], 1 - sender, **kw))

    @rule(action=st.sampled_from(sorted(PAYLOADS)))
    def manager_broadcasts(self, action):
        self.link.send(0, action, PAYLOADS[action], BROADCAST_ID)

    @rule(node=st.integers(0, 1), data=st.binary(max_size=40))
    def garbage_arrives(self, node, data):
        self.link.inject(node, data)

    @rule(dt=st.floats(0.0, 3 * RTO))
    def time_passes(self, dt):
        self.link.run(until=self.link.now + dt, max_steps=5000)

    # ------------------------------------------------------------------ invariants
    @invariant()
    def no_duplicate_delivery(self):
        for node in self.link.nodes:
            keys = Counter((e.msg.src, e.msg.seq) for e in node.events_of(MessageDelivered))
            assert not [k for k, n in keys.items() if n > 1], keys

    @invariant()
    def retransmissions_repeat_seq_and_bytes(self):
        for node in self.link.nodes:
            by_seq: dict[int, bytes] = {}
            for data in node.sent:
                msg = _decode(data)
                assert msg is not None
                if msg.action == Action.ACK:
                    continue
                assert by_seq.setdefault(msg.seq, data) == data

    @invariant()
    def stop_and_wait(self):
        """MCP-BLK-1: while a unicast awaits its ACK only ACKs, broadcasts and its copies leave."""
        for node in self.link.nodes:
            in_flight: int | None = None
            for kind, _, x in node.trace:
                if kind == "ev" and isinstance(x, (DeliveryConfirmed, DeliveryFailed)):
                    assert x.seq == in_flight
                    in_flight = None
                elif kind == "tx":
                    msg = _decode(x)
                    if msg.action == Action.ACK or msg.dst == BROADCAST_ID:
                        continue
                    if in_flight is None:
                        in_flight = msg.seq
                    assert msg.seq == in_flight, f"seq {msg.seq} sent while {in_flight} in flight"

    @invariant()
    def at_most_one_outcome(self):
        for node in self.link.nodes:
            outcomes = Counter(e.handle for e in node.events
                               if isinstance(e, (DeliveryConfirmed, DeliveryFailed)))
            assert all(n == 1 for n in outcomes.values())

    def teardown(self):
        link = getattr(self, "link", None)
        if link is None:
            return
        link.run(max_steps=50_000)
        assert link.next_time() is None, "the link never went quiet"
        for i, node in enumerate(link.nodes):
            peer = link.nodes[1 - i]
            delivered = Counter((e.msg.src, e.msg.seq) for e in peer.events_of(MessageDelivered))
            outcomes = {e.handle: e for e in node.events
                        if isinstance(e, (DeliveryConfirmed, DeliveryFailed))}
            assert sorted(outcomes) == sorted(self.handles[i])  # each unicast: an outcome
            for ev in outcomes.values():
                n = delivered[(node.endpoint.node_id, ev.seq)]
                if isinstance(ev, DeliveryConfirmed):
                    assert n == 1, f"confirmed seq {ev.seq} delivered {n} times"
                else:
                    assert n <= 1


TwoEndpointsOverLossyLink.TestCase.settings = settings(
    max_examples=100, stateful_step_count=30, derandomize=True, deadline=None,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
test_two_endpoints_over_lossy_link = TwoEndpointsOverLossyLink.TestCase

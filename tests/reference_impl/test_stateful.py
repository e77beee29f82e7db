"""Stateful property test: two endpoints through a seeded lossy link (drop, duplicate, reorder).

Hypothesis drives a manager (ID 0) and a drone (ID 1) with unicasts, broadcasts, garbage
and the passing of (virtual) time, and checks after every step:

- no message is delivered to an application twice: MCP-DUP-1 requires this only for a copy
  of the *last* seq delivered from a src and MCP-DUP-4 leaves older ones open; the endpoint
  answers DUP-4 by also discarding copies of its last ``dup_window`` (64) seqs that are not
  ahead of the highest delivered. The link holds a datagram back by at most 0.8 RTO, so
  every copy arrives while its seq is in that window: twice is always an endpoint bug;
- every retransmission repeats the original's sequence number and bytes (MCP-SEQ-2);
- nothing but ACKs, broadcasts and copies of the in-flight message leaves a node while one
  of its unicasts awaits its ACK (MCP-BLK-1);
- a unicast has at most one outcome;

and at the end, once the link is quiet: every unicast was either confirmed and delivered
exactly once, or reported failed (MCP-RTX-1) and delivered at most once.
Deterministic (derandomized) and bounded: 300 programs of at most 30 steps (75 in the quick
run, tests/tiers.py), and the same programs whichever other modules share the process (see
``_pinned_constants``).
"""

from __future__ import annotations

from collections import Counter

import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st
from hypothesis.stateful import (
    RuleBasedStateMachine,
    initialize,
    invariant,
    rule,
    run_state_machine_as_test,
)

from mcp_conform.reference_impl import (
    DeliveryConfirmed,
    DeliveryFailed,
    Endpoint,
    MessageDelivered,
)
from mcp_conform.spec.codec import BROADCAST_ID, Action, DecodeError, MissionItem, decode
from tests.reference_impl.helpers import Link
from tests.tiers import examples

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


#: Everything pinned here, on the built-in default profile, so that no profile loaded or
#: registered by another module can change what runs. derandomize=True: the programs are a
#: function of this class's source; it implies database=None (no replay of failures saved
#: by earlier runs, which would make the outcome depend on history).
SETTINGS = settings(
    settings.get_profile("default"),
    max_examples=300, stateful_step_count=30, derandomize=True, database=None,
    deadline=None, report_multiple_bugs=True,
    suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])


@pytest.fixture
def _pinned_constants(monkeypatch):
    """Hide the literals of other loaded modules from Hypothesis' generator.

    Why the outcome depended on the other test modules in the process (``-n 2`` over
    tests/reference_impl and tests/spec failed, this file alone passed): Hypothesis >= 6.131
    sometimes (p = 0.05 per draw) draws one of the constants found in the source of every
    *local, non-test* module in ``sys.modules`` (hypothesis.internal.conjecture.providers.
    _get_local_constants). Collecting tests/spec and tests/reference_impl imports spec.*,
    conformance.*, captures.*, ... and so changes that pool, and with it the programs a
    derandomized run generates, though every setting is the same. Here the pool is pinned
    to empty (and the per-constraint cache emptied) for this test. Private API: if a
    Hypothesis release moves it, the test still runs, only without this pinning.
    """
    try:
        from hypothesis.internal.conjecture import providers
        from hypothesis.internal.constants_ast import Constants
        cache = providers.CONSTANTS_CACHE.cache
        providers._get_local_constants  # noqa: B018 - probe that the private API exists
    except (ImportError, AttributeError):  # pragma: no cover - another Hypothesis version
        yield
        return
    empty = Constants()
    monkeypatch.setattr(providers, "_get_local_constants", lambda: empty)
    cache.clear()
    yield
    cache.clear()  # entries computed from the empty pool must not serve later tests


@pytest.mark.parametrize("count", examples(full=300, quick=75))
def test_two_endpoints_over_lossy_link(_pinned_constants, count):
    run_state_machine_as_test(TwoEndpointsOverLossyLink, settings=settings(SETTINGS, max_examples=count))


# Programs Hypothesis once found when other modules' constants reached its generator (the
# endpoint then judged duplicates against the *last* delivered seq, so a copy of seq n
# arriving after a late n-1 was delivered again). "B": the manager broadcasts
# START_MISSION; "U": it unicasts START_MISSION to the drone; a float: time passes.
REGRESSIONS = [
    (dict(seed=3141, drop=0.3, duplicate=0.2, reorder=0.3), ["B"] * 11 + ["U"] * 2 + [2.0] + ["B"] * 7),
    (dict(seed=16777215, drop=0.1, duplicate=0.0, reorder=0.3), ["B"] * 17 + ["U"]),
    (dict(seed=1, drop=0.3, duplicate=0.0, reorder=0.3), ["B"] * 10 + ["U"] * 2 + [3.0]),
    (dict(seed=0, drop=0.3, duplicate=0.0, reorder=0.3), ["B"] * 10 + ["U"] * 2 + [2.0]),
    (dict(seed=19210, drop=0.0, duplicate=0.2, reorder=0.3), ["B"] * 5 + [1.0]),
]


@pytest.mark.parametrize(("link", "steps"), REGRESSIONS, ids=[str(r[0]["seed"]) for r in REGRESSIONS])
def test_regression_programs(link, steps):
    """Replay each program step by step, checking every invariant after each step."""
    machine = TwoEndpointsOverLossyLink()
    invariants = [machine.no_duplicate_delivery, machine.retransmissions_repeat_seq_and_bytes,
                  machine.stop_and_wait, machine.at_most_one_outcome]
    machine.setup(seq0=0, seq1=0, **link)
    for step in steps:
        if step == "B":
            machine.manager_broadcasts(action=Action.START_MISSION)
        elif step == "U":
            machine.send_unicast(sender=0, action=Action.START_MISSION, retries=None)
        else:
            machine.time_passes(dt=step)
        for check in invariants:
            check()
    machine.teardown()

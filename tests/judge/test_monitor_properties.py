"""Property tests of the trace monitor: THE guard against false alarms on field captures.

A clean conversation (any challenge, any drones, any initial numbers, receivers that miss
copies, ACKs lost on the way) raises nothing on a complete trace; the same conversation
with any datagrams missing from the capture raises nothing on a lossy one.
"""

from __future__ import annotations

import random

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from tests.judge.monitor_scripts import Script


@st.composite
def conversations(draw: st.DrawFn) -> Script:
    n = draw(st.integers(1, 3))
    drones = tuple(draw(st.lists(st.integers(1, 0xFFFE), min_size=n, max_size=n, unique=True)))
    challenge = draw(st.integers(1, 3))
    seqs = {node: draw(st.integers(0, 0xFFFF)) for node in (0, *drones)}
    rng = random.Random(draw(st.integers(0, 2**32)))
    ack_numbers = draw(st.booleans())
    misses = draw(st.booleans())

    def vary() -> dict[str, object]:
        if not misses:
            return {"ack_delay": rng.uniform(0.001, 0.02)}
        return {"deaf": rng.choice((0, 0, 0, 1, 2, 3)), "lost_acks": rng.choice((0, 0, 1, 2)),
                "ack_delay": rng.uniform(0.001, 0.02)}
    s = Script(drones, challenge=challenge, seqs=seqs, ack_numbers=ack_numbers, vary=vary,
               rto=draw(st.sampled_from((0.2, 1.0, 5.0))))
    s.mission(passthrough=draw(st.booleans()))
    return s


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(conversations())
def test_a_clean_conversation_raises_nothing_on_a_complete_trace(s):
    assert [(v.rule, v.node, v.actual) for v in s.judge(complete=True)] == []


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(conversations(), st.data())
def test_a_capture_that_misses_datagrams_raises_nothing(s, data):
    loss = data.draw(st.sampled_from((0.05, 0.3, 0.7)))
    rng = random.Random(data.draw(st.integers(0, 2**32)))
    kept = [r for r in s.records if r.event is not None or rng.random() >= loss]
    declare = data.draw(st.booleans())
    assert [(v.rule, v.node, v.actual) for v in s.judge(records=kept, complete=False, declare=declare)] == []

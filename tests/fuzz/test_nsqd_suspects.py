"""A death's suspects (issue 36): the cases the process was sent before its cause showed on
stderr, not the last two the campaign wrote. A real backend's abort was seen a case or two late
(its death shows at a later write or read), the two cases after the culprit were replayed, and
the crash "did not reproduce"; a replay of the wrong case waited 2 s each time."""

from __future__ import annotations

import collections

from mcp_conform.fuzz.nsqd_backend import REPLAY_DEATH_S, Backend, Hit
from mcp_conform.fuzz.nsqd_mutators import Case, Write
from mcp_conform.fuzz.nsqd_oracles import Signature

CRASH = Signature("crash", "abort: uncaught std::invalid_argument")


def _backend(sent: list[tuple[float, str]]) -> tuple[Backend, list[Case]]:
    b = object.__new__(Backend)
    cases = [Case(kind, (Write(kind.encode()),)) for _, kind in sent]
    b.history = collections.deque(((t, c) for (t, _), c in zip(sent, cases, strict=True)), maxlen=64)
    return b, cases


def test_the_cases_sent_after_the_cause_are_not_suspects():
    b, cases = _backend([(10.0, "valid"), (10.5, "number-text"), (10.52, "rst-mid-frame"), (10.6, "valid")])
    suspects, wait = b.suspects(Hit(CRASH, "", at=10.51, suspects=2), cases[-2:])
    assert [c.kind for c in suspects] == ["valid", "number-text"]
    assert wait == 1.0  # four times its 10 ms latency, at least 1 s


def test_a_slow_cause_waits_longer_and_never_past_the_bound():
    b, cases = _backend([(0.0, "valid"), (1.0, "gpx-size")])
    assert abs(b.suspects(Hit(CRASH, "", at=1.3), cases)[1] - 1.2) < 1e-9
    assert b.suspects(Hit(CRASH, "", at=5.0), cases)[1] == REPLAY_DEATH_S


def test_without_a_cause_time_the_latest_cases_as_before():
    b, cases = _backend([(0.0, "valid"), (1.0, "number-text"), (2.0, "batched")])
    suspects, wait = b.suspects(Hit(CRASH, "", suspects=2), cases)
    assert [c.kind for c in suspects] == ["number-text", "batched"] and wait == REPLAY_DEATH_S
    close = Hit(Signature("close", "valid", (), "NSQD-FRM-5"), "", at=1.5, suspects=2)
    assert [c.kind for c in b.suspects(close, cases)[0]] == ["number-text", "batched"]  # not a death: as before

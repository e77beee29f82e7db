"""``fuzz.campaign_core``, the campaign every protocol runs (issue 39): what its stateless
engine keeps of the cases it sent."""

from __future__ import annotations

import time

from mcp_conform.fuzz.campaign_core import CaseEngine


def test_a_case_engine_keeps_the_cases_it_sent_with_their_times_when_asked():
    """``fuzz.campaign_core.CaseEngine``'s ``history``: the last N cases sent, each stamped
    before its send (a hit's suspects); none kept by default."""
    class Count(CaseEngine):
        def __init__(self, history: int) -> None:
            super().__init__(None, seed=1, history=history)
            self.n, self.seen = 0, []

        def draw(self):
            self.n += 1
            return self.n

        def tried(self, case):
            return "k", ("m",)

        def send(self, case):
            self.seen.append(len(self.sent))
            return None

    e = Count(3)
    t0 = time.monotonic()
    e.run(time.monotonic() + 5.0, 5, None, lambda: False)
    assert [c for _, c in e.sent] == [3, 4, 5] and all(t0 <= t <= time.monotonic() for t, _ in e.sent)
    assert e.seen == [1, 2, 3, 3, 3]  # each stamped before it was sent
    none = Count(0)
    none.run(time.monotonic() + 5.0, 2, None, lambda: False)
    assert list(none.sent) == [] and none.n == 2


def test_a_hits_suspects_are_the_cases_kept_in_a_window_or_the_last_n():
    """``CaseEngine.taken``: the cases kept sent within a time window, or the last N, oldest
    first; then none kept (the next hit's suspects start afresh). ``send``: the worker's
    target's current one runs the case."""
    class Current:
        def run(self, case):
            return f"hit {case}"

    class Target:
        current = Current()

    e = CaseEngine(None, seed=1, history=10, target=Target())
    for i in range(6):
        e.sent.append((10.0 + i, i))
    assert e.taken(12.0, 14.0) == [2, 3, 4] and list(e.sent) == []
    for i in range(6):
        e.sent.append((10.0 + i, i))
    assert e.taken(last=2) == [4, 5] and e.taken() == []
    assert e.send("c") == "hit c"

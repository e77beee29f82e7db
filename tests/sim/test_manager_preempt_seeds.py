"""Regression seeds: the correct manager under the runner's threads preempted mid-step
(``sim.manager_runner.Preemption``) gets no failed or warned verdict (issue 38's property).

Each seed below gave the reference manager a false verdict from the run's monitor before its
fix, all from one cause: a runner thread taken off the CPU between a datagram's stamp and
telling the observers tells it late, and the manager role's run monitor
(``judge.run_monitor.SessionMonitors``) judged the datagrams in the order they were told:

- seed 110 of ``preempt=(0.3, 0.3)``: the receiver thread, behind by 0.28 s, read the main
  manager's last End_Mission (to drone 3), then its copy, and ACKed both after the manager
  had exited and the silent drone's scenario's session had begun; the copy was judged there,
  a command to drone 3 after its End_Mission in that session (MCP-BLK-6) numbered out of that
  manager's turn (MCP-SEQ-1). The datagrams now go to the session their stamps fall in.
- seed 118 of ``preempt=(0.3, 0.3)``: the case thread's ACK of the withheld Start_Mission's
  copy was told 195 ms after it left, and the monitor, holding datagrams 100 ms to put them
  in order, had fed the manager's next Start_Mission (0.1 ms after the ACK) before it: a
  second unicast before the first's ACK (MCP-BLK-1). A session's monitor now holds them until
  it is read.

Each test also checks that its seed still makes the schedule it is kept for (a probe on the
monitor's interface, the same on the judge before the fix), or it would pass for nothing.
tests/judge/test_session_stamps.py holds the same two tellings on scripted missions.
"""

from __future__ import annotations

import pytest

from mcp_conform.judge.run_monitor import REORDER_NS, SessionMonitors
from mcp_conform.sim.manager_runner import MANAGER_ADDR, run_manager_cases

SHORT = {"rto": 0.2, "ack_window": 0.25}

#: (seed, preempt, challenge, the schedule it is kept for)
SEEDS = [
    (110, (0.3, 0.3), 1, "told after the next session began"),
    (110, (0.3, 0.3), 3, "told after the next session began"),
    (118, (0.3, 0.3), 1, "told past the hold"),
    (118, (0.3, 0.3), 2, "told past the hold"),
]


@pytest.fixture
def told(monkeypatch):
    """What the runner told the run's monitor, in the order told: ("begin", name) and
    ("obs", stamp, peer address)."""
    events: list[tuple] = []
    begin, observe = SessionMonitors.begin, SessionMonitors.observe

    def begin_probe(self, name, *args, **kw):
        events.append(("begin", name))
        return begin(self, name, *args, **kw)

    def observe_probe(self, direction, data, addr, t_ns, *args, **kw):
        events.append(("obs", t_ns, tuple(addr)))
        return observe(self, direction, data, addr, t_ns, *args, **kw)

    monkeypatch.setattr(SessionMonitors, "begin", begin_probe)
    monkeypatch.setattr(SessionMonitors, "observe", observe_probe)
    return events


def _main_told_after_next_session(events: list[tuple]) -> int:
    """How many of the main manager's datagrams (its address) were told after another
    session had begun."""
    begins = [i for i, e in enumerate(events) if e[0] == "begin"]
    if len(begins) < 2:
        return 0
    return sum(1 for e in events[begins[1]:] if e[0] == "obs" and e[2] == MANAGER_ADDR)


def _told_past_the_hold(events: list[tuple]) -> int:
    """How many datagrams were told after one stamped more than ``REORDER_NS`` after them."""
    newest, n = None, 0
    for e in events:
        if e[0] == "obs":
            if newest is not None and e[1] < newest - REORDER_NS:
                n += 1
            newest = e[1] if newest is None else max(newest, e[1])
    return n


@pytest.mark.parametrize(("seed", "preempt", "challenge", "schedule"), SEEDS,
                         ids=[f"seed{s}-p{p[0]}-{p[1]}-c{c}" for s, p, c, _ in SEEDS])
def test_the_correct_manager_preempted_gets_no_verdict(told, seed, preempt, challenge, schedule):
    run = run_manager_cases(None, seed=seed, challenge=challenge, preempt=preempt, **SHORT)
    late = (_main_told_after_next_session(told) if schedule == "told after the next session began"
            else _told_past_the_hold(told))
    assert late > 0 and run.preemptions > 0, f"seed {seed}: no datagram {schedule} (not the race it is kept for)"
    assert not run.rules_with("failed", "warned"), run.explain()
    assert not [c for c in run.report["cases"] if c["outcome"] in ("failed", "warned", "error")], run.explain()
    monitor = run.report["monitor"]
    assert monitor["violations"] == [], monitor["violations"]
    assert not {r: o for r, o in monitor["rules"].get("0", {}).items() if o in ("failed", "warned")}

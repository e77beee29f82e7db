"""Regression seeds: the correct manager under the runner's threads preempted mid-step
(``sim.manager_runner.Preemption``) gets no failed or warned verdict (issue 38's property).
Every seed here gave the reference manager a false verdict on the judge and cases before
(1d84803); each test first checks that its seed still makes the schedule it is kept for (a
probe on interfaces the old code has too), or it would pass for nothing.

A runner thread taken off the CPU between a datagram's stamp and telling the observers tells
it late, and the manager role's run monitor (``judge.run_monitor.SessionMonitors``) judged
the datagrams in the order they were told:

- seed 118 of ``preempt=(0.3, 0.3)``: the case thread's ACK of the withheld Start_Mission's
  copy was told 195 ms after it left, and the monitor, holding datagrams 100 ms to put them
  in order, had fed the manager's next Start_Mission (0.1 ms after the ACK) before it: a
  second unicast before the first's ACK (MCP-BLK-1). A session's monitor now holds them until
  it is read.
- seeds 110 and 249 of ``(0.3, 0.3)``: the main manager's last End_Mission copy, and the
  runner's ACKs of it, told after the silent drone's scenario's session had begun, were
  judged there: a command to a drone after its End_Mission in that session (MCP-BLK-6)
  numbered out of that manager's turn (MCP-SEQ-1). The datagrams now go to the session their
  stamps fall in. In seed 110 the copy sat unread in the socket as the manager exited: the
  main record now ends once the receiver has read it (below), so the session's boundary is
  no longer crossed there; seed 249 crosses it still (an ACK told late, nothing unread).

Where the runner's receiver thread fell seconds behind (stalls of up to 3 times --rto at each
of its steps, ``preempt=(0.3, 0.6)`` and ``(0.5, 0.5)``; the arrival stamps stay the kernel's):

- seeds 18 and 7 of ``(0.5, 0.5)``: the manager ended its mission and exited while its last
  commands sat unread in the runner's socket; the mission record ended at once without them:
  "no End_Mission to drone(s) [..]" (MCP-FLOW-3; FLOW-5: its WP_Ons). The record now ends
  once the receiver has read what the socket holds (``MissionScript._await_end``).
- seed 26 of ``(0.3, 0.6)``, seed 2 of ``(0.5, 0.5)``: the manager gave up a drone's command
  at its retry limit (13 copies, then a new unicast to another drone) and the runner's ACK
  came seconds after; the monitor took the drone for one whose last command was ACKed and
  failed MCP-FLOW-3 for its missing End_Mission (the case excused it: ``gave_up``). The
  monitor now excuses a drone its manager gave up at the retry limit before the ACK came
  (``F_GAVE_UP``), as it did one given up short of MCP-RTX-1's copies.
- seed 73 of ``(0.5, 0.5)``: the same give-up of a drone's last WP_Off, ACKed 0.28 s after its
  13th copy (at --rto 0.2), the manager then done and exited: the case took the ACK for one
  the manager may have had (it allowed 1.5 gaps) and failed MCP-FLOW-3 and FLOW-5 for that
  drone. An ACK after the next copy was due, none following, now leaves the give-up as one
  explanation (``conformance.manager_case.gave_up``).
- seed 90 of ``(0.3, 1.0)`` (the receiver 7 s behind): MCP-RTX-2's wrong-source ACK from drone
  2, sent while drone 1's Start_Mission was withheld, was dated drone 2's answer to its
  Start_Mission (a manager taking any ACK from the destination takes it when it next sends
  there), though the manager sent that Start_Mission 13 times after it and gave it up: drone
  2 looked answered and its missing WP_List and End_Mission failed MCP-FLOW-4 and FLOW-3. A
  wrong ACK is no answer of a command retransmitted after it
  (``conformance.manager_case.runner_ack_time``).

tests/judge/test_session_stamps.py and test_flow3_given_up.py hold the monitor's two on
scripted missions.
"""

from __future__ import annotations

import pytest

from mcp_conform.conformance.manager_case import messages, runner_ack_time
from mcp_conform.judge.run_monitor import REORDER_NS, SessionMonitors
from mcp_conform.sim.manager_runner import MANAGER_ADDR, SimManagerSession, run_manager_cases

SHORT = {"rto": 0.2, "ack_window": 0.25}

#: (seed, preempt, challenge, the schedule it is kept for)
SEEDS = [
    (33, (0.3, 0.3), 1, "unread as the manager exited"),
    (32, (0.3, 0.3), 2, "unread as the manager exited"),
    (21, (0.3, 0.3), 3, "told after the next session began"),
    (2, (0.3, 0.3), 2, "told past the hold"),
    (118, (0.3, 0.3), 2, "told past the hold"),
    (34, (0.5, 0.5), 1, "unread as the manager exited"),
    (7, (0.5, 0.5), 2, "unread as the manager exited"),
    (26, (0.3, 0.6), 2, "ACKed after the manager gave up"),
    (2, (0.5, 0.5), 1, "ACKed after the manager gave up"),
    (73, (0.5, 0.5), 2, "ACKed after the manager gave up"),
]
#: copies a command had when the manager gave it up in the seeds above (the reference
#: manager's retry limit, ``EMBEDDED_RETRIES`` + 1)
GIVE_UP_COPIES = 13


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
    alive = SimManagerSession.alive

    def alive_probe(self):
        up = alive(self)
        if not up:
            events.append(("exited", self.backlog()()))
        return up

    monkeypatch.setattr(SimManagerSession, "alive", alive_probe)
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


def _unread_as_exited(events: list[tuple]) -> bool:
    """Whether the runner's socket held unread datagrams when the main scenario's manager
    was first seen to have exited."""
    return next((e[1] for e in events if e[0] == "exited"), False)


def _acked_after_give_up(m) -> int:
    """How many commands of the mission the manager gave up at its retry limit (that many
    copies, the last one's timer run out) before the runner's first ACK of it."""
    n = 0
    for x in messages(m):
        acked = runner_ack_time(m, x)
        n += len(x.copies) >= GIVE_UP_COPIES and acked is not None and acked > x.last.t + SHORT["rto"]
    return n


def _wrong_ack_then_copies(m) -> int:
    """How many commands to a drone were retransmitted after one of MCP-RTX-2's deliberate
    wrong ACKs from that drone (sent before the command or while it awaited its ACK), and
    given up at the retry limit."""
    n = 0
    for x in messages(m):
        wrong = [a for a in m.withheld.wrong_acks if a.src == x.dst]
        n += bool(wrong) and len(x.copies) >= GIVE_UP_COPIES and any(
            c.t > max(a.t, x.first.t) for a in wrong for c in x.copies)
    return n


@pytest.mark.parametrize(("seed", "preempt", "challenge", "schedule"), SEEDS,
                         ids=[f"seed{s}-p{p[0]}-{p[1]}-c{c}" for s, p, c, _ in SEEDS])
def test_the_correct_manager_preempted_gets_no_verdict(told, seed, preempt, challenge, schedule):
    run = run_manager_cases(None, seed=seed, challenge=challenge, preempt=preempt, **SHORT)
    late = {"told after the next session began": lambda: _main_told_after_next_session(told),
            "told past the hold": lambda: _told_past_the_hold(told),
            "unread as the manager exited": lambda: _unread_as_exited(told),
            "ACKed after the manager gave up": lambda: _acked_after_give_up(run.missions["main"]),
            "a wrong ACK before a command retransmitted": lambda: _wrong_ack_then_copies(run.missions["main"]),
            }[schedule]()
    assert late > 0 and run.preemptions > 0, f"seed {seed}: no datagram {schedule} (not the race it is kept for)"
    assert not run.rules_with("failed", "warned"), run.explain()
    assert not [c for c in run.report["cases"] if c["outcome"] in ("failed", "warned", "error")], run.explain()
    monitor = run.report["monitor"]
    assert monitor["violations"] == [], monitor["violations"]
    assert not {r: o for r, o in monitor["rules"].get("0", {}).items() if o in ("failed", "warned")}

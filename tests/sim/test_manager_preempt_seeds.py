"""Regression seeds: the correct manager under the runner's threads preempted mid-step
(``sim.manager_runner.Preemption``) gets no failed or warned verdict (issue 38's property).
Each test first checks that its seed still makes the schedule it is kept for (a probe of
what the runner told its monitor, or of the mission record), or it would pass for nothing.

Each seed below makes its race on the current runner (the probe > 0), gets no verdict, and
fails with the fix it guards reverted alone (measured on copies of the tree, figures in the
commit message), except where said. The schedules move whenever the runner's own timing
does (the s34-mgrgive and s34-silent merges moved 6 of the 11 seeds kept before): a probe
at 0 is the sign to sweep again (seeds of the same ``preempt``, the probes below).

A runner thread taken off the CPU between a datagram's stamp and telling the observers tells
it late, and the manager role's run monitor (``judge.run_monitor.SessionMonitors``) judged
the datagrams in the order they were told:

- told past the hold, seed 2 c2 of ``preempt=(0.3, 0.3)``: an ACK told after the manager's
  next unicast, stamped before it; a monitor holding datagrams 100 ms (``REORDER_NS``) fed
  them out of order: MCP-BLK-1 (seed 118 before; this one too with the hold put back). A
  session's monitor now holds them until it is read.
- told after the next session began, seed 21 c3 of ``(0.3, 0.3)``: the main manager's
  datagrams told after the silent drone's scenario's session had begun now go to the session
  their stamps fall in (they were judged there: MCP-BLK-6 + SEQ-1, seeds 110 and 249 before).
  This seed makes the race, but no seed fails with that routing alone reverted now (0 of 497
  runs with the probe > 0 of ``(0.3, 0.3)``, ``(0.5, 0.5)`` and ``(0.3, 1.0)``; the drain
  below, which leaves nothing unread as the manager exits, and a session ending at its
  instance's stop are the likely reasons, not measured). It is kept for the property alone;
  tests/judge/test_session_stamps.py holds the routing's regression.

Where the runner's receiver thread fell seconds behind (stalls of up to 3 times --rto at each
of its steps, ``preempt=(0.5, 0.5)`` and ``(0.3, 1.0)``; the arrival stamps stay the kernel's):

- unread as the manager exited, seeds 0 c2 and 20 c1 of ``(0.5, 0.5)``: the manager ended its
  mission and exited while its last commands sat unread in the runner's socket; the mission
  record ended at once without them: "no End_Mission to drone(s) [..]" (MCP-FLOW-3; FLOW-5
  or FLOW-4). The record now ends once the receiver has read what the socket holds
  (``MissionScript._await_end``).
- ACKed after the manager gave up, seeds 30 c1 and 34 c3 of ``(0.5, 0.5)`` and 26 c2 of
  ``(0.3, 0.6)``: the manager gave
  up a drone's command at its retry limit (13 copies, then a new unicast to another drone)
  and the runner's ACK came after; the monitor took the drone for one whose last command was
  ACKed and failed MCP-FLOW-3 for its missing End_Mission. The monitor now excuses a drone
  its manager gave up at the retry limit before the ACK came (``F_GAVE_UP``), as it did one
  given up short of MCP-RTX-1's copies.
- the same race, seeds 46 c2 and 73 c2 of ``(0.5, 0.5)``: a drone's last WP_Off given up at
  13 copies, ACKed a little after the 13th (at --rto 0.2), the manager then done and exited:
  the case took the ACK for one the manager may have had (it allowed 1.5 gaps) and failed
  MCP-FLOW-3 and FLOW-5 for that drone. An ACK after the next copy was due, none following,
  now leaves the give-up as one explanation (``conformance.manager_case.gave_up``).
- a wrong ACK before a command retransmitted, seeds 10 c1 and 3 c2 of ``(0.3, 1.0)``: one of
  MCP-RTX-2's deliberate wrong ACKs from a drone (now the next unicast's, ``withheld_again``:
  the runner answers the first Start_Mission's third copy as it comes) was dated that
  drone's answer to a command the manager then sent 13 times and gave up: the drone looked
  answered and its missing End_Mission failed MCP-FLOW-3 (+ FLOW-5). A wrong ACK is no
  answer of a command retransmitted after it (``conformance.manager_case.runner_ack_time``).

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
    (2, (0.3, 0.3), 2, "told past the hold"),
    (21, (0.3, 0.3), 3, "told after the next session began"),
    (0, (0.5, 0.5), 2, "unread as the manager exited"),
    (20, (0.5, 0.5), 1, "unread as the manager exited"),
    (30, (0.5, 0.5), 1, "ACKed after the manager gave up"),
    (34, (0.5, 0.5), 3, "ACKed after the manager gave up"),
    (46, (0.5, 0.5), 2, "ACKed after the manager gave up"),
    (73, (0.5, 0.5), 2, "ACKed after the manager gave up"),
    (26, (0.3, 0.6), 2, "ACKed after the manager gave up"),
    (10, (0.3, 1.0), 1, "a wrong ACK before a command retransmitted"),
    (3, (0.3, 1.0), 2, "a wrong ACK before a command retransmitted"),
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
    given up at the retry limit. The wrong ACKs of either observation (``Mission.withheld``;
    since the runner answers the first Start_Mission's third copy as it comes, the next
    unicast's: ``withheld_again`` and its spoiled tries)."""
    n = 0
    wrongs = [a for w in (m.withheld, *m.again_spoiled, m.withheld_again) for a in w.wrong_acks]
    for x in messages(m):
        wrong = [a for a in wrongs if a.src == x.dst]
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

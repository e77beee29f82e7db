"""MCP-BLK-1 on a correct manager whose runner threads are preempted mid-step (issue 38: a
false verdict seen once on a loaded host, kept as a regression seed).

The false verdict, against the sample manager at --rto 0.2 on a host with 2 cores and 12 pytest
workers: "nothing new while START_MISSION (seq 8227) to drone 1 awaits its ACK" -- "START_MISSION
(seq 8228) to drone 2 0.628 s after it, before its ACK". The cause is the runner's, not the
manager's: two of its threads answered the withheld Start_Mission's copy that came after the
wrong ACKs. The case thread, woken by that copy, released the drone and sent the right ACK; the
receiver thread, taken off the CPU between waking it and letting the drone players answer the
copy, then answered it too (released by then), 14 ms later. The manager took the first ACK and
sent the next Start_Mission; the mission's ``acks`` keeps the ACK whose thread recorded it
first, and the case thread, preempted after its ACK left, recorded its own second: the case
dated the answer by the later ACK, after the next Start_Mission had arrived. MCP-BLK-1's text
ends the wait at "its ACK": the first the runner sent (conformance.manager_case.runner_ack_time
now reads every ACK the drones sent).

``preempt`` (sim.manager_runner.Preemption) takes a runner thread off the CPU at those two
points; ``sim.stalls`` holds a thread only before it runs, where this interleaving cannot
happen. Seeds 9 and 13 of ``preempt=(0.5, 0.05)`` over the BLK cases failed MCP-BLK-1 this way
on the judge before (0 of 40 seeds after). On real sockets: 1 run of 43 (beside two CPU hogs)
showed the double answer; none of 150 showed the false verdict itself.
"""

from __future__ import annotations

import struct

import pytest

from mcp_conform.sim.manager_runner import run_manager_cases
from mcp_conform.spec.codec import HEADER_SIZE, Action

SHORT = {"rto": 0.2, "ack_window": 0.25}
PREEMPT = (0.5, 0.05)  # p, up to a quarter of --rto
#: seeds whose schedule answered the withheld Start_Mission twice, the later ACK recorded first
PREEMPT_SEEDS = [9, 13]
_ACK = int(Action.ACK)
_U16 = struct.Struct("!H")


def _answers(m, drone: int, seq: int) -> list[float]:
    """When the runner's ``drone`` sent an ACK naming ``seq`` (the wrong-source one excluded)."""
    return sorted(s.t for s in m.sent_by_drones.values()
                  if s.action == _ACK and s.src == drone and _U16.unpack_from(s.data, HEADER_SIZE)[0] == seq)


@pytest.mark.parametrize("seed", PREEMPT_SEEDS)
def test_a_start_mission_answered_twice_is_answered_by_the_first_ack(seed):
    run = run_manager_cases(None, seed=seed, challenge=1 + seed % 3, preempt=PREEMPT, select=["MCP-BLK"], **SHORT)
    # the schedule is the one the seed was kept for: the withheld Start_Mission answered twice,
    # the manager's next unicast between the two ACKs, the later ACK the one ``acks`` holds
    m = run.missions["main"]
    w = m.withheld
    assert w.right_ack is not None and w.copy_after_wrong_acks is not None, run.explain()
    seq = _U16.unpack_from(w.right_ack.data, HEADER_SIZE)[0]
    answers = _answers(m, w.drone, seq)
    nxt = min(d.t for d in m.commands() if d.t > w.right_ack.t and d.header is not None and d.header[0] != w.drone)
    assert len(answers) == 2 and answers[0] < nxt < answers[1], (answers, nxt)
    assert m.acks[(w.drone, seq)].t == answers[1], "the later ACK recorded first: the race this seed is kept for"
    # judged on the first ACK: no MCP-BLK-1 (nor any other verdict) on a correct manager
    assert run.rules["MCP-BLK-1"] == "passed", run.explain()
    assert not run.rules_with("failed", "warned"), run.explain()
    assert not {r: o for r, o in run.report["monitor"]["rules"].get("0", {}).items() if o in ("failed", "warned")}
    assert run.preemptions > 0

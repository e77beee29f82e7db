"""MCP-RTX-2's observation on the next new unicast (``DronePlayers.arm_again``) is not ended by
the runner while the receiver thread is sending its wrong ACKs (simulator seed 176 of
``preempt=(0.3, 0.3)``, the correct manager; a false MCP-RTX-2 at challenges 1-3 on 70f0eef).

The receiver thread sends the two wrong ACKs after the held message's second copy and records
them once both have left. Taken off the CPU between them, the record read "no wrong ACKs, no
second copy" to the case thread, whose ``MissionScript._settle_again`` found a first try (drone
2's Start_Mission) overdue by its first copy, drained the socket while the receiver went on,
spoiled that try and began the next (drone 3's Start_Mission), and then released whatever was
held: drone 3's right ACK went out between ITS two wrong ACKs, before its third copy was due, the
correct manager moved on, and "no copy within 0.70 s after them" failed MCP-RTX-2. Now the
observation is not overdue while its wrong ACKs are on their way, and the script ends only the
one it found overdue (``DronePlayers.again_overdue``, ``release_again(held=...)``); and the case
calls the observation void (Inconclusive) where the right ACK went out before the window after
the wrong ACKs ended, whoever sent it. So that a manager that takes a wrong ACK still fails
MCP-RTX-2, the record no longer ends in the middle of the observation either
(``MissionScript._end_again``: the sim's wrong-seq-ack at seed 2 ended its mission 0.40 s after the
wrong ACKs, tests/sim/test_manager_limit_sim.py).
"""

from __future__ import annotations

import pytest

from mcp_conform.conformance._case_base import CaseBase
from mcp_conform.conformance.cases_manager import test_rtx
from mcp_conform.harness.driver import Datagram, Sent, read_header
from mcp_conform.harness.drone_players import Mission, Withheld
from mcp_conform.harness.errors import CaseFailure, Inconclusive
from mcp_conform.sim.manager_runner import run_manager_cases
from mcp_conform.spec.codec import PREAMBLE, Action, Message, encode

SHORT = {"rto": 0.2, "ack_window": 0.25}
SEED, PREEMPT = 176, (0.3, 0.3)
ADDR = ("127.0.0.1", 7889)


def _tries(m: Mission) -> list[Withheld]:
    return [*m.again_spoiled, m.withheld_again]


def _runner_acks(m: Mission, w: Withheld) -> list[float]:
    """When the runner ACKed the held message of ``w`` (its right ACK, and the earliest of
    ``Mission.acks`` for it), after its first copy."""
    seq = w.copies[0].header[2]  # type: ignore[index]
    return [s.t for s in (w.right_ack, m.acks.get((w.drone, seq))) if s is not None and s.t >= w.copies[0].t]


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_the_right_ack_never_goes_out_before_the_observation_is_over(challenge):
    run = run_manager_cases(None, seed=SEED, challenge=challenge, preempt=PREEMPT, **SHORT)
    m = run.missions["main"]
    tries = [w for w in _tries(m) if w.drone is not None and w.copies]
    # the schedule the seed is kept for: the receiver taken off the CPU between a try's two wrong ACKs
    split = [w for w in tries if len(w.wrong_acks) == 2 and w.wrong_acks[1].t - w.wrong_acks[0].t > SHORT["rto"] / 2]
    assert split and run.preemptions > 0, f"seed {SEED} c{challenge}: no wrong ACKs split (not the race it is kept for)"
    for w in tries:
        if not w.wrong_acks:
            continue
        for t in _runner_acks(m, w):
            # never between or before its wrong ACKs (a spoiled try is answered once they left)
            assert t >= w.wrong_acks[-1].t, (w.drone, t, [s.t for s in w.wrong_acks])
            # the observation kept: nor before the window after them ended, unless a copy came
            # in it (answered as it arrives)
            if w is m.withheld_again:
                assert w.copy_after_wrong_acks is not None or t > w.wrong_acks[0].t + w.wrong_ack_wait, (w.drone, t)
    assert not run.rules_with("failed", "warned"), run.explain()
    assert run.rules["MCP-RTX-2"] in ("passed", "skipped"), run.explain()


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_a_manager_that_takes_a_wrong_ack_still_fails_rtx_2_on_that_seed(challenge):
    run = run_manager_cases("wrong-seq-ack", seed=SEED, challenge=challenge, preempt=PREEMPT, **SHORT)
    assert run.rules["MCP-RTX-2"] == "failed", run.explain()


# ------------------------------------------------------------------ the case, on a record
def _copy(i: int, drone: int, seq: int, t: float) -> Datagram:
    data = encode(Message(drone, 0, seq, Action.START_MISSION))
    return Datagram(i, t, int(t * 1e9), data, ADDR, None, None, read_header(data), data[:9] == PREAMBLE)


def _ack(drone: int, seq: int, t: float) -> Sent:
    return Sent(t, int(t * 1e9), encode(Message(0, drone, 5000 + int(t * 1000), Action.ACK, seq)), ADDR, 0,
                drone, 5000, int(Action.ACK))


def _record(right_at: float) -> Mission:
    """The first Start_Mission to drone 1 in 3 copies, its third answered; drone 3's held in
    2 copies (2.0, 2.2), its wrong ACKs at 2.37 and 2.55, no copy after them, its right ACK at
    ``right_at`` (0.70 s watched after the first wrong ACK)."""
    m = Mission("main", (1, 2, 3), 1, None, None, t0=0.0, t_end=5.0)
    m.withheld = Withheld(copies=[_copy(k, 1, 100, 1.0 + 0.2 * k) for k in range(3)], drone=1)
    m.withheld.right_ack = _ack(1, 100, 1.401)
    a = Withheld(copies=[_copy(3, 3, 101, 2.0), _copy(4, 3, 101, 2.2)], wrong_ack_wait=0.7, drone=3)
    a.wrong_acks = [_ack(3, 101 + 0x8000, 2.37), _ack(2, 101, 2.55)]
    a.right_ack = _ack(3, 101, right_at)
    m.acks[(3, 101)] = a.right_ack
    m.withheld_again = a
    return m


def _judge(m: Mission) -> str:
    class Node(CaseBase):
        def mission(self, kind: str = "main") -> Mission:
            return m

    try:
        test_rtx.test_only_the_right_ack_ends_retransmission(Node(None, "RTX-2", ("MCP-RTX-2",)))
    except CaseFailure as exc:
        return f"failed {exc.rule}"
    except Inconclusive as exc:
        return f"inconclusive: {exc}"
    return "passed"


def test_the_case_calls_the_observation_void_where_the_right_ack_went_out_in_the_window():
    """The right ACK between the wrong ACKs (seed 176's record): no copy after them shows
    nothing (a correct manager stops at the right ACK); sent after the window, the same record
    is a taken wrong ACK."""
    void = _judge(_record(2.40))
    assert void.startswith("inconclusive: MCP-RTX-2:") and "answered 0.03 s after the first wrong ACK" in void, void
    assert _judge(_record(3.10)) == "failed MCP-RTX-2"

"""Verdicts do not depend on the schedule (issue 23): the same outcome for every case, run
``--serial`` and scheduled (``conformance.schedule``: the batch of windows), against the
reference node, correct sample nodes unlike it and faulty ones whose faults fall in the
batch (a reply a silence probe draws, an ACK in the wrong form or missing for a copy, a
crash on a malformed input, a duplicate delivered, new bytes taken for a duplicate, a frame
forwarded twice or truncated), in the startup (retransmission stopped by a wrong
ACK, arming before Start_Mission) and beside it (slow ACKs).

Each node is run once ``--serial`` and ``MCP_SCHEDULE_RUNS`` times scheduled (default 1: a
run's CPU second is what CI's two cores run short of; more by hand, the issue's 20:
``MCP_SCHEDULE_RUNS=20 python -m pytest -n 2 -m slow tests/conformance/test_schedule_verdicts.py``),
each scheduled run compared case by case. The runs of a node go at once
(``serial_and_scheduled``): each spawns its own node on its own ports, and they only wait on
the node's timers.

Most of these nodes are test_mutants' nodes too, which runs each of them scheduled, with the
same node and runner options, to check the fault's rule: those (``FOLDED``) are compared
there, in the same test, its scheduled run being the first of the ``MCP_SCHEDULE_RUNS``
(``test_every_node_is_compared_here_or_in_test_mutants``), not run a second time here. At
``MCP_MUTANTS_TIMING=real`` test_mutants runs other timings, and every node is compared here.
The mutants test_mutants leaves to the simulator (``SIM_COVERS``) are compared there, serial
against scheduled on virtual time (tests/sim/test_mutants_sim.py).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import pytest

from .runner_helpers import (
    FAST,
    RunResult,
    reference_node_command,
    run_conform,
    sample_node_command,
)

pytestmark = pytest.mark.slow

RUNS = int(os.environ.get("MCP_SCHEDULE_RUNS", "1"))
#: Runs of one node at once (``MCP_SCHEDULE_RUNS=20`` does not start 21 nodes together).
AT_ONCE = 3

NODES = [
    ("reference", None),
    ("sample", ()),
    ("acks-only-in-receive-loop", ("--ack-mode", "recv-loop")),
    ("ack-broadcast", ("--fault", "ack-broadcast")),
    ("ack-other-id", ("--fault", "ack-other-id")),
    ("ack-ack", ("--fault", "ack-ack")),
    ("ack-bad-preamble", ("--fault", "ack-bad-preamble")),
    ("ack-unknown-action", ("--fault", "ack-unknown-action")),
    ("ack-bad-length", ("--fault", "ack-bad-length")),
    ("ack-little-endian", ("--fault", "ack-little-endian")),
    ("ack-first-copy-only", ("--fault", "ack-first-copy-only")),
    ("ack-copies-wrong-seq", ("--fault", "ack-copies-wrong-seq")),
    ("ack-previous-seq", ("--fault", "ack-previous-seq")),
    ("ack-wrong-dst", ("--fault", "ack-wrong-dst")),
    ("dup-by-content", ("--fault", "dup-by-content")),
    ("crash-on-short", ("--fault", "crash-on-short")),
    ("no-dup-discard", ("--fault", "no-dup-discard")),
    ("passthrough-twice", ("--fault", "passthrough-twice")),
    ("passthrough-truncated", ("--fault", "passthrough-truncated")),
    ("forwards-no-passthrough", ("--no-passthrough",)),
    ("arm-before-start", ("--fault", "arm-before-start")),
    ("rtx-stop-on-any-ack", ("--fault", "rtx-stop-on-any-ack")),
    ("slow-ack", ("--fault", "slow-ack")),
]

#: The nodes compared in test_mutants (its mutants' and correct variants' node arguments).
FOLDED: dict[tuple[str, ...], str] = (
    {} if os.environ.get("MCP_MUTANTS_TIMING", "short") == "real"
    else {args: label for label, args in NODES if label not in ("reference", "sample")})
HERE = [(label, args) for label, args in NODES if args not in FOLDED]


def serial_and_scheduled(spawn: str, *runner: str, first: tuple[str, ...] = (),
                         timeout: float = 300) -> tuple[RunResult, list[RunResult]]:
    """``spawn``'s node run once ``--serial`` and ``RUNS`` times scheduled, at once: (the serial
    run, the scheduled runs); ``first``: more options of the first scheduled run."""
    base = ("--spawn", spawn, "--mavlink", *runner)
    argsets = [(*base, "--serial"), (*base, *first)] + [base] * (RUNS - 1)
    with ThreadPoolExecutor(max_workers=min(AT_ONCE, len(argsets))) as pool:
        serial, *scheduled = pool.map(lambda args: run_conform(*args, timeout=timeout), argsets)
    return serial, scheduled


def _outcomes(res: RunResult) -> dict[str, str]:
    return {c["id"]: c["outcome"] for c in res.report.get("cases", [])}


def assert_same_verdicts(serial: RunResult, scheduled: list[RunResult]) -> None:
    """Every scheduled run gives each case the serial run's outcome, and the same exit code."""
    assert serial.report.get("schedule", {}).get("mode") == "serial", serial.explain()
    want = _outcomes(serial)
    assert want, serial.explain()
    for n, res in enumerate(scheduled):
        plan = res.report.get("schedule", {})
        assert plan.get("mode") == "scheduled", (plan, res.explain())
        got = _outcomes(res)
        diff = {c: (want.get(c), got.get(c)) for c in sorted(set(want) | set(got)) if want.get(c) != got.get(c)}
        assert not diff, (f"run {n + 1}: serial vs scheduled differ: {diff}; batch: {plan['batch_outcome']}\n"
                          + res.explain())
        assert res.rc == serial.rc, res.explain()


@pytest.mark.parametrize("label,node_args", HERE, ids=[n for n, _ in HERE])
def test_serial_and_scheduled_give_the_same_verdicts(label, node_args, tmp_path):
    """And for a node test_parallel folds here (``IN_SCHEDULE``: the reference node; the sample
    node's is test_parallel.ELSEWHERE's), its ``--parallel 3`` run at once beside them, every
    case the outcome of the first scheduled run (that is ``--parallel 1``)."""
    from .test_parallel import IN_SCHEDULE, assert_three_agree_with_one, three_instances

    spawn = reference_node_command() if node_args is None else sample_node_command(*node_args)
    with ThreadPoolExecutor(max_workers=1) as beside:
        three = (beside.submit(run_conform, *three_instances(spawn, tmp_path), timeout=300)
                 if node_args in IN_SCHEDULE else None)
        serial, scheduled = serial_and_scheduled(spawn, *FAST)
        assert_same_verdicts(serial, scheduled)
        if three is not None:
            assert_three_agree_with_one(scheduled[0], three.result(), tmp_path)


def test_every_node_is_compared_here_or_in_test_mutants():
    """A node folded into test_mutants is one of its nodes there, with the same arguments
    (the sample node's defaults, ``--rto 0.2``, the runner's FAST timings), and compared."""
    from . import test_mutants

    assert test_mutants.RUNNER == FAST and test_mutants.NODE_RTO == 0.2 or not FOLDED
    theirs = {("--fault", f) for f, _ in test_mutants.MUTANTS} | {a for _, a in test_mutants.CORRECT_VARIANTS}
    assert set(FOLDED) <= theirs, set(FOLDED) - theirs
    assert {label for label, _ in HERE} | set(FOLDED.values()) == {label for label, _ in NODES}

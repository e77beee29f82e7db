"""A manager whose every ACK names the acknowledged message's seq + 1, in the simulator: the
fault of the C++ manager of examples/mcp_cpp/manager built ``FAULT=ACK_WRONG_SEQ``, as a model
(the reference endpoint, its ACK handler changed; not in sim.manager_faults: no sample manager
has it), so that its verdicts are checked in a second of CPU instead of a C++ build and a run
on real sockets (tests/examples/test_cpp_manager.py keeps those).

It breaks MCP-ACK-2 ("the acknowledged message's sequence number"), and a copy answered with
a wrong number is, seen from the wire, MCP-ACK-1's or MCP-ACK-2's (D-9): both may be reported,
no other rule. Two false verdicts it drew:

- MCP-ACK-6: once a drone's own ACK took the number seq + 1 (the runner's drones number ACKs
  and messages from one counter, D-5), the manager's ACKs naming it were read as ACKs of that
  ACK -- by the case, whatever their time (most came before the drone's ACK existed), and by the
  monitor right after a Mission_Ready copy they may as well answer;
- ``ACK/test_ack_payload_is_the_seq_big_endian`` skipped "the manager ACKed nothing": no ACK
  was attributed to a Mission_Ready, yet every one named a number no datagram had carried.
"""

from __future__ import annotations

import dataclasses
import functools
import random
from types import SimpleNamespace
from typing import Any

import pytest

from mcp_conform.conformance.cases_manager import test_ack
from mcp_conform.harness.driver import Datagram, Sent, read_header
from mcp_conform.harness.drone_players import Mission
from mcp_conform.harness.errors import CaseFailure, Inconclusive
from mcp_conform.sim.faults import FaultMixin
from mcp_conform.sim.manager_runner import ManagerSimRun, run_manager_cases
from mcp_conform.sim.models import ManagerModel
from mcp_conform.spec.codec import MANAGER_ID, Action, Message, decode, encode

SHORT = {"rto": 0.2, "ack_window": 0.25}
PAYLOAD_CASE = "ACK/test_ack_payload_is_the_seq_big_endian"
ACK6_CASE = "ACK/test_an_ack_is_never_acked"


class AckSeqPlusOne(FaultMixin):
    """Every ACK names the message's seq + 1 (each ACK takes a number of its own, D-5)."""

    def _on_ack_and_deliver(self, msg: Any, addr: Any, now: float, arg: Any) -> None:
        named = (msg.seq + 1) & 0xFFFF
        self.deviations.append((now, f"ACK of seq {msg.seq} names {named}"))
        self._ack(msg, addr, named)
        self._deliver(msg, addr)


def ack_seq_plus_one(seed: int) -> Any:
    spawns = random.Random(seed)

    def make(drones: tuple[int, ...], challenge: int, items: tuple[Any, ...], now: float) -> ManagerModel:
        return ManagerModel(drones, challenge, items, SHORT["rto"], 12, random.Random(spawns.getrandbits(64)),
                            endpoint=lambda nid, rto, retries, rng: AckSeqPlusOne(nid, timeout=rto, retries=retries,
                                                                                  rng=rng))

    make.__name__ = "ack-seq-plus-one"
    return make


@functools.cache
def _run(seed: int, serial: bool) -> ManagerSimRun:
    return run_manager_cases(ack_seq_plus_one(seed), seed=seed, challenge=1 + seed % 3, serial=serial, **SHORT)


def _case(run: ManagerSimRun, case_id: str) -> dict[str, Any]:
    return next(c for c in run.report["cases"] if c["id"] == case_id)


def _monitor(run: ManagerSimRun) -> dict[str, str]:
    return dict(run.report["monitor"]["rules"].get("0", {}))


RUNS = [(seed, serial) for seed in (1, 2, 3) for serial in (False, True)]
IDS = [f"seed{seed}-{'serial' if serial else 'side-by-side'}" for seed, serial in RUNS]


@pytest.mark.parametrize(("seed", "serial"), RUNS, ids=IDS)
def test_fails_mcp_ack_2_and_no_other_rule_but_ack_1(seed, serial):
    run = _run(seed, serial)
    assert sum(len(m.ep.deviations) for m in run.managers) > 0  # the fault acted
    assert run.rules["MCP-ACK-2"] == "failed", run.explain()
    assert set(run.rules_with("failed", "warned")) <= {"MCP-ACK-2", "MCP-ACK-1"}, run.explain()
    monitor = _monitor(run)
    assert monitor.get("MCP-ACK-2") == "failed", run.report["monitor"]
    assert {r for r, o in monitor.items() if o in ("failed", "warned")} <= {"MCP-ACK-2", "MCP-ACK-1"}, \
        run.report["monitor"]


@pytest.mark.parametrize(("seed", "serial"), RUNS, ids=IDS)
def test_no_ack_of_an_ack_is_reported(seed, serial):
    """Neither the case nor the monitor (both failed MCP-ACK-6 before)."""
    run = _run(seed, serial)
    assert run.rules["MCP-ACK-6"] != "failed", run.explain()
    assert _case(run, ACK6_CASE)["outcome"] != "failed", _case(run, ACK6_CASE)
    assert _monitor(run).get("MCP-ACK-6") != "failed", run.report["monitor"]


@pytest.mark.parametrize(("seed", "serial"), RUNS, ids=IDS)
def test_the_payload_case_fails_an_ack_naming_a_number_nothing_carried(seed, serial):
    """The case fails MCP-ACK-2 itself (it was skipped: "the manager ACKed nothing"), its
    evidence the ACK, the number no datagram had carried, and the copy it followed."""
    case = _case(_run(seed, serial), PAYLOAD_CASE)
    assert case["outcome"] == "failed", case
    ev = "\n".join(case["evidence"])
    assert "manager: ACK dst=" in ev and "no datagram carried seq" in ev, ev
    assert "MISSION_READY seq" in ev, ev


# ---------------------------------------------------------------------- the cases, on a recorded mission
# What the simulated runs above do not reach: an ACK naming a drone's ACK's number right after a
# copy in the main mission (the C++ manager did it in the silent drone's, which the monitor
# judges), and the case's reading of the times. Synthetic missions (no sockets, no clock).
ADDR = ("127.0.0.1", 7889)


class _Driver:
    def __init__(self, sent: list[Sent]) -> None:
        self._sent = sent

    def sent(self) -> list[Sent]:
        return list(self._sent)


class _Node:
    """What the two cases use of their context (conformance.manager_case.ManagerCaseContext)."""

    rto, ack_window = SHORT["rto"], SHORT["ack_window"]

    def __init__(self, m: Mission, sent: list[Sent], complete: bool = True) -> None:
        self._m = m
        self.session = SimpleNamespace(driver=_Driver(sent), trace_complete=complete)

    def mission(self) -> Mission:
        return self._m

    def fail(self, rule: str, expected: str, actual: str, evidence: Any = ()) -> CaseFailure:
        return CaseFailure(rule, expected, actual, list(evidence))

    def expect_true(self, ok: bool, rule: str, expected: str, actual: str, evidence: Any = ()) -> None:
        if not ok:
            raise self.fail(rule, expected, actual, evidence)


def _sent(t: float, src: int, seq: int, action: Action, payload: Any = None) -> Sent:
    return Sent(t, int(t * 1e9), encode(Message(MANAGER_ID, src, seq, action, payload)), ADDR, MANAGER_ID, src, seq,
                int(action))


def _rx(i: int, t: float, dst: int, own: int, named: int) -> Datagram:
    data = encode(Message(dst, MANAGER_ID, own, Action.ACK, named))
    return Datagram(i, t, int(t * 1e9), data, ADDR, decode(data), None, read_header(data))


def _recorded(*, ack_before_drone_ack: bool = False, copy: bool = True, right_ack_too: bool = False,
              complete: bool = True) -> _Node:
    """Drone 1's Mission_Ready 1307 at 0 s, ACKed 0.2 ms later naming 1308; drone 1's ACK of
    Start_Mission (31618) takes 1308 at 2 s; at 2.3 s a copy of Mission_Ready (``copy``), the
    manager's ACK naming 1308 0.2 ms later (``ack_before_drone_ack``: at 1.9 s instead), and
    an ACK naming 1307 after it (``right_ack_too``)."""
    m = Mission("main", (1,), 1, None, None, t0=0.0, t_end=5.0)
    sent = [_sent(0.0, 1, 1307, Action.MISSION_READY), _sent(2.0, 1, 1308, Action.ACK, 31618)]
    rx = [(0.0002, 1308)]
    if copy:
        sent.append(dataclasses.replace(sent[0], t=2.3, t_ns=2_300_000_000))
    rx.append((1.9 if ack_before_drone_ack else 2.3002, 1308))
    if right_ack_too:
        rx.append((2.3004, 1307))
    for s in sent:
        m.sent_by_drones.setdefault((s.src, s.seq), s)
    m.rx = [_rx(i, t, 1, 31619 + i, named) for i, (t, named) in enumerate(rx)]
    return _Node(m, sent, complete)


def _outcome(case: Any, node: _Node) -> str:
    try:
        case(node)
    except CaseFailure as exc:
        return f"failed {exc.rule}"
    except Inconclusive:
        return "inconclusive"
    return "passed"


def test_the_ack_6_case_reads_an_ack_right_after_an_unanswered_copy_as_unproven():
    """Failed "1 ACK(s) of an ACK" before: it may be the copy's wrong ACK (D-9)."""
    assert _outcome(test_ack.test_an_ack_is_never_acked, _recorded()) == "inconclusive"


def test_the_ack_6_case_reads_an_ack_before_the_drones_ack_as_no_answer_of_it():
    """Failed before: an ACK sent before the drone's ACK existed cannot answer it."""
    assert _outcome(test_ack.test_an_ack_is_never_acked, _recorded(ack_before_drone_ack=True, copy=False)) == "passed"


@pytest.mark.parametrize("kw", [{"copy": False}, {"right_ack_too": True}], ids=["no-copy", "copy-answered"])
def test_the_ack_6_case_still_fails_an_ack_of_an_ack(kw):
    """No copy it may answer, or the copy answered with its own number: an ACK of the ACK."""
    assert _outcome(test_ack.test_an_ack_is_never_acked, _recorded(**kw)) == "failed MCP-ACK-6"


def test_the_ack_2_case_fails_an_ack_naming_a_number_nothing_carried():
    """Skipped "the manager ACKed nothing" before; not proven on an impaired link; a manager
    whose ACKs name only numbers carried before them (here 1308, once the drone's ACK took
    it) is not failed by it."""
    case = test_ack.test_ack_payload_is_the_seq_big_endian
    assert _outcome(case, _recorded()) == "failed MCP-ACK-2"
    assert _outcome(case, _recorded(complete=False)) == "inconclusive"
    later = _recorded()
    later._m.rx = later._m.rx[1:]  # only the ACK after the drone's ACK: 1308 carried by then
    assert _outcome(case, later) == "inconclusive"

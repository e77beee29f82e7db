"""The suite's schedule (issue 23): the plan as data, the batch kept only when it ran clean,
the startup's watch beside the cases, and a run that overlaps its windows (the verdicts
against serial runs: ``test_schedule_verdicts``, slow)."""

from __future__ import annotations

import json
import time
from pathlib import Path

import jsonschema
import pytest

from mcp_conform.conformance._batch import _Member, unclean
from mcp_conform.conformance.schedule import BATCH, BATCH_CASES, CRASHABLE, plan_cases
from mcp_conform.harness.driver import Datagram, Sent, read_header
from mcp_conform.harness.errors import CaseFailure, Inconclusive
from mcp_conform.judge.attribution import Attribution
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.spec.profiles import ROLE_NAMES, profile_of_role

from .runner_helpers import run_conform

SCHEMA = json.loads((Path(__file__).resolve().parents[2] / "conformance" / "report.schema.json").read_text())

CASES = [("BLK/test_nothing_new_while_mission_ready_awaits_its_ack", "startup"),
         ("RTX/test_mission_ready_is_retransmitted_until_acked", "startup"),
         ("ACK/test_every_command_type_is_acked", "main"),
         *[(c, "main") for c in BATCH_CASES],
         ("ACK/test_ack_leaves_within_the_deadline", "main"),
         ("ROB/test_flood_of_malformed_datagrams", "late"),
         ("BLK/test_end_mission_then_rtl", "end")]


def test_the_plan_batches_what_only_waits_and_says_why_each_case_runs_alone():
    plan = plan_cases(CASES)
    assert plan.mode == "scheduled"
    assert plan.batch == list(BATCH_CASES)
    steps = {s.case: s for s in plan.steps}
    assert all(s.shared and s.why for s in plan.steps if s.group == BATCH)
    assert all(not s.shared and s.why for s in plan.steps if s.group != BATCH)
    assert "latency" in steps["ACK/test_ack_leaves_within_the_deadline"].why
    assert "flood" in steps["ROB/test_flood_of_malformed_datagrams"].why
    # the batch runs where its first case stood; every other case keeps its place
    order = [s.case for s in plan.steps]
    assert order.index("ACK/test_every_command_type_is_acked") < order.index(plan.batch[0])
    assert order.index("RTX/test_mission_ready_is_retransmitted_until_acked") < order.index(plan.batch[0])
    assert [c for c in order if c not in BATCH_CASES] == [c for c, _ in CASES if c not in BATCH_CASES]
    assert order[-1] == "BLK/test_end_mission_then_rtl"
    assert sorted(order) == sorted(c for c, _ in CASES)
    doc = {"schedule": plan.to_json()}
    jsonschema.validate(doc["schedule"], SCHEMA["properties"]["schedule"])
    text = "\n".join(plan.lines())
    assert "batch" in text and "shared" in text


@pytest.mark.parametrize("case", ["ACK/test_ack_payload_is_the_big_endian_seq",
                                  "ACK/test_every_retransmitted_copy_is_acked",
                                  "DUP/test_new_seq_with_the_same_bytes_is_delivered"])
def test_quick_cases_that_judge_by_order_are_not_run_beside_the_batch(case):
    """Beside the batch's commands a node naming the previous message's seq in its ACKs named
    another open command's (MCP-ACK-2 passed), one comparing bytes saw other messages between
    the two it should have taken for one (MCP-DUP-2 passed): those cases run alone."""
    (step,) = [s for s in plan_cases([*CASES, (case, "main")]).steps if s.case == case]
    assert step.group == "alone" and not step.shared and "alone" in step.why


def test_attach_mode_does_not_risk_malformed_inputs_beside_others():
    plan = plan_cases(CASES, spawned=False)
    assert set(plan.batch) == set(BATCH_CASES) - CRASHABLE
    for s in plan.steps:
        if s.case in CRASHABLE:
            assert s.group == "alone" and "attach mode" in s.why


@pytest.mark.parametrize("kw,why", [({"serial": True}, "--serial"), ({"impaired": True}, "--impair"),
                                    ({"role": "manager"}, "manager"), ({"worker": True}, "xdist")])
def test_a_serial_plan_keeps_the_order_and_shares_nothing(kw, why):
    plan = plan_cases(CASES, **kw)
    assert plan.mode == "serial" and why in plan.why
    assert [s.case for s in plan.steps] == [c for c, _ in CASES]
    assert not plan.batch
    assert not any(s.shared for s in plan.steps)


@pytest.mark.parametrize("role", ROLE_NAMES)
def test_whether_a_role_is_scheduled_is_its_profile_s(role):
    """Issue 37 item 4: no role name in the schedule; RoleProfile.scheduled says it."""
    scheduled = profile_of_role(role).role(role).scheduled
    plan = plan_cases(CASES, role=role)
    assert (plan.mode != "serial") == scheduled
    assert scheduled or f"the {role} role's cases run one after another" in plan.why


def test_a_batch_of_one_shares_nothing():
    plan = plan_cases([("ACK/test_broadcast_is_not_acked", "main"), ("ACK/test_every_command_type_is_acked", "main")])
    assert not plan.batch


# ---------------------------------------------------------------------- a batch kept only clean
class _Drv:
    our_id = 0

    def __init__(self) -> None:
        self.tx: list[Sent] = []
        self.rx: list[Datagram] = []
        self.attr: dict[int, Attribution | None] = {}

    def send(self, dst: int, action: Action, payload=None) -> Sent:
        seq = 100 + len(self.tx)
        data = encode(Message(dst, 0, seq, action, payload))
        s = Sent(time.monotonic(), time.time_ns(), data, ("127.0.0.1", 1), dst, 0, seq, int(action), len(self.tx))
        self.tx.append(s)
        return s

    def reply(self, data: bytes, attribution: Attribution | None) -> None:
        from mcp_conform.spec.codec import decode

        try:
            msg = decode(data)
        except Exception:  # noqa: BLE001
            msg = None
        d = Datagram(len(self.rx), time.monotonic(), time.time_ns(), data, ("127.0.0.1", 2), msg, None,
                     read_header(data))
        self.rx.append(d)
        self.attr[d.index] = attribution

    def sent(self):
        return list(self.tx)

    def received(self, since=0):
        return self.rx[since:]

    def attribution(self, d):
        return self.attr.get(d.index)


class _Session:
    target_id = 1
    needs_restart = False
    lost = None
    liveness = None

    def __init__(self) -> None:
        self.driver = _Drv()

    def alive(self) -> bool:
        return True


class _Ctx:
    def __init__(self, case_id: str = "X/test") -> None:
        self.case_id, self.node_silent = case_id, False


def _member(exc=None):
    m = _Member(item=None, ctx=_Ctx())  # type: ignore[arg-type]
    m.exc = exc
    return m


def _ack(seq: int) -> bytes:
    return encode(Message(0, 1, 7, Action.ACK, seq))


def test_a_batch_whose_replies_all_name_an_answered_command_is_clean():
    s = _Session()
    wp = s.driver.send(1, Action.WP_OFF)
    s.driver.reply(_ack(wp.seq), Attribution(wp.command, wp.seq, "seq", "its seq"))
    assert unclean(s, [_member(), _member(Inconclusive("not observable"))], 0) is None


def test_a_reply_to_a_probe_that_must_not_be_answered_throws_the_batch_away():
    s = _Session()
    b = s.driver.send(0xFFFF, Action.WP_OFF)  # a broadcast: never ACKed
    s.driver.reply(_ack(b.seq), Attribution(b.command, b.seq, "seq", "its seq"))
    assert "must not answer" in unclean(s, [_member()], 0)


def test_more_acks_than_copies_to_answer_throw_the_batch_away():
    """A node that also ACKed a probe it must not answer, naming the seq of another open
    command (as a node naming the previous message's seq does), is not taken for clean."""
    s = _Session()
    wp = s.driver.send(1, Action.WP_OFF)
    s.driver.send(0xFFFF, Action.WP_OFF)  # a broadcast: not to be answered
    for _ in range(2):
        s.driver.reply(_ack(wp.seq), Attribution(wp.command, wp.seq, "seq", "its seq"))
    assert "2 ACKs for 1 copies" in unclean(s, [_member()], 0)


def test_a_reply_tied_by_timing_only_throws_the_batch_away():
    s = _Session()
    wp = s.driver.send(1, Action.WP_OFF)
    s.driver.reply(_ack(0x4242), Attribution(wp.command, wp.seq, "timing", "seq 16962"))
    assert "arrived after the command" in unclean(s, [_member()], 0)


def test_a_failure_a_silence_or_another_message_throws_the_batch_away():
    s = _Session()
    assert "CaseFailure" in unclean(s, [_member(), _member(CaseFailure("MCP-ACK-4", "x", "y"))], 0)
    skipped = _member(Inconclusive("the node forwarded no frame"))
    skipped.sent = 1  # skipped on what it saw beside the others: not kept
    assert "skipped after sending" in unclean(s, [skipped], 0)
    silent = _member()
    silent.ctx.node_silent = True
    assert "silent" in unclean(s, [silent], 0)
    s.driver.reply(encode(Message(0, 1, 9, Action.MISSION_READY, None)), None)
    assert "MISSION_READY" in unclean(s, [_member()], 0)


def test_a_batch_thrown_away_gives_the_rest_of_the_run_the_serial_order():
    from mcp_conform.conformance._batch import serial_from_here

    class It:  # an item: hashable, with its session
        session: object = None

    class Session:
        items: list = []

    serial = [It() for _ in range(6)]
    a, b4, c7, d5, e6, f = serial
    session = Session()
    session.items = [a, b4, d5, e6, c7, f]  # the batch b4, d5, e6 where b4 stood
    for it in serial:
        it.session = session
    serial_from_here(b4, serial)  # thrown away while its first case ran
    assert session.items == [a, b4, c7, d5, e6, f]


# ---------------------------------------------------------------------- a run
def _windows(res) -> list[tuple[int, int]]:
    batch = set(BATCH_CASES)
    return [(c["capture"]["start_ns"], c["capture"]["end_ns"]) for c in res.report["cases"] if c["id"] in batch]


def test_a_scheduled_run_watches_its_windows_together_and_serial_one_after_another():
    res = run_conform("-v")
    assert res.rc == 0, res.explain()
    plan = res.report["schedule"]
    assert "schedule: scheduled" in res.output  # -v prints the plan, case by case, with why
    assert "batch   shared ACK/test_broadcast_is_not_acked: waits out a 'no reply' window" in res.output
    jsonschema.validate(res.report, SCHEMA)
    assert plan["mode"] == "scheduled" and plan["batch_outcome"] == "kept", plan
    spans = _windows(res)
    assert len(spans) == len(BATCH_CASES)
    assert max(s for s, _ in spans) < min(e for _, e in spans)  # all open at one instant
    serial = run_conform("--serial")
    assert serial.rc == 0, serial.explain()
    assert serial.report["schedule"]["mode"] == "serial"
    spans = sorted(_windows(serial))
    assert all(e1 <= s2 for (_, e1), (s2, _) in zip(spans, spans[1:], strict=False))  # never together
    assert {c["id"]: c["outcome"] for c in res.report["cases"]} == \
        {c["id"]: c["outcome"] for c in serial.report["cases"]}

"""conformance._case_base: the verify helpers both datagram roles' cases share, on the part
every protocol's case context shares; and the failure Nsqd's and MAVLink's case contexts share
(``SpecCaseBase``: the node's death and the case's traffic, the robustness rule declared)."""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import pytest

from mcp_conform.conformance._case_base import CaseBase, DatagramCaseBase, SpecCaseBase
from mcp_conform.harness.errors import CaseFailure, Inconclusive
from mcp_conform.harness.session_base import Death


def _ctx(subject: str = "the node") -> DatagramCaseBase:
    ctx = DatagramCaseBase(None, "RTX/x", ("MCP-RTX-3",))
    ctx.subject = subject
    return ctx


def test_even_spacing_within_the_tolerance_passes_and_an_outlier_fails() -> None:
    _ctx().expect_even_spacing([0.200, 0.203, 0.198, 0.201])
    with pytest.raises(CaseFailure) as exc:
        _ctx().expect_even_spacing([0.200, 0.200, 0.450, 0.200])
    assert exc.value.rule == "MCP-RTX-3" and "450.0 ms" in exc.value.actual
    with pytest.raises(CaseFailure, match="none under"):  # a storm: evenly spaced, but too close
        _ctx().expect_even_spacing([0.001, 0.001, 0.001])
    with pytest.raises(Inconclusive, match="2 copies are too few"):
        _ctx().expect_even_spacing([0.2])


def test_expect_all_with_nothing_to_judge_names_the_subject() -> None:
    with pytest.raises(Inconclusive, match="the manager sent nothing"):
        _ctx("the manager").expect_all([], lambda d: None, "MCP-HDR-1", "the preamble")


def test_the_protocol_neutral_part_has_the_runners_hooks_and_the_generic_verify() -> None:
    ctx = CaseBase(None, "NSQD/x", ("NSQD-ROB-1",))
    ctx.conclude()  # nothing to prove by default
    ctx.info("seen")
    assert ctx.notes == ["seen"] and ctx.evidence is None and ctx.end_ns is None
    with pytest.raises(CaseFailure) as exc:
        ctx.expect_true(False, "NSQD-ROB-1", "alive", "dead", ["stderr: boom"])
    assert exc.value.rule == "NSQD-ROB-1" and exc.value.evidence == ["stderr: boom"]
    assert not hasattr(ctx, "expect_even_spacing")  # the datagram helpers are DatagramCaseBase's


class _Spec(SpecCaseBase):
    """A protocol's case as its context declares it: its traffic, its grace."""

    subject = "the backend"

    def traffic(self) -> list[str]:
        return ["sent 3 B: 01 02 03"]

    def death_grace(self) -> float:
        return 0.25


def _spec_ctx(death: Death | None, death_rule: str) -> tuple[_Spec, list[float]]:
    graces: list[float] = []

    def died(grace: float = 0.0) -> Death | None:
        graces.append(grace)
        return death

    session: Any = SimpleNamespace(spec=SimpleNamespace(params={"gap_s": 1.5}), death=died)
    ctx = _Spec(session, "ROB/x", ("X-MSG-2", "X-MSG-3"))
    ctx.death_rule = death_rule
    return ctx, graces


def test_a_spec_case_fails_its_rule_with_its_traffic_last_and_its_spec_at_hand() -> None:
    ctx, graces = _spec_ctx(None, "X-ROB-1")
    assert ctx.params == {"gap_s": 1.5}
    f = ctx.fail("X-MSG-2", "an UPDATE", "none", ["conn 1 open"])
    assert (f.rule, f.expected, f.actual) == ("X-MSG-2", "an UPDATE", "none")
    assert f.evidence == ["conn 1 open", "sent 3 B: 01 02 03"] and graces == [0.25]


def test_a_death_is_the_robustness_rules_when_the_protocol_declares_one_else_said_first() -> None:
    death = Death(None, "SIGSEGV", "SUMMARY: AddressSanitizer: SEGV", ("boom", "tail"), "the backend")
    ctx, _ = _spec_ctx(death, "X-ROB-1")
    f = ctx.fail("X-MSG-2", "an UPDATE", "none", ["conn 1 open"])
    assert (f.rule, f.actual, f.relies_on) == ("X-ROB-1", death.describe(), ())
    assert f.evidence == ["SUMMARY: AddressSanitizer: SEGV", "sent 3 B: 01 02 03", "stderr: boom", "stderr: tail",
                          "while testing X-MSG-2, X-MSG-3 (ROB/x)"]
    ctx, _ = _spec_ctx(death, "")  # no robustness rule: the rule judged, the death its first evidence
    f = ctx.fail("X-MSG-2", "an UPDATE", "none", ["conn 1 open"])
    assert (f.rule, f.expected) == ("X-MSG-2", "an UPDATE")
    assert f.evidence == [death.describe(), "conn 1 open", "sent 3 B: 01 02 03"]


def test_a_spec_case_names_who_is_judged_as_its_session_does() -> None:
    """Who is judged is declared once, by the session (``SessionBase.subject``): its case
    contexts' words are the session's."""
    session: Any = SimpleNamespace(spec=SimpleNamespace(params={}), subject="the ground station",
                                   death=lambda grace=0.0: None)
    ctx = SpecCaseBase(session, "HB/x", ("MAV-HB-1",))
    assert ctx.subject == "the ground station"
    with pytest.raises(Inconclusive, match="the ground station sent nothing"):
        ctx.expect_all([], lambda d: None, "MAV-HB-1", "a HEARTBEAT")

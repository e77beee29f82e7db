"""conformance._case_base: the verify helpers both datagram roles' cases share, on the part
every protocol's case context shares."""

from __future__ import annotations

import pytest

from mcp_conform.conformance._case_base import CaseBase, DatagramCaseBase
from mcp_conform.harness.errors import CaseFailure, Inconclusive


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

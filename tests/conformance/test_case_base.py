"""conformance._case_base: the verify helpers both roles' cases share."""

from __future__ import annotations

import pytest

from conformance._case_base import CaseBase
from harness.errors import CaseFailure, Inconclusive


def _ctx(subject: str = "the node") -> CaseBase:
    ctx = CaseBase(None, "RTX/x", ("MCP-RTX-3",))
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

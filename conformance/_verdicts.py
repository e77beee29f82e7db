"""A case's outcome from what it raised: the MUST / SHOULD / INFO mapping, the baseline's
expected failures, and the one line the capture's log gets (``conformance._plugin_run``'s
report hook calls these; they read and write one ``CaseRecord`` and its pytest report).

A ``CaseFailure`` takes the level of the rule it names: MUST -> failed, SHOULD -> warned
(the pytest report becomes a pass) unless ``--mcp-strict``, INFO -> info; ``Inconclusive``
-> skipped with its reason; ``TargetLost``, a time limit and any other exception -> error.
"""

from __future__ import annotations

from typing import Any

import pytest

from mcp_conform.conformance._run_state import CaseTimeLimit, McpState, _one_line
from mcp_conform.conformance.marks import rule_level
from mcp_conform.conformance.report import CaseRecord
from mcp_conform.harness.errors import (
    CaseFailure,
    Inconclusive,
    NodeLost,
    SilenceUnproven,
    TargetLost,
)
from mcp_conform.spec import RULES

__all__ = ["apply_baseline", "exception_only", "judge_exception", "log_evidence", "skip_longrepr", "verdict_repr"]


def skip_longrepr(item: pytest.Item, reason: str) -> tuple[str, int, str]:
    path, lineno, _ = item.reportinfo()
    return (str(path), (lineno or 0) + 1, f"Skipped: {reason}")


def judge_exception(state: McpState, item: pytest.Item, rec: CaseRecord, exc: BaseException,
                     rep: pytest.TestReport) -> None:
    if isinstance(exc, CaseFailure):
        if exc.rule not in RULES:
            rec.outcome, rec.reason = "error", f"the case reported unknown rule {exc.rule!r}"
            return
        rule = RULES[exc.rule]
        level = rule_level(exc.rule)
        rec.failed_rule, rec.expected, rec.actual = exc.rule, exc.expected, exc.actual
        rec.evidence = [str(e) for e in exc.evidence]
        rec.relies_on = exc.dependencies()
        rec.reason = f"{exc.rule}: {rule.text}"
        if level == "MUST" or (level == "SHOULD" and state.cfg.strict):
            rec.outcome = "failed"
            rep.longrepr = exc.describe()
        else:
            rec.outcome = "warned" if level == "SHOULD" else "info"
            rep.outcome, rep.longrepr = "passed", None
            rep.sections.append((f"mcp-conform {rec.outcome}", exc.describe()))
        return
    if isinstance(exc, Inconclusive):
        rec.outcome, rec.reason = "skipped", (str(exc).strip() or "inconclusive")
        rep.outcome, rep.longrepr = "skipped", skip_longrepr(item, rec.reason)
        return
    rec.outcome = "error"
    if isinstance(exc, CaseTimeLimit):
        rec.reason = str(exc)
    elif isinstance(exc, NodeLost):
        rec.reason = f"node lost during this case: {exc.reason}"
        rec.evidence = list(exc.evidence)
    elif isinstance(exc, SilenceUnproven):
        rec.reason, rec.evidence = exc.reason, list(exc.evidence)
    elif isinstance(exc, TargetLost):
        rec.reason = f"target lost: {str(exc).strip() or 'the node is gone'}"
    else:
        rec.reason = _one_line(exc)
        tb = exc.__traceback__
        while tb is not None and tb.tb_next is not None:
            tb = tb.tb_next
        if tb is not None:
            rec.evidence = [f"raised at {tb.tb_frame.f_code.co_filename}:{tb.tb_lineno} "
                            f"in {tb.tb_frame.f_code.co_name}"]


def apply_baseline(state: McpState, rec: CaseRecord, rep: pytest.TestReport) -> None:
    """An expected failure (``--baseline``) that failed or warned is ``xfailed``; one that
    passed is ``xpassed`` (a failure under --strict), as pytest reports xfail / xpass."""
    assert state.baseline is not None
    if rec.outcome not in ("failed", "warned", "passed"):
        return
    entry = state.baseline.match(rec.id, rec.rules, rec.failed_rule if rec.outcome != "passed" else None)
    if entry is None:
        return
    rec.baseline = entry.reason
    if rec.outcome in ("failed", "warned"):
        rec.outcome = "xfailed"
        rep.outcome, rep.longrepr = "skipped", None
        rep.wasxfail = entry.reason  # type: ignore[attr-defined]
    elif state.cfg.strict:
        rec.outcome = "xpassed"
        rep.outcome, rep.longrepr = "failed", f"[XPASS(strict)] {rec.id} is on the baseline ({entry.reason}) but passed"
    else:
        rec.outcome = "xpassed"
        rep.wasxfail = entry.reason  # type: ignore[attr-defined]


def log_evidence(rec: Any) -> str | None:
    """Why a case did not pass, in one line: the reason, expected / actual and the first
    evidence lines of the report (None when it passed)."""
    if rec.outcome in ("passed", "info", "xpassed"):
        return None
    parts = [p for p in (rec.reason,
                         f"expected {rec.expected}, got {rec.actual}" if rec.expected or rec.actual else None,
                         *list(rec.evidence)[:3]) if p]
    return "; ".join(str(p) for p in parts)[:2000] or None


def verdict_repr(original: Any) -> Any:
    """A case's verdict (a :class:`CaseFailure`, an :class:`Inconclusive`) gets its report's
    text from the verdict itself (``judge_exception``), so pytest's long traceback of it, with
    the source of every frame parsed, is not made only to be thrown away (about 10 ms a case,
    a fifth of a short run's CPU); any other exception (a bug, a lost node) keeps it under pytest
    itself (under ``mcp-conform`` no case gets one: :func:`exception_only`)."""
    def repr_failure(excinfo: pytest.ExceptionInfo[BaseException], style: Any = None) -> Any:
        if isinstance(excinfo.value, (CaseFailure, Inconclusive)):
            return excinfo.exconly()
        return original(excinfo) if style is None else original(excinfo, style)
    return repr_failure


def exception_only(excinfo: pytest.ExceptionInfo[BaseException], style: Any = None) -> str:
    """A case's exception as its report text under ``mcp-conform``, which shows no traceback
    (reason and evidence come from the exception, ``judge_exception``): pytest's would parse
    every frame's source, ~30 ms a case (a node lost in attach mode errs every later case)."""
    return excinfo.exconly()

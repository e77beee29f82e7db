"""A case run through ``--impair`` (issue 22 item 3): repeated, never failed, when the
impairment spoiled what it observed.

The runner's own socket is the bad link (``harness.impair_link``), so it knows every
decision. A case that failed (``CaseFailure``, any level) or could not judge
(``Inconclusive``, ``SilenceUnproven``) while a decision able to spoil its observation fell
in its window (a datagram of its exchange dropped, duplicated, reordered, corrupted or held
long, or the node's retransmissions of an earlier one) is repeated; so is one that passed on
what it could judge, leaving some observation unjudged (``unjudged``: a reply whose command is
ambiguous, as a duplicated command's second ACK makes it), when a decision fell in its window:
a node whose every ACK names the wrong seq but one, the ACK of a copy the link made, passed
MCP-ACK-2 so:

- up to ``ATTEMPTS`` attempts; the last one with the link paused (clean), so a rule a node
  breaks on a clean link fails through ``--impair`` as it does without it, and a failure
  is only ever reported from an attempt no decision touched;
- a startup-phase case judges the one startup the run observed: it is not repeated but
  skipped with "spoiled by the impairment: ..." when that startup was touched;
- every spoiled attempt is a note of the case's record (what the link did, to which
  datagram), so the report says why the case ran more than once.

A failure from an untouched attempt stands at once: no decision can have caused it.
"""

from __future__ import annotations

import time
from typing import Any

import pytest

from mcp_conform.harness.errors import CaseFailure, Inconclusive, SilenceUnproven

__all__ = ["ATTEMPTS", "SPOILABLE", "run_impaired"]

#: attempts of a spoiled case in all (the last on a clean link)
ATTEMPTS = 3
#: the outcomes an impairment decision can cause (an error stays an error)
SPOILABLE = (CaseFailure, Inconclusive, SilenceUnproven)
#: how many decisions a note names
SHOWN = 4


def _what(spoiled: list[str]) -> str:
    more = f" and {len(spoiled) - SHOWN} more" if len(spoiled) > SHOWN else ""
    return "; ".join(spoiled[:SHOWN]) + more


def _link(session: Any) -> Any:
    return session.driver.link if session.driver is not None else None


def _sent_since(session: Any, since: float) -> bool:
    driver = session.driver
    return driver is not None and any(s.t >= since for s in driver.sent()[-200:])


def _settle(session: Any, link: Any) -> None:
    """Before a repeat: wait out what the link still holds and the node's retransmissions
    of the spoiled attempt (bounded), so the attempt starts settled; and the attribution's
    horizon since the runner's last send, so no command of the spoiled attempt is still
    "unanswered, sent less than a window earlier" beside the repeat's (``judge.attribution``):
    a node whose ACK names an earlier command (ack-previous-seq) was so left unjudged on the
    clean attempt too."""
    clock = session.clock
    driver = session.driver
    horizon = float(getattr(getattr(driver, "attributor", None), "horizon", 0.0) or 0.0)
    sent = driver.sent()[-1:] if driver is not None else []
    if sent and horizon > 0:
        clock.sleep(max(0.0, min(sent[0].t + 2 * horizon, clock.monotonic() + 2 * horizon) - clock.monotonic()))
    deadline = clock.monotonic() + max(2 * session.cfg.rto, 0.5)
    while clock.monotonic() < deadline:
        if not link.touched(clock.monotonic() - session.cfg.rto):
            break
        clock.sleep(0.05)


def run_impaired(state: Any, item: pytest.Item, first: BaseException | None) -> None:
    """``first`` ended the case's first attempt (None: it passed with observations
    ``unjudged``): re-raise it (untouched; a pass stands), repeat the case (touched), or skip
    it with what the impairment spoiled. Returns when an attempt passed and judged all it saw,
    or passed untouched."""
    session = state.session
    link = _link(session)
    phase = state.meta[item.nodeid][3]
    rules = state.meta[item.nodeid][1]
    head = rules[0] if rules else item.nodeid
    exc = first
    notes: list[str] = []
    for attempt in range(1, ATTEMPTS + 1):
        ctx = state.ctx.get(item.nodeid)
        if phase == "startup":
            since, until = session.startup_window
            spoiled = session.spoiled_by_impairment(since, until)
            if exc is None:
                return  # passed on the one startup the run observed: not repeatable
            if not spoiled:
                raise exc
            raise Inconclusive(f"{head}: spoiled by the impairment: the startup phase it judges was "
                               f"touched ({_what(spoiled)}); it is observed once per run") from exc
        since = ctx.start_t
        # the first attempt may inherit an earlier case's traffic; a repeat starts settled
        spoiled = session.spoiled_by_impairment(since, None, lookback=attempt == 1)
        if isinstance(exc, Inconclusive) and not _sent_since(session, since):
            spoiled = []  # it sent nothing: not observable here, whatever the link did
        if not spoiled:
            if exc is None:
                return  # passed, and what it could not judge no decision caused
            raise exc  # no decision can have caused it: it stands
        notes.append(f"attempt {attempt} spoiled by the impairment ({_one(exc, ctx)}): {_what(spoiled)}")
        if attempt == ATTEMPTS:
            break
        clean = attempt + 1 == ATTEMPTS
        try:
            exc = _attempt(state, item, ctx, link, clean, notes)
        finally:
            if link is not None:
                link.paused = False
        if exc is None and (clean or not getattr(state.ctx.get(item.nodeid), "unjudged", None)):
            return  # on a clean link what it could not judge is the node's own doing
    raise Inconclusive(f"{head}: spoiled by the impairment on all {ATTEMPTS} attempts: "
                       + " | ".join(notes)) from exc


def _one(exc: BaseException | None, ctx: Any) -> str:
    if exc is None:
        return f"passed, {len(ctx.unjudged)} observation(s) not judged"
    if isinstance(exc, CaseFailure):
        return f"{exc.rule} failed"
    return "inconclusive" if isinstance(exc, Inconclusive) else type(exc).__name__


def _attempt(state: Any, item: pytest.Item, ctx: Any, link: Any, clean: bool,
             notes: list[str]) -> BaseException | None:
    """One more attempt of the case with a fresh case context; the exception it ended
    with, or None when it passed (the notes go to its record)."""
    session = state.session
    rec = state.record(item)
    if ctx is not None:
        session.end_case(ctx, "spoiled")
    if link is not None:
        link.paused = clean
        _settle(session, link)
    new = session.begin_case(rec.id, rec.rules)
    new.notes.extend(notes)
    if clean:
        new.notes.append(f"attempt {len(notes) + 1} ran with the impairment paused (a clean link)")
    item.funcargs["node"] = new  # type: ignore[attr-defined]
    state.ctx[item.nodeid] = new
    state.case_deadline = time.monotonic() + state.current_limit()
    state.arm()
    try:
        item.runtest()
    except SPOILABLE as exc:
        return exc
    finally:
        state.disarm()
    return None

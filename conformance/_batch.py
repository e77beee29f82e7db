"""The batch of the schedule (``conformance.schedule``) run: its cases together, each in a
thread of its own with its own case context, so their windows are watched once; kept only
when it ran clean, else thrown away and its cases run again one by one.

Clean (``unclean``): every case passed or was skipped, the node is alive, not lost, not
silent, and every datagram it sent while the batch ran is a well-formed ACK, to the runner,
whose payload names the seq of a command the node had to answer (a well-formed unicast to
its ID), tied to it by that seq without ambiguity, and no more of them than copies of such
commands were sent (a reply naming another open command's seq looks right one by one). So a
reply a silence probe drew (an ACK
of a broadcast, of a message to another ID, of an ACK, of a malformed datagram), a reply
tied by timing only, a node lost to one input, any failure: the batch's verdicts are
discarded and each case runs alone, in the serial order, as ``--serial`` runs it — a fault
one probe provokes is never judged beside another's.

A case whose observation is a run of its own messages with nothing between them (MCP-DUP-1:
a message and its copy, the copy of the one *last* delivered from the manager) sends it
``in_a_row`` (``InARow``): meanwhile the other cases' threads are held back before they
send, so the node sees the run as a case alone sees it. Without it, a correct node that
remembers only the last seq it delivered (MCP-DUP-1's own words; an older copy is MCP-DUP-4's
open question) took the copy for a late copy of an older message when a neighbour's WP_Off
came between, and delivered it again: a verdict that depended on the interleaving (issue 35).

The cases run as the pytest items they are: the batch starts at its first case's call
(``run_batch``); each later case's ``node`` fixture takes the context made for it
(``pending``), and its call returns the verdict its thread ended with (``take``).
"""

from __future__ import annotations

import contextlib
import inspect
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import pytest

from mcp_conform.conformance.drone_case import CaseContext
from mcp_conform.conformance.schedule import BATCH, BATCH_CASES, PASSTHROUGH_CASES, plan_cases
from mcp_conform.harness.clock import REAL, Clock
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.spec.codec import Action, DecodeError, decode

__all__ = ["BatchRun", "InARow", "in_plan_order", "run_batch", "serial_from_here", "unclean"]

_ACK = int(Action.ACK)


@dataclass
class _Member:
    item: pytest.Item
    ctx: CaseContext  # the batch is the drone role's (conformance.schedule)
    exc: BaseException | None = None
    done: threading.Event = field(default_factory=threading.Event)
    sent: int = 0  # datagrams the case sent itself (its thread)


@dataclass
class BatchRun:
    """The batch in progress or done: its members by nodeid, whether it was kept."""

    members: dict[str, _Member] = field(default_factory=dict)
    kept: bool | None = None  # None: not run yet
    why: str = ""
    pending: dict[str, Any] = field(default_factory=dict)  # nodeid -> context for its fixture
    taken: set[str] = field(default_factory=set)


class InARow:
    """The batch's runs of consecutive messages: while one case's thread holds the run
    (``held``), every other case's thread waits before it sends (``gate``, the driver's
    ``tx_gate``; the seq is taken after the wait, so the node sees the runner's seqs in
    order); the run starts once no other case is sending. Threads that are no case of the
    batch (the receiver's ACKs, the liveness watcher's probes from an MCP ID of their own)
    are never held."""

    def __init__(self, members: dict[int, _Member], clock: Clock = REAL) -> None:
        self._cond = clock.condition()  # the session's (harness.clock)
        self._members = members  # thread id -> member
        self._holder: int | None = None
        self._sending = 0  # sends of other case threads in progress

    @contextlib.contextmanager
    def held(self) -> Iterator[None]:
        me = threading.get_ident()
        with self._cond:
            while self._holder is not None or self._sending:
                self._cond.wait(0.05)
            self._holder = me
        try:
            yield
        finally:
            with self._cond:
                self._holder = None
                self._cond.notify_all()

    @contextlib.contextmanager
    def gate(self) -> Iterator[None]:
        me = threading.get_ident()
        counted = False
        if me in self._members:
            with self._cond:
                while self._holder not in (None, me):
                    self._cond.wait(0.05)
                counted = self._holder is None
                self._sending += counted
        try:
            yield
        finally:
            if counted:
                with self._cond:
                    self._sending -= 1
                    self._cond.notify_all()


def _kwargs(item: pytest.Item, ctx: Any) -> dict[str, Any]:
    """The case function's arguments: its context, and its parametrization."""
    fn = item.obj  # type: ignore[attr-defined]
    params = dict(getattr(getattr(item, "callspec", None), "params", {}) or {})
    names = [n for n in inspect.signature(fn).parameters]
    out: dict[str, Any] = {}
    for n in names:
        if n == "node":
            out[n] = ctx
        elif n in params:
            out[n] = params[n]
        else:
            raise LookupError(f"case argument {n!r} is neither its context nor a parameter")
    return out


def batchable(item: pytest.Item) -> bool:
    """The case takes nothing the batch cannot give it (its context, its parameters)."""
    try:
        _kwargs(item, None)
    except (LookupError, TypeError, ValueError):
        return False
    return True


def _run_one(m: _Member, threads: dict[int, _Member]) -> None:
    threads[threading.get_ident()] = m
    try:
        m.item.obj(**_kwargs(m.item, m.ctx))  # type: ignore[attr-defined]
    except BaseException as exc:  # noqa: BLE001 - the verdict, re-raised in the case's own call
        m.exc = exc
    finally:
        m.done.set()


def _expected_reply(session: Any, d: Any, sent: list[Any]) -> str | None:
    """Why ``d`` is not the plain ACK of a command the node had to answer (None: it is)."""
    drv = session.driver
    a = drv.attribution(d)
    if a is None:
        return f"a datagram tied to no command: {d.describe()}"
    if a.how != "seq" or a.ambiguous:
        return f"a reply {a.describe()}: {d.describe()}"
    first = sent[a.command] if 0 <= a.command < len(sent) else None
    if first is None or first.action == _ACK or first.dst != session.target_id:
        return f"a reply to a datagram the node must not answer: {d.describe()}"
    try:
        decode(first.data)
    except DecodeError:
        return f"a reply to a malformed datagram: {d.describe()}"
    # an ACK goes to the command's source (MCP-ACK-3): a case of the batch sending from an ID
    # of its own gets its ACKs there (the independent node's batch was thrown away for a
    # correct "ACK dst=19542" to such a command, CI under load)
    if d.msg is None or d.header[0] != first.src or d.header[1] != session.target_id:
        return f"a reply not in the form of an ACK to its command's source: {d.describe()}"
    return None


def _answerable(session: Any, s: Any) -> bool:
    """A datagram the runner sent that a correct node under test ACKs (:func:`owes_ack`)."""
    return owes_ack(s, session.target_id)


def owes_ack(s: Any, node_id: int | None) -> bool:
    """A datagram the runner sent that node ``node_id`` owes an ACK (MCP-ACK-1): well-formed,
    unicast to its ID, not an ACK (the drone role's node under test, the manager role's 0)."""
    if s.action == _ACK or s.dst != node_id:
        return False
    try:
        decode(s.data)
    except DecodeError:
        return False
    return True


def unclean(session: Any, members: list[_Member], since: int, sent_since: int = 0) -> str | None:
    """Why the batch's verdicts cannot be kept (None: it ran clean). ``since``: the index of
    the first datagram received in the batch; ``sent_since``: of the first sent."""
    for m in members:
        if m.exc is not None and not isinstance(m.exc, (Inconclusive, pytest.skip.Exception)):
            return f"{m.ctx.case_id} ended {type(m.exc).__name__}"
        if m.exc is not None and m.sent:  # skipped on what it saw beside the others
            return f"{m.ctx.case_id} was skipped after sending ({m.exc})"
        if m.ctx.node_silent:
            return f"the node went silent in {m.ctx.case_id}"
    if not session.alive():
        return "the node's process exited"
    if session.needs_restart or session.lost:
        return "the node was lost"
    liveness = session.liveness
    if liveness is not None and liveness.lost is not None:
        return "the node was declared lost"
    drv = session.driver
    sent = drv.sent()
    got = drv.received(since)
    for d in got:
        if d.header is None or d.header[3] != _ACK:
            return f"the node sent {d.describe()}"
        why = _expected_reply(session, d, sent)
        if why is not None:
            return why
    # one ACK per copy of a command it had to answer, at most: more, and it answered something
    # else too, whatever seq it named (a reply naming another open command's seq looks right)
    due = sum(1 for s in sent[sent_since:] if _answerable(session, s))
    if len(got) > due:
        return f"the node sent {len(got)} ACKs for {due} copies of commands it had to answer"
    return None


def run_batch(state: Any, leader: pytest.Item, items: list[pytest.Item], batch: BatchRun) -> None:
    """Run the batch's cases together (``leader``'s context is its fixture's); decide
    whether it is kept. Later cases' contexts wait in ``batch.pending`` for their fixtures."""
    session = state.session
    clock = session.clock  # the run's (harness.clock): the host's, or the simulator's virtual time
    members: list[_Member] = []
    since = session.driver.mark()
    sent_since = len(session.driver.sent())
    for item in items:
        if item is leader:
            ctx = item.funcargs["node"]  # type: ignore[attr-defined]
        else:
            rec = state.record(item)
            ctx = session.begin_case(rec.id, rec.rules)
            batch.pending[item.nodeid] = ctx
        members.append(_Member(item, ctx, done=clock.event()))
        batch.members[item.nodeid] = members[-1]
    try:
        why = _learn_first(session, members)
    except BaseException as exc:  # the time limit, an interrupt
        _throw_away(session, batch, leader, members, f"it was cut short ({type(exc).__name__}: {exc})")
        raise
    if why is not None:
        _throw_away(session, batch, leader, members, why)
        return
    by_thread: dict[int, _Member] = {}

    def count(sent: Any) -> None:  # in the sending thread, under the driver's lock
        m = by_thread.get(threading.get_ident())
        if m is not None:
            m.sent += 1
    drv = session.driver
    drv.tx_hooks.append(count)
    in_a_row = InARow(by_thread, clock)
    for m in members:
        m.ctx.hold_others = in_a_row.held
    drv.tx_gate = in_a_row.gate
    for n, m in enumerate(members):
        clock.start_thread(lambda m=m: _run_one(m, by_thread), f"mcp-batch-{n}")  # type: ignore[misc]  # mypy: a default argument
    try:
        for m in members:
            while not m.done.wait(0.05):  # a signal (the time limit, SIGINT) still reaches the main thread
                pass
    except BaseException as exc:  # the time limit, an interrupt: nothing of the batch is kept
        _throw_away(session, batch, leader, members, f"it was cut short ({type(exc).__name__}: {exc})")
        raise
    finally:
        drv.tx_gate = contextlib.nullcontext
        for m in members:
            m.ctx.hold_others = None
        with contextlib.suppress(ValueError):
            drv.tx_hooks.remove(count)
    why = unclean(session, members, since, sent_since)
    if why is None:
        batch.kept = True
        return
    _throw_away(session, batch, leader, members, why)


def _learn_first(session: Any, members: list[_Member]) -> str | None:
    """What a case of the batch would learn of the node before judging (whether it forwards
    Mav_Passthrough frames to its autopilot), learnt first, by the first case that asks, as
    a serial run learns it: alone, nothing else on the node's autopilot link. Why the batch
    cannot run, or None."""
    if session.passthrough_forwarded is not None:
        return None
    vehicle = session.vehicle
    if vehicle is None or not vehicle.connections:
        return None  # the cases that need it are skipped before they send anything
    first = next((m for m in members if m.ctx.case_id in PASSTHROUGH_CASES), None)
    if first is None:
        return None
    try:
        with session.capability_lock:
            first.ctx.learn_passthrough(first.ctx.rules[0])
    except Inconclusive as exc:  # the probe was not ACKed: not learnt
        return f"{first.ctx.case_id} could not learn whether the node forwards frames ({exc})"
    return None


def _throw_away(session: Any, batch: BatchRun, leader: pytest.Item, members: list[_Member], why: str) -> None:
    """The batch's verdicts are not kept: the later cases' contexts end here; each case runs
    alone at its turn (its fixture makes it a fresh context)."""
    batch.kept, batch.why = False, why
    # what the batch left open takes no reply of the cases run again: its commands answered
    # or expired first (a node naming the previous message's seq answered an open copy of the
    # batch's instead of the next case's command: a cascade of retransmissions)
    horizon = session.driver.attributor.horizon
    with contextlib.suppress(Exception):  # a node lost meanwhile: the reruns say so
        session.driver.settle_attribution(4 * horizon)
    for m in members:
        if m.item is not leader and batch.pending.pop(m.item.nodeid, None) is not None:
            m.ctx.end_ns = session.clock.time_ns()
            session.end_case(m.ctx, "rerun")


def rerun_leader(state: Any, item: pytest.Item, batch: BatchRun) -> None:
    """The batch was thrown away: its first case again, alone, with a fresh context."""
    session = state.session
    old = item.funcargs["node"]  # type: ignore[attr-defined]
    session.end_case(old, "rerun")
    rec = state.record(item)
    new = session.begin_case(rec.id, rec.rules)
    new.notes.append(f"ran alone after its batch was thrown away: {batch.why}")
    item.funcargs["node"] = new  # type: ignore[attr-defined]
    state.ctx[item.nodeid] = new
    item.obj(**_kwargs(item, new))  # type: ignore[attr-defined]


def serial_from_here(item: pytest.Item, serial_order: list[pytest.Item]) -> None:
    """The batch was thrown away at ``item``: the items still to run go back to the serial
    order, so every case after it meets the node in the state a ``--serial`` run leaves it
    in (a node whose answers depend on what came before — the previous message's seq — saw
    the batch's cases before MCP-ACK-7 otherwise). pytest runs ``session.items`` by index:
    the items after this one are replaced in place."""
    items = item.session.items
    i = items.index(item)
    done = set(items[: i + 1])
    rest = [it for it in serial_order if it not in done]
    rest += [it for it in items[i + 1:] if it not in rest and it not in done]
    if len(rest) == len(items) - i - 1:
        items[i + 1:] = rest


def take(item: pytest.Item, batch: BatchRun) -> None:
    """The verdict the case's thread ended with: returned, or raised again."""
    m = batch.members[item.nodeid]
    batch.taken.add(item.nodeid)
    if m.exc is not None:
        raise m.exc


def in_plan_order(state: Any, items: list[pytest.Item]) -> list[pytest.Item]:
    """The cases in the order of the run's plan (``conformance.schedule``); other items stay
    at the end, as they came."""
    cases = [i for i in items if i.nodeid in state.meta]
    rest = [i for i in items if i.nodeid not in state.meta]
    cfg = state.cfg
    by_id: dict[str, pytest.Item] = {}
    for i in cases:
        by_id.setdefault(state.meta[i.nodeid][0], i)
    serial = bool(state.config.getoption("mcp_serial")) or len(by_id) != len(cases) \
        or not all(batchable(i) for i in cases if state.meta[i.nodeid][0] in BATCH_CASES)
    plan = plan_cases([(state.meta[i.nodeid][0], state.meta[i.nodeid][3]) for i in cases], role=cfg.role,
                      spawned=cfg.mode != "attach", serial=serial, impaired=cfg.impair is not None,
                      worker=hasattr(state.config, "workerinput"))
    state.plan = plan
    state.run.schedule = plan.to_json()
    state.batch_items = [by_id[s.case] for s in plan.steps if s.group == BATCH]
    return [by_id[s.case] for s in plan.steps] + rest

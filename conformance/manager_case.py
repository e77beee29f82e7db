"""The per-case context for ``--role manager`` (the ``node`` fixture), and the judgements
over a recorded mission that several rule groups share.

A case asks for the record of a scenario (``node.mission()``: the main one, run at start;
``node.mission("silent")``: run on first use), then calls one verify helper. The helpers
raise ``CaseFailure(rule, expected, actual, evidence)`` or ``Inconclusive(reason)`` as the
drone role's do (``conformance.drone_case``).

Conventions (one fault, one rule):
- A message *awaits its ACK* from its first copy until the runner's first ACK of it (the
  right one, or a deliberately wrong one of MCP-RTX-2: taking a wrong ACK for the ACK is
  RTX-2's fault; not those where RTX-2's second observation proved the manager ignores them)
  — or, when the manager stopped retransmitting it before any ACK (it gave up, MCP-RTX-1's
  business), until its last copy.
- A copy is a datagram to the same drone with the same action and payload as a message
  awaiting its ACK; whether it repeats the seq and bytes is MCP-SEQ-2's business.
- A drone the manager gave up on (a command whose retransmission stopped unACKed) is
  excused from the rest of the mission's flow rules.
- A broadcast (dst the broadcast ID) is a command to each drone whose mission is on when it
  comes -- its Start_Mission answered, no End_Mission sent to it yet -- (D-11): :func:`to_mission`;
  and, going to every drone, one to a drone whose Start_Mission awaits its answer (MCP-BLK-3,
  :func:`awaiting_start`: that drone's too) or after its End_Mission (MCP-BLK-6: not its).
"""

from __future__ import annotations

import math
import statistics
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, TypeVar

from mcp_conform.conformance._case_base import DatagramCaseBase
from mcp_conform.harness.driver import Datagram, read_header
from mcp_conform.harness.drone_players import Input, Mission, Withheld
from mcp_conform.harness.errors import CaseFailure, Inconclusive
from mcp_conform.judge import copies_by_number
from mcp_conform.judge.waypoints import FILE_FIELDS, f32
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import HEADER_SIZE, ITEM, Action

if TYPE_CHECKING:
    from mcp_conform.harness.manager_session import ManagerSession

F = TypeVar("F", bound=Callable[..., Any])
MIN_COPIES = int(SPEC.params["min_copies"])
_ACK = int(Action.ACK)
_START = int(Action.START_MISSION)
_END = int(Action.END_MISSION)
_LISTS = (int(Action.WP_LIST), int(Action.OBSTACLES_LIST))
_WP_ON = int(Action.WP_ON)
_WP_OFF = int(Action.WP_OFF)


def _hex(data: bytes, limit: int = 40) -> str:
    h = data[:limit].hex(" ")
    return h + (f" ... ({len(data)} bytes)" if len(data) > limit else f" ({len(data)} bytes)")


def item_differences(got: Any, want: Any) -> list[str]:
    """Fields of the file's item that the sent item does not carry (floats as float32)."""
    out = []
    for name in FILE_FIELDS:
        g, w = getattr(got, name), getattr(want, name)
        if isinstance(w, float):
            w = f32(w)
            same = g == w or (math.isnan(g) and math.isnan(w))
        else:
            same = g == w
        if not same:
            out.append(f"{name}={g!r} (file: {w!r})")
    return out


@dataclass
class Message:
    """One message of the manager (a new one) with its copies."""

    first: Datagram
    copies: list[Datagram] = field(default_factory=list)  # the first included

    @property
    def dst(self) -> int:
        assert self.first.header is not None
        return self.first.header[0]

    @property
    def seq(self) -> int:
        assert self.first.header is not None
        return self.first.header[2]

    @property
    def action(self) -> int:
        assert self.first.header is not None
        return self.first.header[3]

    @property
    def last(self) -> Datagram:
        return self.copies[-1]


def messages(m: Mission) -> list[Message]:
    """The manager's non-ACK messages in order of first arrival, copies grouped with the
    message they repeat: same (dst, seq), or, to a mission drone (whose ACK it awaits), same
    (dst, action, payload) while the earlier one has not been ACKed and was sent once under its
    number (or is such a chain already): a retransmission with a new seq, MCP-SEQ-2's business,
    as the trace monitor's ``_renumbered`` has it. An earlier one with copies that repeat its
    number was retransmitted as "Retransmissions of the same message are identified by
    repeating sequence number" says: the same command under a new number after them is a new
    message after a give-up (MCP-RTX-1's, ``judge.copies_by_number``), not a third copy. A
    broadcast is never ACKed: one with a new seq is a new message (MCP-DUP-2), however like the
    last it is (a mission of broadcast WP_Offs, each its own seq, was six "copies" of the first,
    MCP-RTX-4 warned: H-cmanager's C manager)."""
    out: list[Message] = []
    by_key: dict[tuple[int, int], Message] = {}
    for d in m.commands():
        h = d.header
        assert h is not None
        msg = by_key.get((h[0], h[2]))
        if msg is None and h[0] in m.drones:
            for cand in reversed(out):
                if (cand.dst == h[0] and cand.action == h[3] and cand.first.data[HEADER_SIZE:] == d.data[HEADER_SIZE:]
                        and not _acked_before(m, cand, d.t)):
                    if _renumbering(cand):
                        msg = cand
                    break
        if msg is None:
            msg = Message(d)
            out.append(msg)
        msg.copies.append(d)
        by_key[(h[0], h[2])] = msg
    return out


def _renumbering(msg: Message) -> bool:
    """``msg`` sent once under its number, or already again under new ones: a copy of it under a
    new number is a retransmission renumbered (``judge._monitor_rtx``'s ``_renumbered``)."""
    return len(msg.copies) == 1 or len({c.header[2] for c in msg.copies if c.header is not None}) > 1


def _sent_again(msg: Message, msgs: list[Message]) -> bool:
    """After its last copy, the same command to the same drone as a new message (a new number
    after copies that repeat ``msg``'s, :func:`messages`): the manager gave up the message, not
    the drone (the new one, given up too, tells so itself)."""
    body = msg.first.data[HEADER_SIZE:]
    return any(y is not msg and y.dst == msg.dst and y.action == msg.action and y.first.t > msg.last.t
               and y.first.data[HEADER_SIZE:] == body for y in msgs)


def withheld_copies(w: Withheld) -> list[Datagram]:
    """The withheld Start_Mission's copies (MCP-RTX-1/3, MCP-SEQ-2) counted by number
    (``judge.copies_by_number``): those that repeat its first's, or all of them where it was
    sent once and then renumbered."""
    return list(w.copies) if copies_by_number.renumbered(w.copies) else copies_by_number.by_number(w.copies)


def runner_ack_time(m: Mission, msg: Message) -> float | None:
    """When the runner first answered ``msg``: its earliest ACK of any copy's seq (``Mission.acks``,
    one ACK per copy, the earliest per seq kept: ``harness.drone_players``), or one of MCP-RTX-2's
    deliberate wrong ACKs from ``msg``'s drone that the manager could take for it — sent while
    ``msg`` awaited its ACK, or sent earlier and still unanswered by any other command to that
    drone (the wrong-source ACK from drone B, sent while the manager awaits drone A's ACK,
    reaches a manager that takes any ACK from the destination when it next sends to B: taking
    it is RTX-2's fault, not a new unicast before B's ACK, MCP-BLK-1). Not the wrong ACKs of a
    message the manager was seen to retransmit after them (``copy_after_wrong_acks``): they did
    not end it, and its answer is the right ACK (a runner held off the CPU may send that past
    the manager's retry limit: seed 118's drone, given up, looked answered by them); nor any
    wrong ACK before a copy of ``msg`` itself (the same: it did not end ``msg``). None of
    them where the second observation (``Mission.withheld_again``) proved the manager ignores a
    wrong ACK (:func:`wrong_acks_ignored`); its own wrong ACKs are like the first's otherwise."""
    times = [m.acks[k].t for c in msg.copies if c.header is not None and (k := (msg.dst, c.header[2])) in m.acks]
    for w in () if wrong_acks_ignored(m) else (m.withheld, *m.again_spoiled, m.withheld_again):
        after = w.copy_after_wrong_acks
        for a in w.wrong_acks:
            if a.src != msg.dst:
                continue
            if after is not None and after.header is not None and after.header[0] == msg.dst and any(
                    c.header is not None and c.header[2] == after.header[2] for c in msg.copies):
                continue  # the manager retransmitted ``msg`` after them: they did not end it (seed 118)
            if any(c.t > max(a.t, msg.first.t) for c in msg.copies):
                continue  # ``msg`` retransmitted after it: it did not end it (seed 90 of (0.3, 1.0))
            if a.t >= msg.first.t:
                times.append(a.t)
            elif not any(a.t <= d.t < msg.first.t for d in m.to_drone(msg.dst)):
                times.append(msg.first.t)
    return min(times) if times else None


def wrong_acks_ignored(m: Mission) -> bool:
    """MCP-RTX-2's second observation (``Mission.withheld_again``, made where the first
    Start_Mission's copies stopped right after the wrong ACKs) saw a copy after its own wrong
    ACKs: the manager does not take a wrong ACK for the answer, so the first's wrong ACKs ended
    nothing, and its Start_Mission's copies stopped at its retry limit (a limit of 2 retries:
    spec ``min_copies``, no violation): the drone was given up, not answered. Told by what the
    manager did with a second message, not by when it moved on (session 32's reverted try)."""
    return m.withheld_again.copy_after_wrong_acks is not None


def first_stopped_at_wrong_acks(m: Mission) -> bool:
    """The first Start_Mission's copies (at least ``min_copies``) stopped right after the wrong
    ACKs: taking them and a retry limit reached there look alike (the second observation tells)."""
    w = m.withheld
    return bool(w.drone is not None and w.wrong_acks and w.copy_after_wrong_acks is None
                and len(w.copies) >= MIN_COPIES and w.ended_before_wrong_acks([c.t for c in w.copies]) is None)


def again_untold(m: Mission) -> str | None:
    """Why MCP-RTX-2's second observation (``Mission.withheld_again``) tells nothing (None: it
    tells). The first proved the manager's limit reaches ``len(withheld.copies)`` copies; the
    second's wrong ACKs must go out after fewer copies of its message, while the next was due."""
    why = _again_untold(m)
    if why is not None and m.again_spoiled:
        why += (f" (and {len(m.again_spoiled)} message(s) before it: the wrong ACKs went out after as many "
                "copies as the first Start_Mission had, the runner's receiver behind)")
    return why


def _again_untold(m: Mission) -> str | None:
    a, limit = m.withheld_again, len(m.withheld.copies)
    if a.drone is None or not a.copies:
        return "the manager sent no new unicast after them to withhold"
    what = f"its {action_name(a.copies[0].action)} to drone {a.drone}"
    if not a.wrong_acks:
        return f"{what} came once, no second copy within {a.wrong_ack_wait:.2f} s (see MCP-RTX-1)"
    t_wrong = a.wrong_acks[0].t
    before = [c.t for c in a.copies if c.t <= t_wrong]
    if a.right_ack is not None and a.right_ack.t < t_wrong:
        return f"{what} was answered before the wrong ACKs went out"
    if len(before) >= limit:
        return (f"the wrong ACKs went out after {len(before)} copies of {what} (the runner's receiver "
                f"behind), where a limit of {limit} copies ends it too")
    stopped = a.ended_before_wrong_acks(before)
    if stopped is not None:
        return f"{what} had stopped before the wrong ACKs ({stopped})"
    return None


def action_name(action: int | None) -> str:
    return Action(action).name if action is not None and 0 <= action <= 9 else str(action)


def _acked_before(m: Mission, msg: Message, t: float) -> bool:
    at = runner_ack_time(m, msg)
    return at is not None and at < t


def gave_up(m: Mission, msg: Message, rto: float, msgs: list[Message] | None = None) -> bool:
    """The manager stopped retransmitting ``msg`` before any ACK of it (a retry limit,
    MCP-RTX-1's business) — not merely because the mission record ends. ``msgs``: ``messages(m)``
    when the caller has it (a caller asking of every message made it again for each: a
    150-waypoint mission's cases outlasted their time limit)."""
    acked = runner_ack_time(m, msg)
    gaps = [b.t - a.t for a, b in zip(msg.copies, msg.copies[1:], strict=False)]
    gap = statistics.median(gaps) if gaps else rto
    slack = 1.5 * gap + 0.05
    # moved on: a new unicast to a drone when the next copy was due (its retry limit), before
    # any ACK of it, and no copy after that (one still awaiting would be retransmitted later:
    # MCP-BLK-1's). Judged on what the manager did, not on when the runner's ACK went out.
    for y in messages(m) if msgs is None else msgs:
        if (y is not msg and y.dst in m.drones and y.first.t >= msg.last.t + 0.8 * gap - 0.015
                and (acked is None or y.first.t < acked)):
            return True
    if acked is None:
        return m.t_end - msg.last.t > slack
    right = [m.acks[k].t for c in msg.copies if c.header is not None and (k := (msg.dst, c.header[2])) in m.acks]
    if acked < min(right, default=acked) and (not right or min(right) > msg.last.t + gap - 0.015):
        # its earliest answer one of MCP-RTX-2's deliberate wrong ACKs, the right one after the
        # next copy was due: a manager that ignores the wrong ACK (as it must) reached its retry
        # limit at that timer, and the drone was given up -- one explanation, so not an answer
        # the flow rules may count (a runner seconds behind sent the wrong ACKs of the second
        # observation after the 13th and last copy of drone 2's WP_List, the right one 0.98 s
        # later: a false MCP-FLOW-3/5, simulator seeds 58, 68, 108, 193 of ``preempt=(0.5, 0.5)``)
        return True
    # no copy after the ACK, which came after the next copy was due: a retry limit reached at
    # that timer, before the ACK, is one explanation (a runner seconds behind ACKed the
    # manager's 13th and last WP_Off copy 0.28 s after it, at --rto 0.2, and the manager, done
    # with the others, exited: a false MCP-FLOW-3 and FLOW-5, simulator seed 73 of
    # ``preempt=(0.5, 0.5)``); within the clocks' 15 ms of that timer the give-up is still one
    # explanation (seed 108 c2 of (0.5, 0.5): the 13th copy's ACK 4 ms after the next was due)
    return acked > msg.last.t + gap - 0.015


def awaiting_until(m: Mission, msg: Message, rto: float, msgs: list[Message] | None = None) -> float:
    """The end of the time ``msg`` awaited its ACK (see the module docstring; ``msgs`` as
    :func:`gave_up` takes it)."""
    acked = runner_ack_time(m, msg)
    if acked is None or gave_up(m, msg, rto, msgs):
        return msg.last.t
    return acked


def abandoned(m: Mission, rto: float) -> set[int]:
    """Drones with a command whose retransmission stopped before any ACK of it; and the first
    Start_Mission's drone where its copies stopped right after the wrong ACKs, the second
    observation told nothing (``again_untold``), and the manager sent that drone nothing new
    after them: a retry limit reached there is one explanation, and under it the drone was
    given up (the flow rules fail only what every explanation breaks)."""
    msgs = messages(m)
    out = {msg.dst for msg in msgs if msg.dst in m.drones and gave_up(m, msg, rto, msgs) and not _sent_again(msg, msgs)}
    w = m.withheld
    if w.drone is not None and w.drone not in out and first_stopped_at_wrong_acks(m) and again_untold(m) is not None:
        start = next((x for x in msgs if x.dst == w.drone and any(c.index == w.copies[0].index for c in x.copies)), None)
        if not any(x.dst == w.drone and x is not start and x.first.t > w.wrong_acks[0].t for x in msgs):
            out.add(w.drone)
    return out


def to_mission(m: Mission, msgs: list[Message], drone: int, broadcast_id: int,
               rto: float | None = None) -> tuple[list[Message], list[Message]]:
    """D-11: the messages of ``msgs`` (``messages(m)``) that reach ``drone``'s mission -- those
    unicast to it, and each broadcast that came while its mission was on: from the runner's
    first answer to its first Start_Mission (:func:`runner_ack_time`: the manager's "after
    Start_Mission is ACKed", MCP-FLOW-4; that ACK is stamped before it leaves, so a broadcast
    that came at its time or before was sent before the ACK could reach the manager) until its
    first End_Mission came (in arrival order: the two may bear one timestamp) -- and the
    broadcasts that came outside that time (no command to it: for the evidence). With ``rto``,
    a broadcast that came while that Start_Mission awaited its answer (:func:`awaiting_start`)
    is a command to it too: MCP-BLK-3's, and its mission's (its list: one fault, one rule)."""
    start = next((x for x in msgs if x.dst == drone and x.action == _START), None)
    on = runner_ack_time(m, start) if start is not None else None
    waiting = awaiting_start(m, msgs, drone, broadcast_id, rto) if rto is not None else []
    ended = False
    mine: list[Message] = []
    outside: list[Message] = []
    for x in msgs:
        if x.dst == drone:
            mine.append(x)
            ended = ended or x.action == _END
        elif x.dst == broadcast_id:
            (mine if (on is not None and on < x.first.t and not ended) or any(x is y for y in waiting)
             else outside).append(x)
    return mine, outside


def awaiting_start(m: Mission, msgs: list[Message], drone: int, broadcast_id: int, rto: float) -> list[Message]:
    """MCP-BLK-3 and D-11: the broadcasts that came while ``drone``'s first Start_Mission awaited
    its answer -- after its first copy (in arrival order) and at the runner's first answer's time
    or before (:func:`runner_ack_time`; the ACK is stamped before it leaves), or, where the
    manager gave it up unanswered (its retry limit, MCP-RTX-1's), by its last copy
    (:func:`awaiting_until`). A broadcast goes to every drone: "does not send any subsequent MCP
    commands until an acknowledgement is received"."""
    k = next((k for k, x in enumerate(msgs) if x.dst == drone and x.action == _START), None)
    if k is None:
        return []
    start = msgs[k]
    until = awaiting_until(m, start, rto, msgs)
    return [x for x in msgs[k + 1:] if x.dst == broadcast_id and x.first.t <= until]


def decode_items(d: Datagram) -> tuple[Any, ...] | None:
    """The items of a WP_List/Obstacles_List/WP_On as the spec lays them out, or None when
    the payload does not fit (MCP-PAY-3/5's business)."""
    if d.msg is not None:
        p = d.msg.payload
        return (p,) if d.action == _WP_ON else tuple(p)
    return None


def unpack_items(region: bytes) -> list[Any]:
    from mcp_conform.spec.codec import MissionItem

    return [MissionItem._make(t) for t in ITEM.iter_unpack(region)]


def needs_scenario(kind: str) -> Callable[[F], F]:
    """A case that judges scenario ``kind`` (not the main one): the runner starts that
    scenario beside the main mission when the case is to run (``scenarios_beside_main``)."""
    def mark(fn: F) -> F:
        fn.mcp_scenario = kind  # type: ignore[attr-defined]
        return fn
    return mark


def scenarios_beside_main(config: Any, items: Sequence[Any]) -> set[str]:
    """The scenarios the cases of this run (pytest items) judge besides the main one, to
    run beside it on manager instances of their own (``harness.manager_side``; issue 23);
    none with ``--serial`` (every scenario after the one before, as before) or in a
    pytest-xdist worker (the workers share the cases out: a worker may not run the case)."""
    if config.getoption("mcp_serial", False) or hasattr(config, "workerinput"):
        return set()
    return {k for i in items if (k := getattr(getattr(i, "obj", None), "mcp_scenario", None))}


class ManagerCaseContext(DatagramCaseBase):
    """What a manager-role case sees (see the module docstring)."""

    subject = "the manager"
    session: ManagerSession

    def __init__(self, session: ManagerSession, case_id: str, rules: tuple[str, ...]) -> None:
        super().__init__(session, case_id, rules)

    @classmethod
    def prepare_session(cls, session: Any, config: Any, items: Sequence[Any]) -> None:
        """The scenarios its cases judge run beside the main one (issue 23)."""
        session.overlap = scenarios_beside_main(config, items)

    # ------------------------------------------------------------------ facts
    @property
    def challenge(self) -> int:
        return self.session.cfg.challenge

    def mission(self, kind: str = "main") -> Mission:
        return self.session.mission(kind)

    def require_observable(self, rule: str) -> None:
        obs = SPEC.rule(rule).observe.get(self.role)
        if obs is None:
            raise Inconclusive(f"{rule} does not apply to a Mission Manager")
        if obs.observable != "mcp":
            raise Inconclusive(f"{rule} is not observable on a Mission Manager: {obs.reason}")

    def require_challenge(self, rule: str, challenge: int) -> None:
        if self.challenge != challenge:
            raise Inconclusive(f"{rule} applies to challenge {challenge}; this run is challenge "
                               f"{self.challenge} (--challenge)")

    # ------------------------------------------------------------------ verify helpers
    def fail(self, rule: str, expected: str, actual: str, evidence: Sequence[str] = ()) -> CaseFailure:
        ev = list(evidence)
        m = self.session.missions.get("main")
        if m is not None and m.exit_code not in (None, 0) and m.output:
            ev.append(f"manager exited with code {m.exit_code}; output (last lines):\n    "
                      + "\n    ".join(m.output.splitlines()[-8:]))
        return CaseFailure(rule, expected, actual, ev)

    def expect_monitor_clean(self, rule: str) -> None:
        """The trace monitor found no violation of ``rule`` by the manager in the main mission
        (what is judged from traffic alone is the monitor's: docs/design.md, "The trace
        monitor")."""
        m = self.mission()
        bad = [v for v in m.monitor if v.rule == rule]
        if bad:
            v = bad[0]
            ev = [m.monitor_trace[i] for i, _ in v.evidence[:3] if 0 <= i < len(m.monitor_trace)]
            raise self.fail(rule, f"(trace monitor) {v.expected}",
                            f"{v.actual}" + (f" (+{len(bad) - 1} more)" if len(bad) > 1 else ""), ev)

    def inputs(self, rule: str, m: Mission | None = None) -> list[Input]:
        m = m or self.mission()
        got = [i for i in m.inputs if i.rule == rule]
        if not got and m.ready_unacked:
            raise Inconclusive(f"{rule}: no input of this rule was sent: {m.ready_unacked}, and each input "
                               "needs an ACKed Mission_Ready after it as its liveness probe (see MCP-ACK-1)")
        if not got:
            died = next((i for i in m.inputs if i.died or (i.probe is not None and not i.probe.acked)), None)
            why = f" (the inputs stopped after {died.label!r})" if died is not None else ""
            raise Inconclusive(f"{rule}: no input of this rule was sent{why}")
        return got

    def expect_survived(self, inputs: Sequence[Input], rule: str, *, live_rule: str = "MCP-ROB-5") -> None:
        """The manager stayed alive through each input and ACKed the probe after it."""
        for i in inputs:
            if i.died:
                death_rule = "MCP-ROB-1" if len(i.sent.data) < HEADER_SIZE else rule
                raise self.fail(death_rule, f"the manager survives input {i.label!r}", "the manager exited after it",
                                [f"input: {_hex(i.sent.data)}"] + self.session.node_evidence())
            if i.probe is not None and not i.probe.acked:
                raise self.fail(live_rule, f"an ACK of the next Mission_Ready after input {i.label!r}",
                                f"no ACK of seq {i.probe.seq} after {len(i.probe.copies)} copies "
                                f"{self.rto:g} s apart", [f"input: {_hex(i.sent.data)}"])

    def expect_not_acked(self, inputs: Sequence[Input], rule: str) -> None:
        """No ACK names any input's seq (big-endian, to its src) within the ACK window (D-6)."""
        m = self.mission()
        for i in inputs:
            hdr = read_header(i.sent.data)
            if hdr is None:
                continue
            _, src, seq, _ = hdr
            replies = [d for d in m.from_manager() if d.is_ack_like and d.acked_seq() == seq
                       and d.header is not None and d.header[0] == src
                       and i.sent.t <= d.t <= i.sent.t + self.ack_window]
            if replies:
                d = replies[0]
                raise self.fail(rule, f"input {i.label!r} (seq {seq}) not ACKed within {self.ack_window:g} s",
                                f"ACKed {d.t - i.sent.t:.3f} s after it",
                                [f"input: {_hex(i.sent.data)}", f"reply: {d.describe()}"])

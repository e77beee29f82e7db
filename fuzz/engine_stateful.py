"""The stateful engine: hypothesis plays the manager across a mission (issue 11 item 3).

:class:`ManagerMachine` is a ``RuleBasedStateMachine`` whose rules are what a manager (and
a confused network) may do to a drone: commands of every kind (Start_Mission, WP_List,
WP_On, WP_Off, Obstacles_List, Mav_Passthrough), End_Mission, broadcasts, duplicates and
late copies, a jump of the sequence number to just before the wrap, messages from other
sources and to other IDs, ACKs sent to the node, malformed datagrams from the spec's
strategies, and a restart whose Mission_Ready ACKs are withheld for a few copies. After
every step a liveness probe follows and every oracle judges (``fuzz.oracles``: replies,
liveness, process, vehicle deliveries, the trace monitor); a flaw fails the step, so
hypothesis shrinks the program to its shortest form and prints it. The engine then hands
the failing example's datagrams to triage (confirmed on a fresh node, shrunk again as a
datagram sequence, written with the printed program).

Workers share hypothesis's example database (``--db DIR`` or ``--db redis://HOST:PORT/N``):
a program that failed on one worker is replayed first by the others.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Callable
from dataclasses import replace
from typing import Any
from urllib.parse import urlparse

from hypothesis import HealthCheck, Phase, settings
from hypothesis import seed as hypothesis_seed
from hypothesis import strategies as st
from hypothesis.database import DirectoryBasedExampleDatabase, ExampleDatabase
from hypothesis.errors import Flaky
from hypothesis.reporting import with_reporter
from hypothesis.stateful import (
    RuleBasedStateMachine,
    initialize,
    invariant,
    precondition,
    rule,
    run_state_machine_as_test,
)

from fuzz.config import FuzzConfig
from fuzz.engine_stateless import EngineStats
from fuzz.oracles import (
    DeliveryLedger,
    Flaw,
    Input,
    MonitorOracle,
    judge_exchange,
    judge_liveness,
    judge_withheld,
)
from fuzz.replay import WITHHOLD, frame_token, settle_vehicle, vehicle_counts
from fuzz.target import FuzzTarget
from fuzz.target_base import DIED, MISSION_ENDED
from fuzz.triage import Triage
from spec.codec import Action, Message, encode
from spec.strategies import malformed_datagrams, mission_items
from vehicle.probe import make_probe

__all__ = ["ManagerMachine", "StatefulEngine", "check_database", "open_database"]

COMMANDS = (Action.START_MISSION, Action.WP_LIST, Action.WP_ON, Action.WP_OFF,
            Action.OBSTACLES_LIST, Action.MAV_PASSTHROUGH)
OTHER_SRC = 0x7777
SEQ_GAP = 1000  # numbers skipped between programs
STEPS = 24  # steps per program at most
END_ODDS = 8  # one End_Mission move in this many ends the mission
CHUNK = 10  # examples per hypothesis run (the budget is checked between steps, too)
TICK_S = 0.25  # progress updates from inside a run, at most this often
#: How long hypothesis may shrink a failing program. Each shrink step replays a program
#: against the node (seconds each), and triage minimises the datagrams afterwards anyway;
#: unbounded, shrinking took most of a campaign (a DUP-1 failure found in the 21st program
#: was shrunk for 30 s).
SHRINK_S = 5.0


class OutOfBudget(BaseException):  # noqa: N818 - not an error: a budget is spent
    """Raised from inside a step once the campaign's deadline, its case budget or a stop
    request is reached (``campaign_over``), or once a failure has been shrunk for
    ``SHRINK_S``: a ``BaseException``, so hypothesis neither counts it as a failure nor
    shrinks it, and a run ends within one step."""

    def __init__(self, campaign_over: bool) -> None:
        super().__init__("campaign budget spent" if campaign_over else "shrink budget spent")
        self.campaign_over = campaign_over


class FlawFound(AssertionError):
    """A step broke a rule: the flaw, and every datagram the program sent."""

    def __init__(self, flaw: Flaw, sent: list[bytes], scenario: str | None = None) -> None:
        super().__init__(f"{flaw.rule}: expected {flaw.expected}; actual {flaw.actual}")
        if CTX is not None:
            CTX.failed(flaw, sent, scenario)
        self.flaw = flaw
        self.sent = sent
        self.scenario = scenario


def redis_address(spec: str) -> tuple[str, int, int]:
    """``redis://HOST:PORT/N`` -> (host, port, db); ValueError naming what is wrong."""
    u = urlparse(spec)
    if not u.hostname or not u.port:
        raise ValueError(f"--db: {spec!r} is not redis://HOST:PORT/N")
    try:
        db = int((u.path or "/0").strip("/") or 0)
    except ValueError:
        raise ValueError(f"--db: {spec!r}: the database number is not an integer") from None
    return u.hostname, u.port, db


def check_database(spec: str) -> None:
    """ValueError naming what is wrong with ``--db``."""
    if spec.startswith("redis://"):
        redis_address(spec)
        try:
            import redis  # noqa: F401
        except ImportError:
            raise ValueError("--db redis://...: the 'redis' package is not installed") from None
    elif "://" in spec:
        raise ValueError(f"--db: {spec!r} is neither a directory nor redis://HOST:PORT/N")


def open_database(spec: str | None) -> ExampleDatabase | None:
    """hypothesis's example database for ``--db`` (a directory, or Redis)."""
    if spec is None:
        return None
    if spec.startswith("redis://"):
        from hypothesis.extra.redis import RedisExampleDatabase
        from redis import Redis

        host, port, db = redis_address(spec)
        return RedisExampleDatabase(Redis(host=host, port=port, db=db), key_prefix=b"mcp-fuzz:")
    return DirectoryBasedExampleDatabase(spec)


class _Context:
    """What the machine plays against (set by the engine before each hypothesis run)."""

    def __init__(self, target: FuzzTarget, stats: EngineStats,
                 out_of_budget: Callable[[], bool] = lambda: False,
                 tick: Callable[[EngineStats], None] | None = None) -> None:
        self.target = target
        self.stats = stats
        self.out_of_budget = out_of_budget
        self.tick = tick
        self._last_tick = 0.0
        self.examples = 0
        self.ledger = DeliveryLedger(target.node_id, target.broadcast_id)
        self.monitor = MonitorOracle(target.node_id, target.rto, target.ack_window,
                                     target.broadcast_id, target.driver.listen)
        self.restarts_seen = target.restarts
        # the first flaws steps raised, with what the program had sent (hypothesis keeps only
        # the failures it can replay; triage confirms the others by itself)
        self.raised: list[tuple[Flaw, list[bytes], str | None]] = []
        self.shrink_until: float | None = None

    def failed(self, flaw: Flaw, sent: list[bytes], scenario: str | None) -> None:
        """A step failed: remember it (the first 20), and start the shrink budget."""
        if len(self.raised) < 20:
            self.raised.append((flaw, list(sent), scenario))
        if self.shrink_until is None:
            self.shrink_until = time.monotonic() + SHRINK_S

    def smallest_failure(self) -> tuple[Flaw, list[bytes], str | None] | None:
        """Of the failures seen in this run, the shortest one under the first one's rule
        (what shrinking had reached when it was cut short)."""
        if not self.raised:
            return None
        rule = self.raised[0][0].rule
        return min((r for r in self.raised if r[0].rule == rule), key=lambda r: len(r[1]))

    def checkpoint(self) -> None:
        """Between steps: progress for the live display (a few times a second), and
        :class:`OutOfBudget` once the budget is spent (issue 18 item 11: a 10-s campaign
        had run 80 s, shrinking one failure while the display stayed at 0)."""
        now = time.monotonic()
        if self.tick is not None and now - self._last_tick >= TICK_S:
            self._last_tick = now
            self.tick(self.stats)
        if self.out_of_budget():
            raise OutOfBudget(campaign_over=True)
        if self.shrink_until is not None and now >= self.shrink_until:
            raise OutOfBudget(campaign_over=False)

    def new_monitor(self) -> None:
        t = self.target
        self.monitor = MonitorOracle(t.node_id, t.rto, t.ack_window, t.broadcast_id, t.driver.listen)

    def fresh_node(self) -> None:
        """A node that has not ended its mission, with oracles that know it."""
        t = self.target
        if t.spawned and (t.ended or not t.alive()):
            t.restart(MISSION_ENDED if t.ended and t.alive() else DIED)
        if t.restarts != self.restarts_seen:
            self.restarts_seen = t.restarts
            self.ledger = DeliveryLedger(t.node_id, t.broadcast_id)
            self.monitor = MonitorOracle(t.node_id, t.rto, t.ack_window, t.broadcast_id, t.driver.listen)
            t.traffic.drain()


CTX: _Context | None = None


class ManagerMachine(RuleBasedStateMachine):
    """The manager's moves against one drone (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__()
        assert CTX is not None, "ManagerMachine runs under StatefulEngine"
        self.ctx = CTX
        self.ctx.examples += 1
        self.ctx.fresh_node()
        self.t = self.ctx.target
        self.sent: list[bytes] = []
        self.history: list[bytes] = []  # new unicast messages to the node, in order
        self.tokens = 0
        self.ended = False
        self.wrapped = False
        self.scenario: str | None = None  # how the node was started, when not plainly
        # each program numbers its messages afresh, away from the wrap, and is judged by a
        # fresh monitor: one program's numbers never alias another's in the trace
        drv = self.t.driver
        for src in (drv.our_id, OTHER_SRC):  # forward only: a lower number is a wrap
            drv.set_seq(drv.peek_seq(src) + SEQ_GAP, src)
        self.t.traffic.drain()
        self.ctx.new_monitor()

    # ------------------------------------------------------------------ helpers
    def _token(self) -> str:
        self.tokens += 1
        return f"s{self.ctx.examples}x{self.tokens}"

    def _message(self, action: Action, dst: int, src: int, items: list[Any]) -> bytes:
        drv = self.t.driver
        seq = drv.next_seq(src)
        if action == Action.MAV_PASSTHROUGH:
            payload: Any = make_probe(self._token())
        elif action in (Action.WP_LIST, Action.OBSTACLES_LIST):
            payload = tuple(items)
        elif action == Action.WP_ON:
            payload = items[0] if items else None
        else:
            payload = None
        if action == Action.WP_ON and payload is None:
            action, payload = Action.WP_OFF, None
        return encode(Message(dst, src, seq, action, payload))

    def _step(self, datagrams: list[bytes]) -> None:
        """Send, probe, judge; a flaw fails the step (hypothesis then shrinks)."""
        t, drv, ctx = self.t, self.t.driver, self.ctx
        ctx.checkpoint()
        mark = drv.mark()
        inputs = []
        for data in datagrams:
            sent = drv.send_raw(data)
            inp = Input.of(data)
            inputs.append(inp)
            self.sent.append(data)
            token = frame_token(data) if inp.header and inp.header[3] == Action.MAV_PASSTHROUGH else None
            ctx.ledger.sent(len(self.sent) - 1, inp, token)
            m = inp.msg
            if m is not None and m.action != Action.ACK and m.dst == t.node_id and m.src != t.node_id:
                drv.wait_for(drv.ack_for(sent), max(t.rto, 0.5), mark)
        probe = t.probe()
        ctx.ledger.sent(len(self.sent), Input.of(probe.sent.data), None)
        ctx.stats.cases += len(datagrams)
        flaws = judge_exchange(inputs, t, mark, probe)
        flaws += ctx.monitor.feed(t.traffic.drain())
        if flaws:
            raise FlawFound(self._absolute(flaws[0], len(self.sent) - len(datagrams)), list(self.sent),
                            self.scenario)

    def _absolute(self, f: Flaw, offset: int) -> Flaw:
        """The flaw's culprit as an index into everything this program sent."""
        if f.datagram is not None:
            idx = max((i for i, d in enumerate(self.sent) if d == f.datagram), default=None)
            return replace(f, culprit=idx)
        return replace(f, culprit=None if f.culprit is None else f.culprit + offset)

    # ------------------------------------------------------------------ rules
    @initialize()
    def begin(self) -> None:
        self.ctx.fresh_node()

    @precondition(lambda self: not self.ended)
    @rule(action=st.sampled_from(COMMANDS), items=st.lists(mission_items(), max_size=2),
          copies=st.integers(1, 3))
    def command(self, action: Action, items: list[Any], copies: int) -> None:
        """A new command to the node, sent ``copies`` times as a manager whose ACKs were lost
        would (every copy ACKed, MCP-ACK-1; delivered once, MCP-DUP-1/2)."""
        data = self._message(action, self.t.node_id, self.t.driver.our_id, items)
        self.history.append(data)
        self._step([data] * copies)

    @precondition(lambda self: not self.ended and bool(self.history))
    @rule()
    def duplicate(self) -> None:
        """The last command again, same bytes (ACKed again, not delivered again: MCP-DUP-1)."""
        self._step([self.history[-1]])

    @precondition(lambda self: not self.ended and len(self.history) >= 2)
    @rule(back=st.integers(2, 4))
    def late_copy(self, back: int) -> None:
        """A late copy of an older command (MCP-DUP-4: either way, but ACKed)."""
        self._step([self.history[-min(back, len(self.history))]])

    @precondition(lambda self: not self.ended)
    @rule(action=st.sampled_from(COMMANDS))
    def broadcast(self, action: Action) -> None:
        """A broadcast: delivered, never ACKed (MCP-ACK-4)."""
        self._step([self._message(action, self.t.broadcast_id, self.t.driver.our_id, [])])

    @precondition(lambda self: not self.ended)
    @rule(action=st.sampled_from(COMMANDS), offset=st.integers(1, 3))
    def to_other_id(self, action: Action, offset: int) -> None:
        """A unicast to another drone: neither ACKed nor acted on (MCP-ACK-5)."""
        dst = (self.t.node_id + offset) & 0xFFFF
        if dst in (self.t.broadcast_id, self.t.driver.our_id):
            dst = (self.t.node_id + 10) & 0xFFFF
        self._step([self._message(action, dst, self.t.driver.our_id, [])])

    @precondition(lambda self: not self.ended)
    @rule(action=st.sampled_from(COMMANDS))
    def other_source(self, action: Action) -> None:
        """A command from another source (ACKed to that source; duplicates per source, MCP-DUP-3)."""
        data = self._message(action, self.t.node_id, OTHER_SRC, [])
        self._step([data])

    @precondition(lambda self: not self.ended)
    @rule(seq=st.integers(0, 0xFFFF))
    def ack_to_node(self, seq: int) -> None:
        """An ACK to the node, naming anything: never ACKed (MCP-ACK-6)."""
        drv = self.t.driver
        self._step([encode(Message(self.t.node_id, drv.our_id, drv.next_seq(), Action.ACK, seq))])

    @precondition(lambda self: not self.ended and not self.wrapped)
    @rule(before=st.integers(0, 2))
    def near_wrap(self, before: int) -> None:
        """The manager's sequence number jumps to just before 65535, so the next commands
        wrap to 0 (MCP-SEQ-3: 0 after 65535 is new); once per program, so no number is
        reused for another message."""
        self.wrapped = True
        self.t.driver.set_seq(0xFFFF - before)

    @precondition(lambda self: not self.ended)
    @rule(data=malformed_datagrams())
    def garbage(self, data: bytes) -> None:
        """A malformed datagram: discarded silently, the node stays live (MCP-ROB-*)."""
        self._step([data])

    @precondition(lambda self: not self.ended and self.t.spawned and len(self.history) >= 2)
    @rule(now=st.integers(0, END_ODDS - 1))
    def end_mission(self, now: int) -> None:
        """End_Mission (now and then: it costs a fresh node for the next program): ACKed;
        the mission is over."""
        if now != END_ODDS - 1:
            return
        data = self._message(Action.END_MISSION, self.t.node_id, self.t.driver.our_id, [])
        t, drv = self.t, self.t.driver
        mark = drv.mark()
        sent = drv.send_raw(data)
        self.sent.append(data)
        self.ctx.stats.cases += 1
        got = drv.wait_for(drv.ack_for(sent), max(t.rto, 0.5) * 3, mark)
        self.ended = True
        t.session.ended = True
        if got is None and t.alive():
            raise FlawFound(Flaw("MCP-ACK-1", f"an ACK of End_Mission seq {sent.seq}",
                                 "no ACK of End_Mission", culprit=len(self.sent) - 1), list(self.sent),
                            self.scenario)

    @precondition(lambda self: not self.ended and self.t.spawned and len(self.history) >= 2)
    @rule(copies=st.integers(1, 3), now=st.integers(0, END_ODDS - 1))
    def restart_withholding_acks(self, copies: int, now: int) -> None:
        """Now and then a fresh node whose Mission_Ready ACKs are withheld for a few copies,
        then given out of order (the monitor judges the copies: MCP-RTX-1/2, MCP-SEQ-2)."""
        if now != END_ODDS - 1:
            return
        t = self.t
        w = t.restart_withholding(copies)
        self.ctx.restarts_seen = t.restarts
        self.ctx.ledger = DeliveryLedger(t.node_id, t.broadcast_id)  # a new node delivers afresh
        self.history.clear()
        self.sent.clear()  # what the new node was sent starts here
        self.scenario = f"{WITHHOLD}{copies}"
        flaw = judge_withheld(w.copies, w.after_wrong_ack, copies, t.alive())
        if flaw is not None:
            raise FlawFound(flaw, [], scenario=self.scenario)
        self._step([])

    @precondition(lambda self: self.ended)
    @rule()
    def mission_over(self) -> None:
        """Nothing is sent after End_Mission (D-6: the node may no longer receive)."""

    @invariant()
    def node_alive(self) -> None:
        if not self.ended and not self.t.alive():
            raise FlawFound(judge_liveness([Input.of(d) for d in self.sent[-1:]], False, self.t.fate())
                            or Flaw("MCP-ROB-5", "a live node", "the node died"), list(self.sent),
                            self.scenario)

    def teardown(self) -> None:
        """Once every forward has arrived (a sentinel frame behind them), the vehicle's record
        is judged: each frame as often as the duplicate rules say (MCP-DUP-1/2, MCP-SEQ-3,
        MCP-PAY-8); judged here only, so a failing program fails in the same place each time."""
        ctx, t = self.ctx, self.t
        if t.vehicle is None or self.ended or not t.alive() or not ctx.ledger.expected:
            return
        settled = settle_vehicle(t, ctx.ledger, "t")
        flaws = ctx.ledger.judge(vehicle_counts(t), settled=settled)
        ctx.ledger.expected.clear()
        if flaws:
            raise FlawFound(self._absolute(flaws[0], 0), list(self.sent), self.scenario)


class StatefulEngine:
    """Runs ``ManagerMachine`` in chunks of examples until the budget is spent."""

    def __init__(self, target: FuzzTarget, triage: Triage, cfg: FuzzConfig) -> None:
        self.target = target
        self.triage = triage
        self.cfg = cfg
        self.stats = EngineStats()
        self.database = open_database(cfg.db)
        self.programs: list[str] = []
        self.first_failure_example: int | None = None
        self.flaky: list[str] = []
        self.monitor_available = False

    def _settings(self, chunk: int) -> settings:
        phases = [Phase.reuse, Phase.generate, Phase.shrink] if chunk == 0 else [Phase.generate, Phase.shrink]
        if self.cfg.extra.get("reuse_only"):
            phases = [Phase.reuse, Phase.shrink]
        return settings(max_examples=CHUNK, stateful_step_count=STEPS, deadline=None,
                        database=self.database, phases=phases, print_blob=False,
                        suppress_health_check=list(HealthCheck), report_multiple_bugs=False)

    def run(self, deadline: float, max_cases: int | None,
            tick: Callable[[EngineStats], None] | None = None,
            stop: Callable[[], bool] = lambda: False) -> EngineStats:
        global CTX
        st = self.stats
        ctx = _Context(self.target, st, tick=tick, out_of_budget=lambda: (
            time.monotonic() >= deadline or (max_cases is not None and st.cases >= max_cases) or stop()))
        CTX = ctx
        chunk = 0
        try:
            while (time.monotonic() < deadline and (max_cases is None or st.cases < max_cases)
                   and not stop()):
                t0 = time.monotonic()
                out = False
                report: list[object] = []
                machine = hypothesis_seed(self.cfg.seed * 1000 + self.cfg.worker * 100 + chunk)(
                    type("ManagerMachine", (ManagerMachine,), {}))
                failure: FlawFound | None = None
                try:
                    with with_reporter(report.append):
                        run_state_machine_as_test(machine, settings=self._settings(chunk))
                except FlawFound as exc:
                    failure = exc
                    # hypothesis attaches the shortest program to the exception it raises
                    report.extend(getattr(exc, "__notes__", []))
                except Flaky as exc:
                    # a program that failed once and not the same way again: hypothesis cannot
                    # shrink it, triage may still confirm what was first seen
                    self.flaky.append(str(exc)[:500])
                    if ctx.raised:
                        failure = FlawFound(*ctx.raised[0])
                except OutOfBudget as exc:
                    # a budget ran out mid-run (perhaps while shrinking): the shortest failure
                    # seen goes to triage, which minimises its datagrams itself
                    out = exc.campaign_over
                    smallest = ctx.smallest_failure()
                    if smallest is not None:
                        failure = FlawFound(*smallest)
                st.seconds += time.monotonic() - t0
                st.batches += 1
                chunk += 1
                ctx.raised.clear()
                ctx.shrink_until = None
                if failure is not None:
                    st.flaws += 1
                    if self.first_failure_example is None:
                        self.first_failure_example = ctx.examples
                    program = "\n".join(str(r) for r in report).strip() or None
                    if program:
                        self.programs.append(program)
                    inputs = [Input.of(d) for d in failure.sent]
                    flaw = failure.flaw
                    self.triage.consider(flaw, inputs, "paced", program=program, scenario=failure.scenario)
                    ctx.fresh_node()
                    if self.cfg.extra.get("reuse_only"):
                        break
                if tick is not None:
                    tick(st)
                if self.cfg.extra.get("reuse_only") or out:
                    break
        finally:
            self.raised = ctx.raised
            self.monitor_available = ctx.monitor.available
            CTX = None
            with contextlib.suppress(Exception):
                self.target.traffic.drain()
        st.restarts = self.target.restarts
        return st

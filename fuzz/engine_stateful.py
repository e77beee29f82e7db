"""The stateful engine: programs of a manager's moves across a mission, pipelined (issue 11
item 3, issue 36 item 4).

A program (``fuzz.programs``: commands of every kind and their copies, duplicates and late
copies, broadcasts, messages to other IDs and from other sources, ACKs to the node, a jump
of the sequence number to the wrap, malformed datagrams, now and then a fresh node whose
Mission_Ready ACKs are withheld or an End_Mission) is sent back to back, as the stateless
engine sends a batch: nothing waits for an ACK between moves. One liveness probe follows the
program; its ACK proves the node live and, since a node handles its datagrams in order, that
every ACK it was going to send for the program has been sent. Each ACK is then tied to what
it answers by the sequence number it names (``fuzz.oracles.judge_exchange``, the conformance
batch's attribution), and every oracle judges: replies, liveness, process, the trace
monitor, the vehicle's record (``DeliveryLedger``: each frame as often as the duplicate
rules say, judged once the node's forwards have settled) and the copies of each command:
each copy is ACKed again (MCP-ACK-1), observed as the rule says — a copy left unanswered is
sent again every ``--rto`` up to ``ACK_COPIES`` copies before it is a finding, so a node
that lost one datagram of a burst is not blamed, and a healthy node pays nothing.

Before (one probe and one ACK wait per step, hypothesis drawing each step): 90-270 cases/s;
the faults that need a sequence (a message then its copy; a seq walked to the wrap) were
too slow to reach within a campaign's budget. A flaw goes to triage with the datagrams of
its program up to the culprit (confirmed on a fresh node, shrunk, grouped) and the program
printed; the program is saved in the example database (``--db DIR`` or ``--db
redis://HOST:PORT/N``, hypothesis's), whose programs every worker plays first.
"""

from __future__ import annotations

import contextlib
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any

from hypothesis.database import DirectoryBasedExampleDatabase, ExampleDatabase

from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.drone_target import FuzzTarget
from mcp_conform.fuzz.loop import TICK_S, EngineStats
from mcp_conform.fuzz.oracles import (
    DeliveryLedger,
    Flaw,
    Input,
    MonitorOracle,
    acked_seq,
    judge_exchange,
    judge_withheld,
)
from mcp_conform.fuzz.programs import Move, ProgramGenerator, dumps, loads, program_text
from mcp_conform.fuzz.replay import WITHHOLD, frame_token, settle_vehicle, vehicle_counts
from mcp_conform.fuzz.target_base import AFTER_FLAW, DIED, MISSION_ENDED, NEW_TURN, WITHHELD_START
from mcp_conform.fuzz.triage import Triage
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.spec.generators import random_malformed, random_message
from mcp_conform.vehicle.probe import make_probe

__all__ = ["ACK_COPIES", "OutOfBudget", "StatefulEngine", "check_database", "judge_copies",
           "open_database"]

OTHER_SRC = 0x7777
SEQ_GAP = 1000  # numbers skipped between programs: one program's never alias another's
#: Copies of a command left unanswered sent in all before its missing ACK is a finding:
#: MCP-ACK-1's observation ("retransmitting it every --rto as a manager would, up to 5
#: copies").
ACK_COPIES = 5
COPY_RECHECKS = 3  # unanswered copies observed per program at most (a lost datagram each)
#: With the vehicle, its record is judged for under-delivery (a frame that never arrived:
#: MCP-DUP-2, MCP-SEQ-3) once the forwards have settled: a sentinel frame behind them, sent
#: after programs totalling this long, and before the node is restarted or ends its mission.
SETTLE_S = 0.5
DB_KEY = b"mcp-fuzz/stateful/programs"
_ACK = int(Action.ACK)
_PASSTHROUGH = int(Action.MAV_PASSTHROUGH)


class OutOfBudget(BaseException):  # noqa: N818 - not an error: a budget is spent
    """Raised from inside a step once the campaign's deadline, its case budget or a stop
    request is reached (``campaign_over``), or once a failure has been shrunk for long
    enough: a ``BaseException``, so hypothesis neither counts it as a failure nor shrinks
    it, and a run ends within one step (the Nsqd engine's, ``fuzz.nsqd_stateful``)."""

    def __init__(self, campaign_over: bool) -> None:
        super().__init__("campaign budget spent" if campaign_over else "shrink budget spent")
        self.campaign_over = campaign_over


#: the URL schemes redis-py's ``Redis.from_url`` takes (``redis://[[user]:password@]host[:port][/db]``,
#: ``rediss://`` for TLS, ``unix://path``)
REDIS_SCHEMES = ("redis://", "rediss://", "unix://")


def check_database(spec: str) -> None:
    """ValueError naming what is wrong with ``--db``: a Redis URL redis-py reads, or a directory."""
    if spec.startswith(REDIS_SCHEMES):
        try:
            import redis
        except ImportError:
            raise ValueError("--db redis://...: the 'redis' package is not installed "
                             "(pip install 'centmesh-mcp-conform[redis]')") from None
        try:
            redis.Redis.from_url(spec).close()
        except ValueError as exc:
            raise ValueError(f"--db: not a Redis URL: {str(exc).splitlines()[0]}") from None
    elif "://" in spec:
        raise ValueError(f"--db: {spec!r} is neither a directory nor a Redis URL ({', '.join(REDIS_SCHEMES)})")


def open_database(spec: str | None) -> ExampleDatabase | None:
    """hypothesis's example database for ``--db`` (a directory, or Redis by redis-py's own URL
    parsing: a password or a TLS URL is kept, as ``mcp-fuzz``'s reachability check read it)."""
    if spec is None:
        return None
    if spec.startswith(REDIS_SCHEMES):
        from hypothesis.extra.redis import RedisExampleDatabase
        from redis import Redis

        return RedisExampleDatabase(Redis.from_url(spec), key_prefix=b"mcp-fuzz:")
    return DirectoryBasedExampleDatabase(spec)


def _must_ack(inp: Input, node_id: int, broadcast_id: int) -> bool:
    """A message a correct node ACKs, every copy (MCP-ACK-1; as ``fuzz.oracles`` says)."""
    m = inp.msg
    return (m is not None and m.action != _ACK and m.dst == node_id
            and m.src not in (node_id, broadcast_id))


def judge_copies(inputs: list[Input], replies: list[Any], node_id: int, broadcast_id: int) -> list[int]:
    """The first copy left unanswered of each command some of whose copies were ACKed: the
    node ACKed fewer datagrams naming (src, seq) than were sent with it (MCP-ACK-1: "every
    later copy is ACKed again"). A command none of whose copies was ACKed is
    ``judge_replies``'s (MCP-ACK-1 too). Indices into ``inputs``; a candidate only, until
    observed as the rule says (:meth:`StatefulEngine._copy_flaws`)."""
    sent: dict[tuple[int, int], list[int]] = {}
    for i, inp in enumerate(inputs):
        if _must_ack(inp, node_id, broadcast_id):
            m = inp.msg
            assert m is not None
            sent.setdefault((m.src, m.seq), []).append(i)
    acks: dict[tuple[int, int], int] = {}
    for d in replies:
        seq = acked_seq(d)
        if seq is not None:
            key = (d.header[0], seq)
            acks[key] = acks.get(key, 0) + 1
    out = []
    for key, idx in sent.items():
        n = acks.get(key, 0)
        if 0 < n < len(idx):
            out.append(idx[n])
    return sorted(out)


@dataclass
class _Window:
    """What the vehicle's record is judged over: the datagrams sent since the last settle,
    and where each program began among them."""

    sent: list[bytes] = field(default_factory=list)
    starts: list[tuple[int, list[Move], str | None]] = field(default_factory=list)
    since: float = field(default_factory=time.monotonic)

    def program_of(self, index: int) -> tuple[int, list[Move], str | None]:
        return max((s for s in self.starts if s[0] <= index), key=lambda s: s[0],
                   default=(0, [], None))


class StatefulEngine:
    """Plays programs against one drone until the budget is spent (see the module docstring)."""

    def __init__(self, target: FuzzTarget, triage: Triage, cfg: FuzzConfig) -> None:
        self.target = target
        self.triage = triage
        self.cfg = cfg
        self.stats = EngineStats()
        self.database = open_database(cfg.db)
        self.gen = ProgramGenerator(cfg.seed, cfg.worker, restarts=target.spawned)
        self.programs: list[str] = []  # the failing programs, printed
        self.played = 0
        self.first_failure_example: int | None = None
        self.flaky: list[str] = []
        self.monitor_available = False
        self._tokens = 0
        self._restarts_seen = target.restarts
        self._flagged: set[bytes] = set()  # over-delivered frames already sent to triage
        self._new_oracles()

    # ------------------------------------------------------------------ oracles
    def _new_oracles(self) -> None:
        t = self.target
        self.ledger = DeliveryLedger(t.node_id, t.broadcast_id)
        self.monitor = MonitorOracle(t.node_id, t.rto, t.ack_window, t.broadcast_id, t.driver.listen)
        self.monitor_available = self.monitor.available
        self.window = _Window()

    def _fresh_node(self) -> None:
        """A node that has not ended its mission, with oracles that know it."""
        t = self.target
        if t.spawned and (t.ended or not t.alive()):
            self._restart(MISSION_ENDED if t.ended and t.alive() else DIED)
        if t.restarts != self._restarts_seen:
            self._restarts_seen = t.restarts
            self._new_oracles()
            t.traffic.drain()

    def _restart(self, reason: str, restart: Callable[[], Any] | None = None) -> Any:
        """A fresh node (``restart``: the target's own way, else ``target.restart(reason)``) and
        oracles that know it from its start: the ledger (MCP-DUP-1's premise is what the node
        was sent) learns what the startup sent it (Start_Mission from our src: a seq the
        node's duplicate check and wrap go by, MCP-DUP-2, MCP-SEQ-3), nothing of what earlier
        nodes were sent. What ``restart`` returned."""
        t = self.target
        t.traffic.drain()  # the node before's
        got = None
        if restart is None:
            t.restart(reason)
        else:
            got = restart()
        self._restarts_seen = t.restarts
        self._new_oracles()
        for r in t.traffic.drain():
            if r.direction == "tx":
                self.ledger.sent(-1, Input.of(r.data), None)
        return got

    # ------------------------------------------------------------------ the run
    def run(self, deadline: float, max_cases: int | None,
            tick: Callable[[EngineStats], None] | None = None,
            stop: Callable[[], bool] = lambda: False) -> EngineStats:
        st = self.stats
        self._over = lambda: st.spent(deadline, max_cases, stop)
        if self.cfg.engine == "both" and self.target.spawned:
            # the stateless turn's cases went to this node, and the ledger knows none of them:
            # a header field at a boundary (seq 0xFFFF from our own src) left a seq-no-wrap
            # node taking every later message of ours for a duplicate, each program's
            # under-delivery a flaw no fresh node reproduced (2-9 thousand cases of unconfirmed
            # flaws before the wrap was found; MCP-DUP-1's premise is what the node was sent)
            self._restart(NEW_TURN)
        saved = self._saved_programs()
        reuse_only = bool(self.cfg.extra.get("reuse_only"))
        last_tick = 0.0
        try:
            while not self._over():
                if saved:
                    moves = saved.pop(0)
                elif reuse_only:
                    break
                else:
                    moves = self.gen.program()
                t0 = time.monotonic()
                failure = self._play(moves)
                st.seconds += time.monotonic() - t0
                st.batches += 1
                self.played += 1
                if failure is not None:
                    self._failed(*failure)
                    if reuse_only:
                        break
                now = time.monotonic()
                if tick is not None and now - last_tick >= TICK_S:
                    last_tick = now
                    tick(st)
            last = self._settle_and_judge()  # the last window's under-delivery, too
            if last is not None:
                self._failed(*last)
        finally:
            with contextlib.suppress(Exception):
                self.target.traffic.drain()
        if tick is not None:
            tick(st)
        st.restarts = self.target.restarts
        return st

    def _saved_programs(self) -> list[list[Move]]:
        if self.database is None:
            return []
        return [m for m in (loads(v) for v in self.database.fetch(DB_KEY)) if m]

    def _failed(self, flaw: Flaw, sent: list[bytes], moves: list[Move], scenario: str | None) -> None:
        """A flaw seen: the program saved for the other workers, the datagrams triaged."""
        st = self.stats
        st.flaws += 1
        if self.first_failure_example is None:
            self.first_failure_example = self.played
        program = program_text(moves)
        self.programs.append(program)
        if self.database is not None:
            self.database.save(DB_KEY, dumps(moves))
        self.triage.consider(flaw, [Input.of(d) for d in sent], "batch", program=program, scenario=scenario)
        if self.target.spawned and not self._over():
            # the node now is triage's last replay's (replays run on fresh nodes), or the one
            # that just broke a rule: either way not what the ledger knows. A seq-no-wrap
            # node left by a replay of its wrap (seq 65535 from our src) took every later
            # message of ours for a duplicate: each later program drew an under-delivery
            # (MCP-DUP-2) no fresh node reproduced, each triaged in vain, the next finding
            # missed. Go on on a fresh node, the ledger knowing it from its start.
            self._restart(AFTER_FLAW)
        else:
            # attach mode: the same node, whatever it was sent meanwhile (the ledger forgets
            # it, as before); or the turn is over
            self._restarts_seen = -1
            self._fresh_node()

    # ------------------------------------------------------------------ one program
    def _play(self, moves: list[Move]) -> tuple[Flaw, list[bytes], list[Move], str | None] | None:
        """Send one program back to back, probe once, judge; the first flaw, with the
        program's datagrams up to its culprit, or None."""
        t, st = self.target, self.stats
        self._fresh_node()
        drv = t.driver
        scenario: str | None = None
        if moves and moves[0].name == "withhold":
            self._settle_and_judge()
            copies = moves[0].copies
            w = self._restart(WITHHELD_START, lambda: t.restart_withholding(copies))
            scenario = f"{WITHHOLD}{copies}"
            flaw = judge_withheld(w.copies, w.after_wrong_ack, copies, t.alive())
            if flaw is not None:
                return flaw, [], moves[:1], scenario
        for src in (drv.our_id, OTHER_SRC):  # forward only: a lower number is a wrap
            drv.set_seq(drv.peek_seq(src) + SEQ_GAP, src)
        t.traffic.drain()
        self.monitor = MonitorOracle(t.node_id, t.rto, t.ack_window, t.broadcast_id, drv.listen)
        win = self.window
        base = len(win.sent)
        win.starts.append((base, moves, scenario))
        history: list[bytes] = []
        inputs: list[Input] = []
        mark = drv.mark()
        end = None
        for move in moves:
            if move.name == "end_mission":
                end = move
                break
            if move.name == "withhold" or self._over():
                continue
            for data in self._render(move, history):
                if self._over():  # a move of several datagrams stops at the case budget too
                    break
                drv.send_raw(data)
                inp = Input.of(data)
                token = frame_token(data) if inp.header and inp.header[3] == _PASSTHROUGH else None
                self.ledger.sent(len(win.sent), inp, token)
                win.sent.append(data)
                inputs.append(inp)
                st.cases += 1
        probe = t.probe()
        self.ledger.sent(len(win.sent), Input.of(probe.sent.data), None)
        flaws = judge_exchange(inputs, t, mark, probe)
        if probe.acked and not flaws:
            flaws += self._copy_flaws(inputs, mark)
        flaws += self.monitor.feed(t.traffic.drain())
        if flaws:
            f = flaws[0]
            if f.datagram is not None and f.culprit is None:  # the monitor's: by its bytes
                f = replace(f, culprit=max((i for i, inp in enumerate(inputs) if inp.data == f.datagram),
                                           default=None))
            upto = len(inputs) if f.culprit is None or f.source in ("liveness", "process") else f.culprit + 1
            return f, [i.data for i in inputs[:upto]], moves, scenario
        vehicle = self._judge_vehicle(settled=False)
        if vehicle is not None:
            return vehicle
        if time.monotonic() - win.since >= SETTLE_S or end is not None:
            vehicle = self._settle_and_judge()
            if vehicle is not None:
                return vehicle
        if end is not None and not self._over():
            return self._end_mission(moves, scenario)
        return None

    def _copy_flaws(self, inputs: list[Input], mark: int) -> list[Flaw]:
        """MCP-ACK-1 for copies, observed as the rule says: each copy left unanswered
        (``judge_copies``) is sent again every --rto, up to ``ACK_COPIES`` copies in all; an
        ACK of any of them and there is no finding (a lost datagram is the link's doing)."""
        t, drv = self.target, self.target.driver
        flaws = []
        for i in judge_copies(inputs, drv.received(mark), t.node_id, t.broadcast_id)[:COPY_RECHECKS]:
            inp = inputs[i]
            m = inp.msg
            assert m is not None
            answered = False
            again = drv.mark()
            for _ in range(ACK_COPIES - 1):
                sent = drv.send_raw(inp.data)
                token = frame_token(inp.data) if m.action == _PASSTHROUGH else None
                self.ledger.sent(len(self.window.sent), inp, token)  # a copy: the ledger counts it
                self.window.sent.append(inp.data)
                if drv.wait_for(drv.ack_for(sent), max(t.rto, 0.05), again) is not None:
                    answered = True
                    break
            if not answered:
                copies = sum(1 for j in inputs if j.data == inp.data)
                flaws.append(Flaw("MCP-ACK-1", f"an ACK of every copy of seq {m.seq} (a copy is ACKed again)",
                                  f"{inp.describe()} sent {copies} times in the program, not every copy ACKed; "
                                  f"{ACK_COPIES - 1} more copies, one every --rto, none ACKed",
                                  culprit=i, evidence=(f"input: {inp.data.hex()}",)))
                break  # one fault, one finding: the program's first such copy is enough
        return flaws

    def _judge_vehicle(self, *, settled: bool) -> tuple[Flaw, list[bytes], list[Move], str | None] | None:
        """The vehicle's record against the ledger: over-delivery whenever it shows,
        under-delivery once ``settled``; the flaw with its program's datagrams."""
        t = self.target
        if t.vehicle is None or not self.ledger.expected:
            return None
        for f in self.ledger.judge(vehicle_counts(t), settled=settled):
            if f.datagram is None or f.culprit is None or f.culprit < 0 or f.datagram in self._flagged:
                continue
            self._flagged.add(f.datagram)
            win = self.window
            start, moves, scenario = win.program_of(f.culprit)
            return replace(f, culprit=f.culprit - start), win.sent[start:f.culprit + 1], moves, scenario
        return None

    def _settle_and_judge(self) -> tuple[Flaw, list[bytes], list[Move], str | None] | None:
        """With the vehicle: a sentinel behind the window's forwards, then the record judged
        for under-delivery too; a new window either way."""
        t = self.target
        found = None
        if t.vehicle is not None and self.ledger.expected and t.alive() and not t.ended:
            settled = settle_vehicle(t, self.ledger, "t")
            found = self._judge_vehicle(settled=settled)
        self.ledger.expected.clear()
        self.window = _Window()
        return found

    def _end_mission(self, moves: list[Move], scenario: str | None) -> tuple[Flaw, list[bytes], list[Move], str | None] | None:
        """End_Mission: ACKed (MCP-ACK-1), the mission over; the next program gets a fresh node."""
        t, drv = self.target, self.target.driver
        data = encode(Message(t.node_id, drv.our_id, drv.next_seq(), Action.END_MISSION, None))
        sent = drv.send_raw(data)
        self.stats.cases += 1
        got = drv.exchange(sent, rto=max(t.rto, 0.05), copies=ACK_COPIES)
        t.session.ended = True
        if got.ack is None and t.alive():
            return (Flaw("MCP-ACK-1", f"an ACK of End_Mission seq {sent.seq}",
                         f"no ACK of End_Mission in {ACK_COPIES} copies, one every --rto", culprit=0),
                    [data], moves, scenario)
        return None

    # ------------------------------------------------------------------ rendering
    def _token(self) -> str:
        self._tokens += 1
        return f"s{self.cfg.worker}n{self._tokens}"

    def _message(self, action: int, dst: int, src: int, seed: int) -> bytes:
        drv = self.target.driver
        seq = drv.next_seq(src)
        if action == _PASSTHROUGH:
            return encode(Message(dst, src, seq, Action.MAV_PASSTHROUGH, make_probe(self._token())))
        return encode(random_message(random.Random(seed), Action(action), dst=dst, src=src, seq=seq))

    def _render(self, move: Move, history: list[bytes]) -> list[bytes]:
        """A move's datagrams, numbered by the driver as it is played."""
        t, drv = self.target, self.target.driver
        name = move.name
        if name == "command":
            data = self._message(move.action, t.node_id, drv.our_id, move.seed)
            history.append(data)
            return [data] * move.copies
        if name == "duplicate":
            return history[-1:]
        if name == "late_copy":
            return [history[-min(move.arg, len(history))]] if history else []
        if name == "broadcast":
            return [self._message(move.action, t.broadcast_id, drv.our_id, move.seed)]
        if name == "to_other_id":
            dst = (t.node_id + move.arg) & 0xFFFF
            if dst in (t.broadcast_id, drv.our_id, OTHER_SRC):
                dst = (t.node_id + 10) & 0xFFFF
            return [self._message(move.action, dst, drv.our_id, move.seed)]
        if name == "other_source":
            return [self._message(move.action, t.node_id, OTHER_SRC, move.seed)]
        if name == "ack_to_node":
            return [encode(Message(t.node_id, drv.our_id, drv.next_seq(), Action.ACK, move.arg))]
        if name == "near_wrap":
            drv.set_seq(0xFFFF - move.arg)
            return []
        if name == "garbage":
            return [random_malformed(random.Random(move.seed), move.kind, dst=t.node_id, src=drv.our_id,
                                     seq=drv.next_seq())]
        return []

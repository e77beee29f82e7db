"""The Nsqd stateful engine: hypothesis plays clients of a backend (issue 21 item 1).

:class:`ClientsMachine` is a ``RuleBasedStateMachine`` over connections to the backend, its
moves derived from ``spec/nsqd.yaml``: open a connection (in one of two client slots: a
second client while the first is served, NSQD-CON-2, D-4), a valid command (the messages
table's effect is judged, NSQD-MSG-3), a mutated case of any kind of ``fuzz.stream_mutators``,
a frame cut by FIN or RST (NSQD-ROB-2) and a new connection after it (NSQD-ROB-3), a close.
Each move is an :class:`Op`; :class:`Player` plays ops on a backend (``stream_campaign.Backend``)
and judges after each one with the stateless engine's oracles (death, sanitizer report, the
backend's own frames by ``Conn.violation``, a close after frames a backend handles, a
command's effect, a stream that stopped), plus what only several connections show: a first
client closed or disturbed when a second connects, a waiting client never served once the
first leaves (NSQD-CON-2), a command lost on a new connection after a cut frame (NSQD-ROB-3).

A failing program is shrunk by hypothesis (for at most ``SHRINK_S``, one signature kept), then
triaged as the campaign's cases are (``StreamCampaign.add_program``): replayed in a fresh
process, delta-debugged over its ops, confirmed N of N, deduplicated by signature. The engine
runs in chunks inside the campaign's budget (``OutOfBudget`` from a step ends a run within one
step) and ticks the campaign's progress. Workers share hypothesis's example database (``--db``).
"""

from __future__ import annotations

import contextlib
import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hypothesis import HealthCheck, Phase, settings
from hypothesis import seed as hypothesis_seed
from hypothesis import strategies as st
from hypothesis.errors import Flaky
from hypothesis.reporting import with_reporter
from hypothesis.stateful import RuleBasedStateMachine, rule, run_state_machine_as_test

from fuzz.ddmin import ddmin
from fuzz.engine_stateful import OutOfBudget, open_database
from fuzz.stream_findings import TrafficLog
from fuzz.stream_mutators import KINDS, Write, draw_case, valid_values
from fuzz.stream_oracles import CLOSE_RULE, Signature, desync_rule, same_finding
from harness.stream_session import Conn
from spec import NSQD
from spec.stream_codec import encode

__all__ = ["ClientsMachine", "Op", "Player", "StreamStatefulEngine", "play_program", "triage_program"]

SLOTS = 2  # client slots: a first client and a second one at once
STEPS = 12  # moves per program at most
CHUNK = 10  # programs per hypothesis run (the budget is checked between moves, too)
SHRINK_S = 8.0  # how long hypothesis may shrink a failing program (triage minimises again)
TICK_S = 0.25
#: UPDATEs to the first client, counted from a second's connect, that show the backend has
#: gone round its loop with the second waiting (Player._settle): one may come from the turn
#: under way when it connected, one from the next turn, which saw it (a backend that kicks
#: the first may send that UPDATE just before it closes it), and a third only on a first kept
LOOP_UPDATES = 3
#: the commands whose effect UPDATE shows (NSQD-MSG-3), and every message a client sends
COMMANDS = tuple(m.name for m in NSQD.messages if m.sent_by in ("client", "any") and m.effect.to)
CLIENT_MSGS = tuple(m.name for m in NSQD.messages if m.sent_by in ("client", "any") and not m.effect.unobserved)


def command_bytes(name: str) -> bytes:
    """A valid command with the same field values every time (a fixed seed)."""
    msg = NSQD.message(name)
    return encode(NSQD, name, **valid_values(NSQD, msg, random.Random(0)))


@dataclass(frozen=True)
class Op:
    """One move of a program: ``open`` (a new connection in ``slot``, the old one closed),
    ``send`` (a case's writes, the last maybe ending by FIN or RST), ``cmd`` (a valid
    command, its effect judged) or ``close`` (``how``: fin or rst)."""

    what: str
    slot: int
    writes: tuple[Write, ...] = ()
    kind: str = ""  # send: the case's kind; cmd: the message
    valid: bool = False  # send: every frame one a backend handles
    in_sync: bool = True  # send: the stream is still in step after it (Case.probe)
    how: str = "fin"  # close
    note: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"what": self.what, "slot": self.slot, "writes": [{"hex": w.data.hex(), "end": w.end} for w in self.writes],
                "kind": self.kind, "valid": self.valid, "in_sync": self.in_sync, "how": self.how, "note": self.note}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> Op:
        return cls(d["what"], int(d["slot"]), tuple(Write(bytes.fromhex(w["hex"]), w.get("end", "")) for w in d.get("writes", [])),
                   d.get("kind", ""), bool(d.get("valid")), bool(d.get("in_sync", True)), d.get("how", "fin"), d.get("note", ""))

    def describe(self) -> str:
        if self.what == "open":
            return f"client {self.slot}: connect"
        if self.what == "close":
            return f"client {self.slot}: close ({self.how.upper()})"
        if self.what == "cmd":
            return f"client {self.slot}: {self.kind}"
        return f"client {self.slot}: {self.kind} ({self.note})"


@dataclass
class Client:
    """A slot's connection and what the judge knows of it."""

    conn: Conn
    second: bool  # another client was served when it connected: not served yet (D-4)
    after_cut: str = ""  # the kind of cut (fin/rst-mid-frame) of the connection before it
    clean: bool = True  # only frames a backend handles were sent on it
    in_sync: bool = True
    others: bool = False  # another client connected while it was served
    kinds: list[str] = field(default_factory=list)  # the mutated cases sent on it
    last_kind: str = "valid"


class Hit(Exception):
    """What the judge saw after an op (raised inside the player)."""

    def __init__(self, signature: Signature, detail: str, stderr: tuple[str, ...] = ()) -> None:
        super().__init__(signature.describe())
        self.signature, self.detail, self.stderr = signature, detail, stderr


class Player:
    """Plays ops on a backend's session and judges after each (see the module docstring)."""

    def __init__(self, backend: Any) -> None:
        self.b = backend
        backend._drop()
        self.clients: dict[int, Client] = {}
        self.cut = ""  # a client left mid-frame since the last new connection
        self.window = float(NSQD.params["effect_window_s"])
        self.gap = float(NSQD.params["update_gap_max_s"])

    # -- playing ------------------------------------------------------------------------
    def play(self, op: Op) -> None:
        """One op; :class:`Hit` when an oracle fires."""
        self.b.session.sent_log.clear()  # the session's record of what the current op sent
        if op.what == "open":
            self._open(op.slot)
        elif op.what == "close":
            c = self.clients.pop(op.slot, None)
            if c is not None:
                c.conn.close(rst=op.how == "rst")
                self._forget(c)
        else:
            c = self.clients.get(op.slot) or self._open(op.slot)
            if c is None:
                return
            if op.what == "cmd":
                self._command(c, op)
            else:
                self._send(c, op)
        self._judge()

    def close(self) -> None:
        for c in self.clients.values():
            c.conn.close()
            self._forget(c)
        self.clients.clear()

    def _forget(self, c: Client) -> None:
        if c.conn in self.b.session.conns:
            self.b.session.conns.remove(c.conn)

    def _open(self, slot: int) -> Client | None:
        old = self.clients.pop(slot, None)
        if old is not None:
            old.conn.close()
            self._forget(old)
            self._promote()  # a client waiting behind the old one is served before the new one
        served = [c for c in self.clients.values() if not c.second and c.conn.closed_at is None]
        conn = self.b.session.connect(timeout=float(NSQD.params["connect_timeout_s"]))
        if conn is None:
            if served:
                return None  # a second client may be refused (D-4)
            self._dead()
            raise Hit(Signature("hang", "not accepting", (), "NSQD-ROB-1"), "a new connection was not accepted")
        self.b.connections += 1
        c = Client(conn, second=bool(served), after_cut=self.cut)
        self.cut = ""
        for o in served:
            o.others = True
            self._settle(o.conn)
        self.clients[slot] = c
        return c

    def _settle(self, first: Conn) -> None:
        """A second client has just connected: wait until ``first`` shows what that did to it
        (NSQD-CON-2), the backend's close or ``LOOP_UPDATES`` UPDATEs sent to it since (its
        loop gone round with the second waiting). What it had sent before is read first: a
        frame is stamped when read, and one waiting unread proves nothing (the old wait, 0.15 s
        or until such a frame, let a loaded host's backend kick the first after the judgement:
        a finding a replay missed). The backend's own progress, so load makes the wait longer,
        never wrong; it ends early only on a stream that stopped (no UPDATE within
        update_gap_max_s, NSQD-MSG-1: a command on it judges that). The verdict comes at this
        op every time, as hypothesis's shrinking and its replay of a saved program need."""
        first.pump(0)
        have = len(first.updates())
        proof = have + LOOP_UPDATES
        while first.closed_at is None and have < proof:
            if not first.wait_for(lambda n=have: first.closed_at is not None or len(first.updates()) > n, self.gap):
                return
            have = len(first.updates())

    def _send(self, c: Client, op: Op) -> None:
        c.clean = c.clean and op.valid
        c.in_sync = c.in_sync and op.in_sync
        if not op.valid or not op.in_sync:
            c.kinds.append(op.kind)
        c.last_kind = op.kind if op.valid else c.last_kind
        for w in op.writes:
            if not c.conn.send(w.data):
                break
            if w.end:
                c.conn.close(rst=w.end == "rst")
                self._gone(c)
                if not _whole_frames(b"".join(x.data for x in op.writes)):
                    self.cut = f"{w.end}-mid-frame"  # the next connection served is a new stream
                    for o in self.clients.values():  # a waiting client may be that one
                        o.after_cut = o.after_cut or (self.cut if o.second else "")
                return
        c.conn.pump(0.003)

    def _gone(self, c: Client) -> None:
        for slot, o in list(self.clients.items()):
            if o is c:
                del self.clients[slot]
        self._forget(c)

    def _command(self, c: Client, op: Op) -> None:
        msg = NSQD.message(op.kind)
        conn = c.conn
        judged = not c.second and c.in_sync and conn.closed_at is None
        if judged and not conn.updates():  # the state before the command, from the stream
            conn.wait_for(lambda: bool(conn.updates()), self.gap)
            if not conn.updates() and conn.closed_at is None:
                self._dead()
                raise Hit(Signature("hang", "no UPDATE on a new connection", (), "NSQD-MSG-1"),
                          f"no UPDATE within {self.gap:g} s of connecting")
        ups = conn.updates()
        judged = judged and bool(ups) and ups[-1].values["state"] not in msg.effect.to  # type: ignore[index]
        since = time.monotonic()
        conn.send(op.writes[0].data)
        c.last_kind = "valid"
        if not judged:
            conn.pump(0.003)
            return
        ok = conn.wait_for(lambda: any(u.values["state"] in msg.effect.to for u in conn.updates(since))  # type: ignore[index]
                           or (msg.effect.or_error and bool(conn.errors(since))), self.window)
        if ok or conn.closed_at is not None:
            return  # a close is judged with the others' (_judge)
        self._judge()  # a death or the backend's own frames first
        seen = sorted({NSQD.state_name(u.values["state"]) for u in conn.updates(since)})  # type: ignore[index]
        what = (f"{op.kind}: UPDATE.state {' or '.join(NSQD.state_name(s) for s in msg.effect.to)} expected "
                f"within {self.window:g} s, saw {', '.join(seen) or 'no UPDATE'}")
        if not seen:
            sig = (Signature("hang", "UPDATE stream stopped with a second client", (), "NSQD-CON-2") if c.others
                   else Signature("hang", "UPDATE stream stopped", (), "NSQD-MSG-1"))
        elif c.others:
            sig = Signature("effect", "command lost with a second client", (), "NSQD-CON-2")
            what += " (a second client had connected)"
        elif c.after_cut and not c.kinds:
            sig = Signature("desync", f"stream lost after {c.after_cut}", (), "NSQD-ROB-3")
            what += f" (a new connection after a frame cut by {c.after_cut[:3].upper()})"
        elif c.kinds:
            sig = Signature("desync", f"stream lost after {c.kinds[-1]}", (), desync_rule(c.kinds[-1]))
        else:
            sig = Signature("effect", op.kind, (), "NSQD-MSG-3")
        raise Hit(sig, what)

    # -- judging ------------------------------------------------------------------------
    def _dead(self) -> None:
        hit = self.b.death_hit(0.3)
        if hit is not None:
            raise Hit(hit.signature, hit.detail, hit.stderr)

    def _judge(self) -> None:
        for c in self.clients.values():
            c.conn.pump(0)
        closed = any(c.conn.closed_at is not None for c in self.clients.values())
        hit = self.b.death_hit(0.03 if closed else 0.0)
        if hit is not None:
            raise Hit(hit.signature, hit.detail, hit.stderr)
        proc = self.b.session.proc
        if proc is not None:
            if len(proc.sanitizer_report()) > self.b.reports_seen:
                hit = self.b.report_hit()
                if hit is not None:
                    raise Hit(hit.signature, hit.detail, hit.stderr)
        for c in self.clients.values():
            v = c.conn.violation()
            if v is not None:
                raise Hit(Signature("protocol", v.rule, (), v.rule), f"{v.expected}; {v.actual}")
        for slot, c in list(self.clients.items()):
            if c.conn.closed_at is None:
                continue
            self._gone(c)
            if c.second or not c.clean:
                continue  # a second client may be closed (D-4); after a bad frame it may (D-3)
            if c.others:  # before a cut: the second client is what happened to it last
                raise Hit(Signature("close", "first client closed by a second", (), "NSQD-CON-2"),
                          f"client {slot} was closed by the backend when a second client connected")
            if c.after_cut and not c.kinds:
                raise Hit(Signature("desync", f"stream lost after {c.after_cut}", (), "NSQD-ROB-3"),
                          f"client {slot}'s new connection, after a frame cut by {c.after_cut[:3].upper()}, "
                          "was closed after frames a backend handles")
            raise Hit(Signature("close", c.last_kind, (), CLOSE_RULE.get(c.last_kind, "NSQD-FRM-5")),
                      f"the backend closed client {slot}'s connection after frames it handles")
        self._promote()

    def _promote(self) -> None:
        """A waiting second client is served once no first one is left (NSQD-CON-2, D-4)."""
        if any(not c.second for c in self.clients.values()):
            return
        for slot, c in self.clients.items():
            if not c.second:
                continue
            c.second = False
            conn = c.conn
            if conn.updates():
                continue
            bound = self.gap + 0.5
            if not conn.wait_for(lambda conn=conn: bool(conn.updates()), bound) and conn.closed_at is None:
                self._dead()
                raise Hit(Signature("hang", "waiting client not served", (), "NSQD-CON-2"),
                          f"client {slot}, waiting while another was served, got no UPDATE within {bound:g} s "
                          "of the other leaving")
            return


def _whole_frames(data: bytes) -> bool:
    """``data`` is whole frames by their length prefixes (nothing cut)."""
    off = 0
    while off + 4 <= len(data):
        n = int.from_bytes(data[off:off + 4], "big", signed=True)
        if n < 5:
            return False
        off += n
    return off == len(data)


# ---------------------------------------------------------------------------- the machine
@dataclass
class _Context:
    campaign: Any
    backend: Any
    out_of_budget: Callable[[], bool]
    tick: Callable[[], None] | None = None
    chunk_started: float = 0.0
    target: Signature | None = None  # the signature being shrunk (others are ignored)
    raised: list[tuple[Hit, list[Op]]] = field(default_factory=list)
    shrink_until: float | None = None
    last_tick: float = 0.0
    restarts: int = 0

    def checkpoint(self) -> None:
        now = time.monotonic()
        if self.tick is not None and now - self.last_tick >= TICK_S:
            self.last_tick = now
            self.campaign.fuzz_s += now - self.chunk_started  # the live rate counts this run so far
            self.chunk_started = now
            self.tick()
        if self.out_of_budget():
            raise OutOfBudget(campaign_over=True)
        if self.shrink_until is not None and now >= self.shrink_until:
            raise OutOfBudget(campaign_over=False)

    def fresh(self) -> None:
        """A backend that is alive and serving for the next program."""
        b = self.backend
        if b.session.death() is not None or not b.session.live(float(NSQD.params["update_gap_max_s"])):
            self.backend = self.campaign.current = b.fresh()
            self.restarts += 1


CTX: _Context | None = None


class ProgramFailed(AssertionError):
    def __init__(self, hit: Hit, ops: list[Op]) -> None:
        super().__init__(hit.signature.describe())
        self.hit, self.ops = hit, ops


class ClientsMachine(RuleBasedStateMachine):
    """Clients' moves against one backend (see the module docstring)."""

    def __init__(self) -> None:
        super().__init__()
        assert CTX is not None, "ClientsMachine runs under StreamStatefulEngine"
        self.ctx = CTX
        self.ctx.fresh()
        self.player = Player(self.ctx.backend)
        self.ops: list[Op] = []

    def _do(self, op: Op) -> None:
        ctx = self.ctx
        ctx.checkpoint()
        self.ops.append(op)
        ctx.campaign.cases += 1
        if op.what in ("send", "cmd"):
            ctx.campaign.note_tried("valid" if op.what == "cmd" else op.kind, b"".join(w.data for w in op.writes))
        try:
            self.player.play(op)
        except Hit as hit:
            if ctx.target is not None and hit.signature.key != ctx.target.key and \
                    not (hit.signature.oracle == ctx.target.oracle == "desync"):
                return  # while shrinking, only the failure being shrunk counts
            if ctx.target is None:
                ctx.target = hit.signature
                ctx.shrink_until = time.monotonic() + SHRINK_S
            if len(ctx.raised) < 20:
                ctx.raised.append((hit, list(self.ops)))
            raise ProgramFailed(hit, list(self.ops)) from None

    @rule(slot=st.integers(0, SLOTS - 1))
    def connect(self, slot: int) -> None:
        """A new connection in ``slot`` (a reconnect when it had one; a second client when the
        other slot is served)."""
        self._do(Op("open", slot))

    @rule(slot=st.integers(0, SLOTS - 1), name=st.sampled_from(COMMANDS))
    def command(self, slot: int, name: str) -> None:
        """A valid command; its effect judged on a served connection (NSQD-MSG-3)."""
        self._do(Op("cmd", slot, (Write(command_bytes(name)),), name, valid=True))

    @rule(slot=st.integers(0, SLOTS - 1), kind=st.sampled_from(KINDS), seed=st.integers(0, 2**32 - 1))
    def mutated(self, slot: int, kind: str, seed: int) -> None:
        """A case of ``fuzz.stream_mutators`` (its kind, drawn from ``seed``)."""
        case = draw_case(random.Random(seed), kind=kind)
        self._do(Op("send", slot, case.writes, case.kind, case.valid, case.probe, note=case.note))

    @rule(slot=st.integers(0, SLOTS - 1), name=st.sampled_from(CLIENT_MSGS), cut=st.integers(1, 10_000),
          how=st.sampled_from(("fin", "rst")))
    def leave_mid_frame(self, slot: int, name: str, cut: int, how: str) -> None:
        """A frame cut by FIN or RST (NSQD-ROB-2); the next connection is a new stream (NSQD-ROB-3)."""
        whole = command_bytes(name)
        cut = 1 + cut % (len(whole) - 1)
        self._do(Op("send", slot, (Write(whole[:cut], end=how),), f"{how}-mid-frame", in_sync=False,
                    note=f"{name} cut at {cut} by {how.upper()}"))

    @rule(slot=st.integers(0, SLOTS - 1), how=st.sampled_from(("fin", "rst")))
    def disconnect(self, slot: int, how: str) -> None:
        """The client in ``slot`` leaves (a waiting one is then served: NSQD-CON-2)."""
        if slot in self.player.clients:
            self._do(Op("close", slot, how=how))

    def teardown(self) -> None:
        self.player.close()


def play_program(backend: Any, ops: list[Op], log: Any = None) -> Hit | None:
    """Play ``ops`` on ``backend`` (a fresh one for a replay): the first hit, if any.
    ``log`` (a ``fuzz.stream_findings.TrafficLog``): the replay's traffic, for the finding's
    repro.mcap and repro.pcap, as a stateless finding's confirming replay keeps it."""
    backend.session.recorder = log
    p = Player(backend)
    try:
        for op in ops:
            p.play(op)
        hit = backend.death_hit(0.3)
        if hit is not None:
            return Hit(hit.signature, hit.detail, hit.stderr)
        p._judge()
        return None
    except Hit as hit:
        return hit
    finally:
        if log is not None:
            for c in list(backend.session.conns):  # how the connections stand at the end: a dead backend's close
                with contextlib.suppress(OSError, ValueError):
                    c.pump(0)
        p.close()
        if log is not None:
            log.done = True
        backend.session.recorder = None


class StreamStatefulEngine:
    """Runs :class:`ClientsMachine` in chunks until the budget is spent; each failure goes to
    ``campaign.add_program`` (triage, dedup, finding-N/)."""

    def __init__(self, campaign: Any, backend: Any, db: str | None = None, worker: int = 0) -> None:
        self.campaign = campaign
        self.backend = backend
        self.database = open_database(db)
        self.worker = worker
        self.programs = 0
        self.flaky = 0

    def _settings(self, chunk: int) -> settings:
        phases = [Phase.reuse, Phase.generate, Phase.shrink] if chunk == 0 else [Phase.generate, Phase.shrink]
        return settings(max_examples=CHUNK, stateful_step_count=STEPS, deadline=None, database=self.database,
                        phases=phases, print_blob=False, suppress_health_check=list(HealthCheck),
                        report_multiple_bugs=False)

    def run(self, out_of_budget: Callable[[], bool], tick: Callable[[], None] | None = None) -> Any:
        """Fuzz until ``out_of_budget()``; the backend (maybe a fresh one) at the end."""
        global CTX
        ctx = _Context(self.campaign, self.backend, out_of_budget, tick)
        CTX = ctx
        chunk = 0
        try:
            while not out_of_budget():
                ctx.chunk_started = time.monotonic()
                failure: tuple[Hit, list[Op]] | None = None
                over = False
                machine = hypothesis_seed(self.campaign.seed * 1000 + self.worker * 100 + chunk)(
                    type("ClientsMachine", (ClientsMachine,), {}))
                try:
                    with with_reporter(lambda _text: None):  # the program is in the finding, not on stdout
                        run_state_machine_as_test(machine, settings=self._settings(chunk))
                except ProgramFailed as exc:
                    failure = (exc.hit, exc.ops)
                except Flaky:
                    self.flaky += 1  # failed once, not again the same way: triage may still confirm it
                    failure = ctx.raised[0] if ctx.raised else None
                except OutOfBudget as exc:
                    over = exc.campaign_over
                    if ctx.raised:  # the shortest failure shrinking had reached
                        failure = min(ctx.raised, key=lambda r: len(r[1]))
                self.campaign.fuzz_s += time.monotonic() - ctx.chunk_started
                self.programs += CHUNK
                chunk += 1
                ctx.raised.clear()
                ctx.target, ctx.shrink_until = None, None
                if failure is not None:
                    ctx.backend = self.campaign.current = self.campaign.add_program(ctx.backend, failure[0], failure[1])
                if tick is not None:
                    tick()
                if over:
                    break
        finally:
            CTX = None
            self.campaign.restarts += ctx.restarts
        return ctx.backend


def triage_program(campaign: Any, backend: Any, hit: Hit, ops: list[Op]) -> Any:
    """A failing program: deduplicated, replayed in a fresh process, delta-debugged over its
    ops, confirmed ``campaign.replays`` of as many times, then a finding (``campaign._add``).
    The backend to go on with."""
    from harness.errors import SetupError

    sig = hit.signature
    known = next((f for f in campaign.findings if f.signature.key == sig.key), None)
    if known is not None:
        known.count += 1
        return backend.fresh() if sig.oracle in ("crash", "hang", "sanitizer") else backend
    if campaign.target is not None and campaign.spawn is None and sig.oracle in ("crash", "hang") \
            and backend.session.death() is not None:
        raise SetupError(f"the attached backend is gone ({hit.detail}); findings so far are kept")
    box: dict[str, Any] = {"b": backend, "stderr": hit.stderr, "traffic": []}

    def reproduces(o: list[Op], log: TrafficLog | None = None) -> bool:
        box["b"] = campaign.current = box["b"].fresh()
        campaign.restarts += 1
        h = play_program(box["b"], o, log)
        if h is not None and h.stderr:
            box["stderr"] = h.stderr
        ok = h is not None and same_finding(h.signature, sig)
        if ok and log is not None:
            box["traffic"] = log.records  # the last confirming replay's: repro.mcap, repro.pcap
        return ok

    if not reproduces(ops):
        campaign.unconfirmed += 1
        return box["b"].fresh()
    if len(ops) > 1:
        ops = ddmin(list(ops), reproduces, budget=16)
    confirmed = sum(reproduces(ops, TrafficLog()) for _ in range(campaign.replays))
    if confirmed < campaign.replays:
        campaign.unconfirmed += 1
        return box["b"].fresh()
    campaign.add_program_finding(sig, hit.detail, f"{confirmed} of {campaign.replays}", tuple(box["stderr"]),
                                 "stateful: " + "; ".join(op.describe() for op in ops), [op.to_json() for op in ops],
                                 box["traffic"])
    return box["b"].fresh()

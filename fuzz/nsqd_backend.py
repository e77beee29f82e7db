"""The backend under ``mcp-fuzz --protocol nsqd`` and the replay of cases on it (issue 21).

:class:`Backend` holds a session (spawned, attached or the embedded default) and the current
connection; ``run`` writes a case and asks the oracles of ``fuzz.nsqd_oracles`` what they
saw, ``probe`` checks that a command still takes its effect. Its process and its end are
the shared core's (``fuzz.target_core.ProcessTarget``: the one MAVLink's vehicle has), as is
the read of several connections at once (``read_until``). ``_reproduces`` replays cases in
a fresh process, as triage and ``--replay`` do (``fuzz.nsqd_triage``).

What a case waits for (judged cases/s, issue 21): an observation that ends it, never a fixed
wait that proves nothing. A bad frame's watch ends at the backend's answer (ERROR, close); a
connection a case may leave unusable ends with our FIN and the backend's close (it has
handled every byte before it); a valid frame on a kept connection, answered by nothing, is
sent and what is there read, its close window (a close after frames a backend handles is a
finding) coming before the next bad frame on that still-clean connection, at the probe, or in
a replay; a probe or a judged effect ends at the UPDATE that shows the state (:meth:`Backend._verify`).

Restarts (issue 36 item 5): a backend that dies on every frame (an ASan build that over-reads)
is restarted after nearly every case. A spawned process is ready when it accepts a connection
and sends on it (``harness.nsqd_session``'s own check, polled every 50 ms: a sanitizer's
start takes a few ms, so nearly every start waited one poll; a real backend takes 1.2-1.4 s).
:meth:`Backend.fresh`, the process a replay or the campaign goes on with, takes a spare started
in the background after the previous one, already through that check, and starts the next
spare: the wait is gone from the campaign and from triage. The spares are the worker's target's
(:class:`BackendTarget`, the shared core's ``fuzz.target_core.SpareTarget``, as MAVLink's are).
"""

from __future__ import annotations

import collections
import contextlib
import random
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any

from mcp_conform.fuzz.finding_files import TrafficLog
from mcp_conform.fuzz.nsqd_mutators import Case, valid_values
from mcp_conform.fuzz.nsqd_oracles import (
    CLOSE_RULE,
    Hit,
    Signature,
    parse_cause,
    parse_sanitizer,
    same_finding,
)
from mcp_conform.fuzz.spares import SPARES
from mcp_conform.fuzz.target_base import TargetLost
from mcp_conform.fuzz.target_core import ProcessTarget, SpareTarget, TargetSpec, read_until
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.nsqd_session import Conn, StreamSession
from mcp_conform.harness.session_base import SpawnedNode
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import encode
from mcp_conform.spec.profiles import NSQD_PROFILE

__all__ = ["Backend", "BackendTarget", "Hit", "end_log", "message_names", "read_until", "violation_hit"]

_PROBES = (("STOP_TEST", NSQD.states["STOP_TEST"]), ("CAPTURE_IMAGES", NSQD.states["CAPTURE_IMAGES"]))


@dataclass
class Traits:
    """What a campaign learned of its backend, shared by every process it starts.

    ``reports_fatal``: whether a sanitizer's report ends the process (ASan's default) or not
    (``halt_on_error=0``: a real backend's ASan build over-reads on every frame and goes on).
    Until known, a whole report is followed by a 3 s wait for the exit (a loaded CI host took
    over 0.3 s between SUMMARY and exit); once a process lived 3 s past one, 0.3 s."""

    reports_fatal: bool | None = None


class Backend(ProcessTarget):
    """The backend under fuzz: a session (spawned, attached or the embedded default) and the
    fuzzer's current connection; its process and its end the shared core's
    (``fuzz.target_core.ProcessTarget``)."""

    subject = StreamSession.subject

    def __init__(self, target: tuple[str, int] | None, spawn: str | None, traits: Traits | None = None,
                 pool: BackendTarget | None = None) -> None:
        self.how = TargetSpec(spawn, target)  # attached: an address and no --spawn
        self.traits = traits if traits is not None else Traits()
        #: (time.monotonic() at its first write, case) for each case this process was sent
        #: (bounded): a death's suspects are the ones sent before its cause showed
        self.history: collections.deque[tuple[float, Case]] = collections.deque(maxlen=64)
        self.session = StreamSession(RunConfig(protocol=NSQD_PROFILE.name, role=NSQD_PROFILE.default_role.name,
                                               target=target, spawn=spawn))
        self.session.start()
        self.conn: Conn | None = None
        self.connections = 0
        self.reports_seen = 0
        self.probe_i = 0
        self.clean = True
        # the last case's frame had to leave the connection open (NSQD-MSG-4: "a frame whose id
        # names no message is consumed by its length: the connection is kept"): the probe goes
        # on that connection even when the backend closed it -- whether the close was seen yet
        # is timing, and a replay must not turn on it (1 replay in 6 went to a new connection,
        # found nothing and "did not reproduce" the desync)
        self.must_keep = False
        self.bad_probes: set[str] = set()
        self.synced = False  # the last case's judged effect showed the stream in sync
        self.unwatched = ""  # the kind of the last valid case sent without its close window
        self.unwatched_n = 0  # how many cases in a row before this one were
        #: the worker's target this backend is one of, whose spares its :meth:`fresh` takes
        #: (``fuzz.target_core.SpareTarget``); ``handed_on``: a fresh one has taken its place
        self.pool = pool if pool is not None else BackendTarget(self)
        self.handed_on = False

    def end(self) -> None:
        """The session closed (its process stopped, spawned)."""
        with contextlib.suppress(Exception):
            self.session.close()

    def close(self) -> None:
        """The session closed, and the spares with it unless a fresh backend took its place."""
        self.end()
        if not self.handed_on:
            self.pool.spares.discard()

    def fresh(self) -> Backend:
        """A new process (spawn mode and the embedded default): this one closed, then its
        target's (``SpareTarget.fresh``: the spare started in the background at the previous
        call, a fresh start if it failed: its error is then the start's own; the next spare
        started); attach mode: the same target, found live (:meth:`check_live`). A replay's and a
        restart's alike: a real backend takes 1.2-1.4 s to start, and every replay of triage
        waited for it."""
        if self.how.attached:
            self._drop()
            self.check_live("when the fuzzer came back to it (a replay, or a restart after a hit)")
            return self
        self.handed_on = True
        self.end()
        b: Backend = self.pool.fresh()
        return b

    restart = fresh  #: the process the campaign goes on fuzzing with

    def check_live(self, why: str) -> None:
        """Attach mode: the backend accepts a new connection and sends its first frame within
        the protocol's allowance (NSQD-CON-1, as at the start), or ``TargetLost`` naming it and
        ``why`` it was looked at (:meth:`fresh`, which every replay and every restart after a
        crash or hang calls). Attach mode has no other backend to replay on: replays on the
        same dead one "confirm" whatever it showed last (a backend killed mid-campaign was a
        confirmed NSQD-ROB-1 hang, 53,452 times, 3 of 3 replays), as ``fuzz.target_base``'s
        check ends an MCP campaign and ``fuzz.mavlink_triage`` a MAVLink one."""
        s = self.session
        if not self.how.attached:
            return
        if not s.live(float(NSQD.params["connect_timeout_s"]) + float(NSQD.params[s.gap_param])):
            host, port = s.address
            raise TargetLost(f"the backend at {host}:{port} accepts no connection or sends no {s.first_sign} "
                             f"({s.first_rule}) {why}; attach mode has no other backend, so the campaign ends here")

    def _drop(self) -> None:
        if self.conn is not None:
            self.conn.close()
            with contextlib.suppress(ValueError):
                self.session.conns.remove(self.conn)
            self.conn = None

    def _connect(self) -> Conn | None:
        self._drop()
        self.conn = self.session.connect(timeout=float(NSQD.params["connect_timeout_s"]))
        self.connections += 1
        self.clean = True  # only frames a backend handles were sent on it (a close is then a finding)
        return self.conn

    @property
    def node(self) -> SpawnedNode | None:
        """The spawned backend (the session's), None: attached."""
        return self.session.node

    def death_hit(self, grace: float) -> Hit | None:
        d = self.session.death(grace=grace)
        if d is None:
            return None
        proc = self.process
        assert proc is not None  # a death: of a spawned process
        report = proc.sanitizer_report()
        # named by what killed it: under halt_on_error=0 the first report is seldom that (a
        # real backend's over-read on every frame hid its aborting number parse, its negative
        # string length and its GPX parser's SEGV under one finding)
        cause = proc.last_cause()
        parsed = parse_cause(cause) if cause else (parse_sanitizer(report) if report else None)
        at = None
        if parsed:
            kind, access, frames = parsed
            at = proc.cause_time() if cause else proc.report_time()
        else:  # no cause written: seen now, its cause no later
            kind, access, frames, at = d.signal_name or f"exit {d.code}", "", (), time.monotonic()
        return Hit(Signature("crash", kind, frames, "NSQD-ROB-1", access), d.describe(),
                   tuple(report[:20]) or d.stderr, at=at)

    def end_hit(self, grace: float) -> Hit | None:
        """The process's death within ``grace`` s, else what a new sanitizer report on its
        stderr shows (:meth:`report_hit`), else None (the stateful player's check after each op)."""
        hit = self.death_hit(grace)
        proc = self.process
        if hit is None and proc is not None and len(proc.sanitizer_report()) > self.reports_seen:
            return self.report_hit()
        return hit

    def report_hit(self) -> Hit | None:
        """A new sanitizer report on stderr: once it is whole (its SUMMARY line, which ASan
        writes last; up to 5 s, or 1 s without a new line: symbolising its stacks takes a
        while on a loaded machine), a death if the process then exits (ASan's default), else
        the report of a process still running (halt_on_error=0)."""
        proc = self.process
        assert proc is not None
        report = self.whole_report()
        self.reports_seen = len(report)
        # a loaded CI host took over 0.3 s between lines of a report, and between its SUMMARY
        # and the exit: shorter waits classed a crash as a report of a process still running
        # ("sanitizer": its replay "did not reproduce", test_nsqd_repro)
        whole = any("SUMMARY:" in x for x in report)
        dead = self.death_hit((0.3 if self.traits.reports_fatal is False else 3.0) if whole else 1.0)
        if dead is not None:
            first = parse_sanitizer(report) if whole else None
            if first and self.traits.reports_fatal is None:  # of the report itself, or of a later cause
                self.traits.reports_fatal = (dead.signature.kind, dead.signature.frames[:3]) == (first[0], first[2][:3])
            return dead
        if whole and self.traits.reports_fatal is None:
            self.traits.reports_fatal = False
        parsed = parse_sanitizer(report)
        if parsed:
            # named by kind and frames, the bug; its access size is the input's (a real backend's
            # over-read on every frame read as many sizes as frame lengths: one finding per size)
            access = f" ({parsed[1]})" if parsed[1] else ""
            return Hit(Signature("sanitizer", parsed[0], parsed[2], "NSQD-ROB-1"),
                       f"a sanitizer report{access}, the process still running", tuple(report[:20]),
                       at=proc.report_time())
        return None

    def run(self, case: Case) -> Hit | None:
        """Write the case; what the oracles saw, if anything (its ``suspects``: this case, the
        one before, and the valid ones before them sent without a wait: what shows now may be
        theirs)."""
        self.history.append((time.monotonic(), case))
        hit = self._run(case)
        if hit is not None:
            hit.suspects = max(hit.suspects, self.unwatched_n + 2)
        self.unwatched_n = self.unwatched_n + 1 if self.unwatched else 0
        return hit

    def suspects(self, hit: Hit, window: list[Case]) -> tuple[list[Case], float]:
        """The cases that may have caused ``hit`` (oldest first, as sent) and how long a replay
        of one should wait for it to show (``_reproduces``' ``wait``).

        Where its cause's time is known (a death's "terminate called" or sanitizer line, a
        report's first line), the cases this process was sent before it (the latest
        :data:`SUSPECTS_MAX`). A backend's death shows only at a later case's write or read, and
        a backend may handle its input well behind the fuzzer (a real one handles one frame per
        20 ms loop: the cases after its culprit were blamed and the death "did not
        reproduce"), but its cause's line is read as it is written. The
        wait: four times the time from that case to its cause, at least 1 s (0.5-0.9 s: a real one's, loaded), at most
        :data:`REPLAY_DEATH_S` (a replay of the wrong case waited those 2 s each time)."""
        if hit.at is None or hit.signature.oracle not in ("crash", "sanitizer"):
            return window[-hit.suspects:], REPLAY_DEATH_S
        before = [(t, c) for t, c in self.history if t <= hit.at]
        if not before:
            return window[-hit.suspects:], REPLAY_DEATH_S
        latency = hit.at - before[-1][0]
        return [c for _, c in before[-SUSPECTS_MAX:]], min(REPLAY_DEATH_S, max(1.0, 4 * latency))

    def _run(self, case: Case) -> Hit | None:
        self.session.sent_log.clear()  # the session's record of what the current case sent
        reused = self.conn is not None and self.conn.closed_at is None
        conn = self.conn if reused else self._connect()
        if conn is None:
            return self.death_hit(0.3) or Hit(Signature("hang", "not accepting", (), "NSQD-ROB-1"),
                                              "a new connection was not accepted")
        if not reused:
            self.unwatched = ""
        if self.unwatched and not case.valid:
            # valid frames went out unwatched (a correct backend answers them with nothing:
            # a fixed wait after each proved nothing) and the connection is still clean: before
            # a frame it may close on, their close window (a close now is theirs)
            hit = self._close_window(self.unwatched, "")
            if hit is not None:
                return hit
        self.clean = self.clean and case.valid
        self.must_keep = case.kind == "bad-id"
        for w in case.writes:
            if not conn.send(w.data):
                break
            if w.end:
                conn.close(rst=w.end == "rst")
                self._drop()
                break
        if self.conn is not None:
            if case.valid and reused and self.conn.closed_at is None and not case.check:
                # a frame the backend handles, answered by nothing: read what is there; on a
                # clean connection its close window comes before the next bad frame (and at
                # the probe), on another a close is allowed anyway
                self.conn.pump(0)
                self.unwatched = case.kind if self.clean else ""
            elif case.probe or self.conn.closed_at is not None:
                self.conn.pump(0.003)  # ends at the first frame (an ERROR, the first UPDATE) or the close
                self.unwatched = ""
            else:  # a case that may leave the stream unusable: the next starts afresh. Its
                # connection ends with our FIN: the backend's close (it has handled every byte
                # before it) ends the watch at once, no fixed wait (the same bound)
                self.conn.shutdown()
                self.conn.wait_for(lambda: False, 0.003)
                if self.death_hit(0.0) is None:
                    self._drop()
        closed_by_backend = self.conn is not None and self.conn.closed_at is not None
        # a death closes the socket as the process exits: where a close would be a finding, a
        # moment to tell the two apart (a close after a bad frame is allowed, and a death then
        # shows at the next case: not worth 30 ms on every framing error)
        hit = self.death_hit(0.03 if closed_by_backend and self.clean else 0.0)
        if hit is not None:
            return hit
        proc = self.process
        if proc is not None and len(proc.sanitizer_report()) > self.reports_seen:
            return self.report_hit()  # a report: the process may be on its way out
        hit = violation_hit([self.conn])  # the backend's own frames first: an effect is read from them
        if hit is not None:
            return hit
        if case.check and case.expect and self.conn is not None and self.conn.closed_at is None:
            hit = self._effect(case)
            if hit is not None:
                return hit
        if self.conn is not None:
            if self.conn.closed_at is not None and self.clean:
                rule = CLOSE_RULE.get(case.kind, "NSQD-FRM-5")
                return Hit(Signature("close", case.kind, (), rule),
                           f"the backend closed the connection after frames it handles ({case.note})")
        return None

    def _close_window(self, kind: str, note: str, within: float = 0.003) -> Hit | None:
        """The close window (``within``: 3 ms in a campaign, ended by the backend's close)
        after frames the backend handles, sent on a connection that only carried such frames:
        a close in it is a finding (NSQD-FRM-2/3/5, by the last case's ``kind``)."""
        conn = self.conn
        self.unwatched = ""
        if conn is None or conn.closed_at is not None or not self.clean:
            return None
        conn.wait_for(lambda: False, within)
        if conn.closed_at is None:
            return None
        hit = self.death_hit(0.03)
        if hit is not None:
            return hit
        return Hit(Signature("close", kind, (), CLOSE_RULE.get(kind, "NSQD-FRM-5")),
                   f"the backend closed the connection after frames it handles{f' ({note})' if note else ''}")

    def _verify(self, conn: Conn, states: tuple[int, ...], or_error: bool, since: float) -> tuple[bool, Conn | None]:
        """Whether a command just sent on ``conn`` took its effect (NSQD-MSG-3): UPDATE.state in
        ``states`` (or, ``or_error``, an ERROR) on ``conn`` after ``since``, or on the next
        connection. Our FIN follows the command, so the backend handles the command before it
        sees the stream end; a one-client backend then closes ``conn`` and serves the next
        connection (opened at once, waiting in the backlog: NSQD-CON-2, D-4), whose UPDATEs
        carry the flight state the command left. The observation ends with the UPDATE that
        shows it instead of the next periodic one (up to a period); a backend that serves
        several clients at once shows it in a later UPDATE, within the same window. The next
        connection, when opened, becomes the current one (``self.conn``)."""
        window = float(NSQD.params["effect_window_s"])
        conn.shutdown()
        fresh = self.session.connect(timeout=float(NSQD.params["connect_timeout_s"]))
        if fresh is not None:
            self.connections += 1

        def shown() -> bool:
            return (any(u.values["state"] in states for u in conn.updates(since))  # type: ignore[index]
                    or (or_error and bool(conn.errors(since)))
                    or (fresh is not None and any(u.values["state"] in states for u in fresh.updates())))  # type: ignore[index]

        ok = read_until([c for c in (conn, fresh) if c is not None], shown, window)
        return ok, fresh

    def _adopt(self, fresh: Conn | None) -> None:
        """``fresh`` (a connection :meth:`_verify` opened) is the current connection."""
        self._drop()
        self.conn = fresh
        self.clean, self.must_keep = True, False

    def _effect(self, case: Case) -> Hit | None:
        """A valid command's effect shows in UPDATE.state within the effect window (NSQD-MSG-3)."""
        conn = self.conn
        assert conn is not None
        since = conn.sent[-1][0] if conn.sent else time.monotonic()
        window = float(NSQD.params["effect_window_s"])
        clean = self.clean
        before = [u.values["state"] for u in conn.updates() if u.t < since]  # type: ignore[index]
        ok, fresh = self._verify(conn, case.expect, case.or_error, since)
        ups = conn.updates(since) + (fresh.updates() if fresh is not None else [])
        # a state the stream was not in before, reached by the command: the stream is in sync,
        # as a probe would have shown (the campaign starts its probe window afresh)
        self.synced = ok and bool(before) and before[-1] not in case.expect and \
            any(u.values["state"] in case.expect for u in ups)  # type: ignore[index]
        self._adopt(fresh)
        hit = violation_hit((conn, fresh))
        if hit is not None:
            return hit
        if ok:
            return None
        if conn.reset or (not clean and conn.closed_at is not None):
            return None  # the backend had closed it (a bad frame before may let it): the command unread
        if not ups:  # nothing at all: not the command's effect, the backend's liveness
            return self.death_hit(0.3) or Hit(Signature("hang", "UPDATE stream stopped", (), "NSQD-MSG-1"),
                                              f"no UPDATE within {window:g} s of the command")
        seen = sorted({NSQD.state_name(u.values["state"]) for u in ups})  # type: ignore[index]
        # a death first (Player._judge too): a backend that read the command late may have sent an UPDATE
        return self.death_hit(0.03 if conn.closed_at is not None else 0.0) or Hit(Signature("effect", case.msg or case.note, (), "NSQD-MSG-3"),
            f"{case.note}: UPDATE.state {' or '.join(NSQD.state_name(s) for s in case.expect)} expected, "
            f"saw {', '.join(seen) or 'no UPDATE'}")

    def probe(self) -> Hit | None:
        """A command on the current connection (a new one if the backend closed it, unless it
        had to keep it: ``must_keep``) must take its effect within the effect window
        (:meth:`_verify`: on that connection or, after our FIN, on the next one)."""
        if self.unwatched:
            hit = self._close_window(self.unwatched, "")
            if hit is not None:
                return hit
        usable = [p for p in _PROBES if p[0] not in self.bad_probes] or list(_PROBES)
        name, state = usable[self.probe_i % len(usable)]
        self.probe_i += 1
        keep = self.conn is not None and (self.conn.closed_at is None or self.must_keep)
        conn = self.conn if keep else self._connect()
        if conn is None:
            return self.death_hit(0.3) or Hit(Signature("hang", "not accepting", (), "NSQD-ROB-1"),
                                              "a new connection was not accepted")
        since = time.monotonic()
        window = float(NSQD.params["effect_window_s"])
        conn.send(encode(NSQD, name))
        seen, fresh = self._verify(conn, (state,), False, since)
        self._adopt(fresh)
        hit = self.death_hit(0.0 if seen else 0.3) or violation_hit((conn, fresh))
        if hit is not None:
            return hit
        if seen:
            return None
        if conn.closed_at is None and not conn.updates(since) and (fresh is None or not fresh.updates()):
            return Hit(Signature("hang", "UPDATE stream stopped", (), "NSQD-MSG-1"),
                       f"no UPDATE within {window:g} s on an open connection")
        # the stream lost sync on this connection, or the command itself is wrong: on the new one
        if fresh is None or fresh.closed_at is not None:
            fresh = self._connect()
            if fresh is None:
                return Hit(Signature("hang", "not accepting", (), "NSQD-ROB-1"), "a new connection was not accepted")
        since = time.monotonic()
        fresh.send(encode(NSQD, name))
        if fresh.wait_for(lambda: any(u.values["state"] == state for u in fresh.updates(since)), window):  # type: ignore[index]
            return Hit(Signature("desync", "command lost", (), "NSQD-MSG-4"),
                       f"{name} sent after the case took no effect within {window:g} s, and did on a new "
                       "connection (the stream lost sync)")
        if not fresh.updates():
            return self.death_hit(0.3) or Hit(Signature("hang", "no UPDATE on a new connection", (), "NSQD-ROB-1"),
                                              "the backend accepts but sends nothing")
        if not fresh.updates(since):  # it sent UPDATEs on it, then none for a window: its stream stopped
            return self.death_hit(0.3) or Hit(Signature("hang", "UPDATE stream stopped", (), "NSQD-MSG-1"),
                                              f"no UPDATE within {window:g} s on a new connection after "
                                              f"{len(fresh.updates())} UPDATE(s) on it")
        self.bad_probes.add(name)  # its own effect is wrong: probe with the other command from now on
        seen_states = sorted({NSQD.state_name(u.values["state"]) for u in fresh.updates(since)})  # type: ignore[index]
        return Hit(Signature("effect", name, (), "NSQD-MSG-3"),
                   f"{name}: UPDATE.state {NSQD.state_name(state)} expected, saw {', '.join(seen_states)}")



class BackendTarget(SpareTarget):
    """A worker's backend as the loop sees a target (``fuzz.target_core.SpareTarget``): the
    one now fuzzed (``current``), ``SPARES`` started ahead (none attached), each sharing the
    first one's :class:`Traits`."""

    current: Backend

    def __init__(self, first: Backend) -> None:
        how, traits = first.how, first.traits
        super().__init__(first, lambda log: Backend(how.target, how.spawn, traits, self), Backend.end,
                         attached=how.attached, timeout=None, n=SPARES,
                         alive=Backend.process_alive)


def violation_hit(conns: Iterable[Conn | None]) -> Hit | None:
    """The first rule the backend's frames on ``conns`` break (``Conn.violation``), as a hit."""
    for c in conns:
        v = c.violation() if c is not None else None
        if v is not None:
            return Hit(Signature("protocol", v.rule, (), v.rule), f"{v.expected}; {v.actual}")
    return None


def message_names(data: bytes) -> list[str]:
    """The message of each frame in ``data``, walked by its length prefixes (after a prefix
    that lies, no further): ``unknown`` for an id that names none, ``-`` for no id at all."""
    names, off = [], 0
    while off + 5 <= len(data):
        n, mid = int.from_bytes(data[off:off + 4], "big", signed=True), data[off + 4]
        names.append(NSQD.message(mid).name if NSQD.has_message(mid) else "unknown")
        if n < 5 or off + n > len(data):
            break
        off += n
    return names or ["-"]


def _defaults(msg: Any) -> dict[str, Any]:
    """Valid values of a message's fields, the same every time (a fixed seed)."""
    return valid_values(NSQD, msg, random.Random(0))


#: The most cases a death's suspects reach back (``Backend.suspects``; the campaign's triage
#: finds the culprit among them by bisection)
SUSPECTS_MAX = 16

#: How long a replay of a crash waits, after its last case, for the process's death or a
#: sanitizer's report to begin (a correct backend's replay waits it out).
REPLAY_DEATH_S = 2.0
#: how long a replay watches for the close it confirms: the campaign's 3-ms window, with no
#: next case to show it, missed a backend closing 6 kB frames on a loaded host (CI, load 9:
#: test_nsqd_case_costs); ended by the close, so a replay that shows it takes no longer
REPLAY_CLOSE_S = 0.5


def _reproduces(backend: Backend, cases: list[Case], sig: Signature, *, probe: bool,
                log: TrafficLog | None = None, wait: float = REPLAY_DEATH_S) -> tuple[bool, Backend, Hit | None]:
    """Whether ``cases`` written to a fresh process show ``sig``; ``wait``: how long, after the
    last, for a death or a report to show (``Backend.suspects``)."""
    b = backend.fresh()
    b.session.recorder = log  # the replay's traffic, for the finding's repro.mcap and repro.pcap
    try:
        return _replay(b, cases, sig, probe=probe, wait=wait)
    finally:
        end_log(b, log)


def end_log(b: Backend, log: TrafficLog | None, close: Callable[[], object] = lambda: None) -> None:
    """A replay's traffic log (``log``, its ``b.session.recorder``) ended: how the connections
    stand at the end read into it (a dead backend's close), then ``close()`` (the replay's own
    closes, logged too), and no more (a stateless replay's and a program's alike)."""
    if log is not None:
        for c in list(b.session.conns):
            with contextlib.suppress(OSError, ValueError):
                c.pump(0)
    close()
    if log is not None:
        log.done = True
    b.session.recorder = None


def _passing(hit: Hit | None, sig: Signature) -> bool:
    """A non-fatal sanitizer report seen on the way in a replay of a death: not its verdict
    (under halt_on_error=0 a real backend over-reads on every frame, then dies of its
    aborting number parse; the replay stopped at the report and "did not reproduce")."""
    return (hit is not None and sig.oracle == "crash" and hit.signature.oracle == "sanitizer"
            and not same_finding(hit.signature, sig))


def _replay(b: Backend, cases: list[Case], sig: Signature, *, probe: bool,
            wait: float = REPLAY_DEATH_S) -> tuple[bool, Backend, Hit | None]:
    hit = passed = None
    death = sig.oracle in ("crash", "sanitizer")
    for c in cases:
        hit = b.run(c)
        if _passing(hit, sig) or (death and hit is not None and hit.signature.oracle not in ("crash", "sanitizer")
                                  and c is not cases[-1]):
            passed, hit = hit, None  # a death's replay goes on past what the cases before it show
            continue
        if hit is not None:
            break
    if death and len(cases) > 1:  # a backend that handles a frame per loop has them queued
        wait = min(REPLAY_DEATH_S, wait + 0.04 * (len(cases) - 1))
    if hit is None and sig.oracle in ("crash", "sanitizer"):
        # a replay has no next case to show a death: wait for it, or for a sanitizer's report,
        # taken whole and followed to the exit (Backend.report_hit). A loaded CI host took
        # more than the 0.5 s this once waited: the report, read half-way, made a crash
        # "sanitizer" and the replay "did not reproduce" (test_nsqd_repro)
        proc, end = b.process, time.monotonic() + wait
        while hit is None and time.monotonic() < end:
            hit = b.death_hit(0.05)
            if hit is None and proc is not None and len(proc.sanitizer_report()) > b.reports_seen:
                hit = b.report_hit()
                if not _passing(hit, sig):
                    break
                passed, hit = hit, None
    if sig.oracle == "sanitizer" and hit is not None and not same_finding(hit.signature, sig):
        # a non-fatal report's verdict is the report, whatever the process did after it (the
        # first report of this fresh process: the replay's own)
        first = b.process.sanitizer_report() if b.process is not None else []
        parsed = parse_sanitizer(first) if first else None
        if parsed and (parsed[0], parsed[2][:3]) == (sig.kind, sig.frames[:3]):
            hit = Hit(Signature("sanitizer", parsed[0], parsed[2], sig.rule), hit.detail, tuple(first[:20]))
    if hit is None and sig.oracle == "close" and cases:  # a replay has no next case to show a close:
        hit = b._close_window(cases[-1].kind, cases[-1].note, REPLAY_CLOSE_S)  # a longer window, ended by it
    if hit is None and probe:
        hit = b.probe()
    hit = hit or passed
    return (hit is not None and same_finding(hit.signature, sig)), b, hit


def _replay_kind(sig: Signature) -> str:
    """The kind of case a finding's writes are replayed as: what lost the stream its sync (a
    bad id's connection must be kept, so the probe goes on it: ``Backend.must_keep``)."""
    lost = "stream lost after "
    return sig.kind[len(lost):] if sig.oracle == "desync" and sig.kind.startswith(lost) else "replay"

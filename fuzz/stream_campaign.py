"""``mcp-fuzz --protocol nsqd``: a campaign against a TCP backend until it breaks (issue 21).

Cases come from ``fuzz.stream_mutators`` (seeded); each is written on a connection to the
backend and judged at once by the oracles of ``fuzz.stream_oracles`` (death, sanitizer
report, a close after valid frames, the backend's own frames); every ``probe_every`` cases a
probe command must still take its effect (else the stream lost sync, or the backend hangs),
and every few hundred connections a spawned backend's descriptors are counted (a leak).

A hit is triaged: the case (or, for a failed probe, each case since the last good one) is
replayed in a fresh process until one reproduces alone; it is minimised (delta debugging
over its writes, then over its bytes); it must then reproduce N of N times (``replays``),
each in a fresh process, with the same signature, or it is dropped as unconfirmed; its
signature deduplicates it. ``finding-N/`` holds ``finding.json``, the input as hex and as a
Python bytes literal, the stderr excerpt and ``replay.txt``; ``mcp-fuzz --protocol nsqd
--replay finding-N`` reproduces it (exit 1) or not (exit 0).
"""

from __future__ import annotations

import contextlib
import json
import random
import shlex
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from fuzz.ddmin import ddmin
from fuzz.stream_findings import TrafficLog, load_stream_finding, write_stream_repro
from fuzz.stream_mutators import Case, Write, draw_case, valid_values
from fuzz.stream_oracles import CLOSE_RULE, Signature, desync_rule, parse_sanitizer, same_finding
from harness.config import RunConfig
from harness.errors import SetupError
from harness.stream_session import Conn, StreamSession
from spec import NSQD
from spec.stream_codec import encode

__all__ = ["StreamCampaign", "replay_stream_finding"]

_same, _ddmin, _CLOSE_RULE = same_finding, ddmin, CLOSE_RULE  # their old names (moved for fuzz.stream_stateful)
_PROBES = (("STOP_TEST", NSQD.states["STOP_TEST"]), ("CAPTURE_IMAGES", NSQD.states["CAPTURE_IMAGES"]))


@dataclass
class Hit:
    signature: Signature
    detail: str
    stderr: tuple[str, ...] = ()


@dataclass
class Finding:
    signature: Signature
    cases: list[Case]
    detail: str
    replays: str
    stderr: tuple[str, ...] = ()
    count: int = 1
    note: str = ""
    traffic: list[Any] = field(default_factory=list)  # the last confirming replay's (repro.mcap, repro.pcap)
    program: list[dict[str, Any]] | None = None  # the stateful engine's: its ops (fuzz.stream_stateful.Op)

    def writes(self) -> list[Write]:
        if self.program is not None:
            return [Write(bytes.fromhex(w["hex"]), w.get("end", "")) for op in self.program for w in op["writes"]]
        return [w for c in self.cases for w in c.writes]


class Backend:
    """The backend under fuzz: a session (spawned, attached or the embedded default) and the
    fuzzer's current connection."""

    def __init__(self, target: tuple[str, int] | None, spawn: str | None) -> None:
        self.target, self.spawn = target, spawn
        self.session = StreamSession(RunConfig(target=target, spawn=spawn))
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

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self.session.close()

    def fresh(self) -> Backend:
        """A new process (spawn mode and the embedded default); attach mode: the same target."""
        if self.target is not None and self.spawn is None:
            self._drop()
            return self
        self.close()
        return Backend(self.target, self.spawn)

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

    def death_hit(self, grace: float) -> Hit | None:
        d = self.session.death(grace=grace)
        if d is None:
            return None
        report = self.session.proc.sanitizer_report() if self.session.proc is not None else []
        parsed = parse_sanitizer(report) if report else None
        if parsed:
            kind, access, frames = parsed
        else:
            kind, access, frames = d.signal_name or f"exit {d.code}", "", ()
        return Hit(Signature("crash", kind, frames, "NSQD-ROB-1", access), d.describe(), tuple(report[:20]) or d.stderr)

    def report_hit(self) -> Hit | None:
        """A new sanitizer report on stderr: once it is whole (SUMMARY, or no line for 0.3 s;
        symbolising its stacks takes a while on a loaded machine), a death if the process then
        exits (ASan's default), else the report of a process still running (halt_on_error=0)."""
        proc = self.session.proc
        assert proc is not None
        report, end, quiet = proc.sanitizer_report(), time.monotonic() + 5.0, time.monotonic() + 0.3
        while time.monotonic() < min(end, quiet) and proc.alive() and not any("SUMMARY:" in x for x in report):
            time.sleep(0.01)
            now = proc.sanitizer_report()
            if len(now) > len(report):
                report, quiet = now, time.monotonic() + 0.3
        self.reports_seen = len(report)
        dead = self.death_hit(0.3)
        if dead is not None:
            return dead
        parsed = parse_sanitizer(report)
        if parsed:
            return Hit(Signature("sanitizer", parsed[0], parsed[2], "NSQD-ROB-1", parsed[1]),
                       "a sanitizer report, the process still running", tuple(report[:20]))
        return None

    def run(self, case: Case) -> Hit | None:
        """Write the case; what the oracles saw, if anything."""
        conn = self.conn if self.conn is not None and self.conn.closed_at is None else self._connect()
        if conn is None:
            return self.death_hit(0.3) or Hit(Signature("hang", "not accepting", (), "NSQD-ROB-1"),
                                              "a new connection was not accepted")
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
            self.conn.pump(0.003)
            if not case.probe and self.conn.closed_at is None and self.death_hit(0.0) is None:
                self._drop()  # a case that may leave the stream unusable: the next starts afresh
        closed_by_backend = self.conn is not None and self.conn.closed_at is not None
        # a death closes the socket as the process exits: where a close would be a finding, a
        # moment to tell the two apart (a close after a bad frame is allowed, and a death then
        # shows at the next case: not worth 30 ms on every framing error)
        hit = self.death_hit(0.03 if closed_by_backend and self.clean else 0.0)
        if hit is not None:
            return hit
        proc = self.session.proc
        if proc is not None:
            report = proc.sanitizer_report()
            if len(report) > self.reports_seen:  # a report: the process may be on its way out
                return self.report_hit()
        if self.conn is not None:  # the backend's own frames first: an effect is read from them
            v = self.conn.violation()
            if v is not None:
                return Hit(Signature("protocol", v.rule, (), v.rule), f"{v.expected}; {v.actual}")
        if case.check and case.expect and self.conn is not None and self.conn.closed_at is None:
            hit = self._effect(case)
            if hit is not None:
                return hit
        if self.conn is not None:
            if self.conn.closed_at is not None and self.clean:
                rule = _CLOSE_RULE.get(case.kind, "NSQD-FRM-5")
                return Hit(Signature("close", case.kind, (), rule),
                           f"the backend closed the connection after frames it handles ({case.note})")
        return None

    def _effect(self, case: Case) -> Hit | None:
        """A valid command's effect shows in UPDATE.state within the effect window (NSQD-MSG-3)."""
        conn = self.conn
        assert conn is not None
        since = conn.sent[-1][0] if conn.sent else time.monotonic()
        window = float(NSQD.params["effect_window_s"])
        before = [u.values["state"] for u in conn.updates() if u.t < since]  # type: ignore[index]
        ok = conn.wait_for(lambda: any(u.values["state"] in case.expect for u in conn.updates(since))  # type: ignore[index]
                           or (case.or_error and bool(conn.errors(since))), window)
        # a state the stream was not in before, reached by the command: the stream is in sync,
        # as a probe would have shown (the campaign starts its probe window afresh)
        self.synced = ok and bool(before) and before[-1] not in case.expect and \
            any(u.values["state"] in case.expect for u in conn.updates(since))  # type: ignore[index]
        v = conn.violation()
        if v is not None:
            return Hit(Signature("protocol", v.rule, (), v.rule), f"{v.expected}; {v.actual}")
        if ok or conn.closed_at is not None:
            return None
        if not conn.updates(since):  # nothing at all: not the command's effect, the backend's liveness
            return self.death_hit(0.3) or Hit(Signature("hang", "UPDATE stream stopped", (), "NSQD-MSG-1"),
                                              f"no UPDATE within {window:g} s on an open connection")
        seen = sorted({NSQD.state_name(u.values["state"]) for u in conn.updates(since)})  # type: ignore[index]
        return Hit(Signature("effect", case.msg or case.note, (), "NSQD-MSG-3"),
                   f"{case.note}: UPDATE.state {' or '.join(NSQD.state_name(s) for s in case.expect)} expected, "
                   f"saw {', '.join(seen) or 'no UPDATE'}")

    def probe(self) -> Hit | None:
        """A command on the current connection (a new one if the backend closed it, unless it
        had to keep it: ``must_keep``) must take its effect within the effect window."""
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
        seen = conn.wait_for(lambda: any(u.values["state"] == state for u in conn.updates(since)), window)  # type: ignore[index]
        hit = self.death_hit(0.3 if conn.closed_at else 0.0)
        if hit is not None:
            return hit
        v = conn.violation()
        if v is not None:
            return Hit(Signature("protocol", v.rule, (), v.rule), f"{v.expected}; {v.actual}")
        if seen:
            return None
        if conn.closed_at is None and not conn.updates(since):
            return Hit(Signature("hang", "UPDATE stream stopped", (), "NSQD-MSG-1"),
                       f"no UPDATE within {window:g} s on an open connection")
        # the stream lost sync on this connection, or the command itself is wrong: on a new one
        fresh = self._connect()
        if fresh is None:
            return Hit(Signature("hang", "not accepting", (), "NSQD-ROB-1"), "a new connection was not accepted")
        since = time.monotonic()
        fresh.send(encode(NSQD, name))
        if fresh.wait_for(lambda: any(u.values["state"] == state for u in fresh.updates(since)), window):  # type: ignore[index]
            return Hit(Signature("desync", "command lost", (), "NSQD-MSG-4"),
                       f"{name} sent after the case took no effect within {window:g} s, and did on a new "
                       "connection (the stream lost sync)")
        if not fresh.updates(since):
            return self.death_hit(0.3) or Hit(Signature("hang", "no UPDATE on a new connection", (), "NSQD-ROB-1"),
                                              "the backend accepts but sends nothing")
        self.bad_probes.add(name)  # its own effect is wrong: probe with the other command from now on
        seen = sorted({NSQD.state_name(u.values["state"]) for u in fresh.updates(since)})  # type: ignore[index]
        return Hit(Signature("effect", name, (), "NSQD-MSG-3"),
                   f"{name}: UPDATE.state {NSQD.state_name(state)} expected, saw {', '.join(seen)}")

    def fds(self) -> int | None:
        return self.session.open_fds()


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


def _reproduces(backend: Backend, cases: list[Case], sig: Signature, *, probe: bool,
                log: TrafficLog | None = None) -> tuple[bool, Backend, Hit | None]:
    b = backend.fresh()
    b.session.recorder = log  # the replay's traffic, for the finding's repro.mcap and repro.pcap
    try:
        return _replay(b, cases, sig, probe=probe)
    finally:
        if log is not None:
            for c in list(b.session.conns):  # how the connections stand at the end: a dead backend's close
                with contextlib.suppress(OSError, ValueError):
                    c.pump(0)
            log.done = True
        b.session.recorder = None


def _replay(b: Backend, cases: list[Case], sig: Signature, *, probe: bool) -> tuple[bool, Backend, Hit | None]:
    hit = None
    for c in cases:
        hit = b.run(c)
        if hit is not None:
            break
    if hit is None and sig.oracle in ("crash", "sanitizer"):
        hit = b.death_hit(0.5)  # a replay has no next case to show a death: wait for it
        if hit is None and b.session.proc is not None and b.session.proc.sanitizer_report():
            parsed = parse_sanitizer(b.session.proc.sanitizer_report())
            if parsed:
                hit = Hit(Signature("sanitizer", parsed[0], parsed[2], "NSQD-ROB-1", parsed[1]), "a sanitizer report")
    if hit is None and probe:
        hit = b.probe()
    return (hit is not None and _same(hit.signature, sig)), b, hit


def _replay_kind(sig: Signature) -> str:
    """The kind of case a finding's writes are replayed as: what lost the stream its sync (a
    bad id's connection must be kept, so the probe goes on it: ``Backend.must_keep``)."""
    lost = "stream lost after "
    return sig.kind[len(lost):] if sig.oracle == "desync" and sig.kind.startswith(lost) else "replay"


@dataclass
class StreamCampaign:
    target: tuple[str, int] | None
    spawn: str | None
    seed: int
    duration: float | None
    max_cases: int | None
    out: Path | None
    replays: int = 3
    probe_every: int = 40
    stop_after: int | None = None  # end the campaign once this many findings are confirmed
    findings: list[Finding] = field(default_factory=list)
    unconfirmed: int = 0
    cases: int = 0
    by_kind: dict[str, int] = field(default_factory=dict)
    restarts: int = 0
    engine: str = "stateless"  # stateless | stateful | both (the duration split between them)
    db: str | None = None  # hypothesis's example database of the stateful engine (--db)
    worker: int = 0  # a --jobs worker's index: its own seed stream
    tick: Callable[[StreamCampaign], None] | None = None  # live progress (fuzz.stream_progress)
    tried: dict[str, dict[str, int]] = field(default_factory=dict)  # kind -> message -> cases
    fuzz_s: float = 0.0  # seconds spent fuzzing (triage's replays excluded)
    triage_s: float = 0.0
    started: float = field(default_factory=time.monotonic)
    stop: Callable[[], bool] = lambda: False  # a --jobs parent's stop request
    current: Any = None  # the backend now fuzzed (closed at the end, whatever ends the campaign)
    workers: list[dict[str, Any]] | None = None  # --jobs: each worker's figures (fuzz.stream_jobs)

    def _over(self, deadline: float) -> bool:
        return (time.monotonic() >= deadline or (self.max_cases is not None and self.cases >= self.max_cases)
                or (self.stop_after is not None and len(self.findings) >= self.stop_after) or self.stop())

    def note_tried(self, kind: str, data: bytes) -> None:
        """Which message ids x mutation kinds were sent (the progress table, summary.json)."""
        row = self.tried.setdefault(kind, {})
        for name in message_names(data):
            row[name] = row.get(name, 0) + 1

    def _tick(self) -> None:
        if self.tick is not None:
            self.tick(self)

    def run(self) -> dict[str, Any]:
        self.started = t0 = time.monotonic()
        engines = ["stateless", "stateful"] if self.engine == "both" else [self.engine]
        backend = self.current = Backend(self.target, self.spawn)
        try:
            for k, name in enumerate(engines):
                deadline = t0 + self.duration * (k + 1) / len(engines) if self.duration is not None else float("inf")
                if name == "stateful":
                    from fuzz.stream_stateful import StreamStatefulEngine

                    backend = StreamStatefulEngine(self, backend, self.db, self.worker).run(
                        lambda d=deadline: self._over(d), self._tick)
                else:
                    backend = self._stateless(backend, deadline)
        finally:
            self.current.close()
        return self.summary(time.monotonic() - t0)

    def add_program(self, backend: Backend, hit: Any, ops: list[Any]) -> Backend:
        """A stateful program's failure: triaged like a case's (fuzz.stream_stateful)."""
        from fuzz.stream_stateful import triage_program

        t0 = time.monotonic()
        try:
            return triage_program(self, backend, hit, ops)
        finally:
            self.triage_s += time.monotonic() - t0

    def add_program_finding(self, sig: Signature, detail: str, replays: str, stderr: tuple[str, ...], note: str,
                            program: list[dict[str, Any]]) -> None:
        self._add(Finding(sig, [], detail, replays, stderr, note=note, program=program))

    def _stateless(self, backend: Backend, deadline: float) -> Backend:
        rng = random.Random(self.seed if not self.worker else hash((self.seed, self.worker)))
        window: list[Case] = []
        fds0, conns0, leak_reported = backend.fds(), 0, False
        n, last_tick = 0, 0.0
        t_fuzz = time.monotonic()
        try:
            while not self._over(deadline):
                case = draw_case(rng)
                if case.expect and n % 4 == 0:  # one valid command in four is judged by its effect
                    case = replace(case, check=True)
                n += 1
                self.cases += 1
                self.by_kind[case.kind] = self.by_kind.get(case.kind, 0) + 1
                self.note_tried(case.kind, case.data)
                if time.monotonic() - last_tick >= 0.25:
                    last_tick = time.monotonic()
                    self.fuzz_s += last_tick - t_fuzz
                    t_fuzz = last_tick
                    self._tick()
                window.append(case)
                hit = backend.run(case)
                probe = False
                if hit is None and backend.synced:  # a judged effect proved the stream in sync
                    backend.synced = False
                    window.clear()
                if hit is None and len(window) >= self.probe_every:
                    hit, probe = backend.probe(), True
                    if hit is None:
                        window.clear()
                if hit is not None:
                    # a death may show only at the next case's write: the one before is a suspect too
                    t1 = time.monotonic()
                    self.fuzz_s += t1 - t_fuzz
                    backend = self.current = self._triage(backend, hit, list(window) if probe else window[-2:], probe)
                    t_fuzz = time.monotonic()
                    self.triage_s += t_fuzz - t1
                    window.clear()
                    continue
                if not leak_reported and self.cases % 400 == 0 and fds0 is not None:
                    fds = backend.fds()
                    grown = (fds or 0) - fds0
                    if fds is not None and grown > int(NSQD.params["fd_growth_max"]) and backend.connections - conns0 >= 50:
                        leak_reported = True
                        self._add(Finding(Signature("leak", "open descriptors grow with connections", (), "NSQD-CON-3"),
                                          [], f"{fds0} -> {fds} open descriptors over {backend.connections - conns0} "
                                          "connections", "observed over the campaign", note="connect/close cycles"))
        finally:
            self.fuzz_s += time.monotonic() - t_fuzz
        return backend

    def _triage(self, backend: Backend, hit: Hit, suspects: list[Case], probe: bool) -> Backend:
        sig = hit.signature
        known = next((f for f in self.findings if f.signature.key == sig.key), None)
        if known is not None and sig.oracle != "desync":  # deduplicated before any replay: counted
            known.count += 1
            return backend.fresh() if sig.oracle in ("crash", "hang", "sanitizer") else backend
        if self.target is not None and self.spawn is None and sig.oracle in ("crash", "hang") \
                and backend.session.death() is not None:
            raise SetupError(f"the attached backend is gone ({hit.detail}); findings so far are kept")
        culprit: list[Case] | None = None
        if sig.oracle == "effect" and any(m.name == sig.kind for m in NSQD.messages):
            # a command's own effect: the command alone (plain values), judged by its effect
            msg = NSQD.message(sig.kind)
            culprit = [Case("valid", (Write(encode(NSQD, msg.name, **_defaults(msg))),), True, msg.name,
                            expect=msg.effect.to, or_error=msg.effect.or_error, check=True)]
            suspects, probe = [], False
        if probe and len(suspects) > 2:
            # a failed probe: the cases since the last good one, replayed together, then delta
            # debugged down to the case(s) that break the stream (log n replays, not n)
            ok, backend, _ = _reproduces(backend, suspects, sig, probe=True)
            self.restarts += 1
            if ok:
                box = {"b": backend}

                def still(cs: list[Case]) -> bool:
                    good, box["b"], _ = _reproduces(box["b"], cs, sig, probe=True)
                    return good

                culprit = _ddmin(list(suspects), still, budget=20)
                backend = box["b"]
            suspects = []
        for c in reversed(suspects):  # the newest suspect first
            ok, backend, _ = _reproduces(backend, [c], sig, probe=probe)
            self.restarts += 1
            if ok:
                culprit = [c]
                break
        if culprit is None and len(suspects) > 1 and sig.oracle != "effect":
            ok, backend, _ = _reproduces(backend, suspects, sig, probe=probe)
            culprit = suspects if ok else None
        if culprit is None:
            self.unconfirmed += 1
            return backend.fresh()
        if sig.oracle == "desync":  # named by what lost the stream its sync
            kind = culprit[-1].kind
            sig = Signature("desync", f"stream lost after {kind}", (), desync_rule(kind))
            hit = Hit(sig, hit.detail, hit.stderr)
        known = next((f for f in self.findings if f.signature.key == sig.key), None)
        if known is not None:
            known.count += 1
            return backend.fresh()
        state = {"b": backend}

        def test(writes: list[Write]) -> bool:
            ok, state["b"], _ = _reproduces(state["b"], [Case(_replay_kind(sig), tuple(writes))], sig, probe=probe)
            return ok

        writes = [w for c in culprit for w in c.writes]
        if sig.oracle != "effect":
            writes = _ddmin(writes, test, budget=24)
        if len(writes) == 1 and not writes[0].end and sig.oracle in ("crash", "sanitizer"):
            data = writes[0].data
            for cut in (len(data) // 2, len(data) * 3 // 4, len(data) - 1):  # a shorter tail, if it still reproduces
                if 0 < cut < len(data) and test([Write(data[:cut])]):
                    data = data[:cut]
            writes = [Write(data)]
        c0 = culprit[0]
        minimal = [Case(c0.kind, tuple(writes), c0.valid, c0.note, expect=c0.expect, or_error=c0.or_error,
                        check=c0.check)]
        confirmed = 0
        traffic: list[Any] = []
        for _ in range(self.replays):
            log = TrafficLog()
            ok, state["b"], last = _reproduces(state["b"], minimal, sig, probe=probe, log=log)
            confirmed += ok
            traffic = log.records if ok else traffic
            if last is not None and last.stderr:
                hit = Hit(hit.signature, hit.detail, last.stderr)
        if confirmed < self.replays:
            self.unconfirmed += 1
            return state["b"].fresh()
        self._add(Finding(sig, minimal, hit.detail, f"{confirmed} of {self.replays}", hit.stderr,
                          note=culprit[0].note + (" (then a probe command)" if probe else ""), traffic=traffic))
        return state["b"].fresh()

    def _add(self, f: Finding) -> None:
        self.findings.append(f)
        if self.out is not None:
            write_finding(self.out / f"finding-{len(self.findings)}", f, self.spawn, self.target, probe="probe" in f.note)

    def summary(self, elapsed: float) -> dict[str, Any]:
        """``summary.json``: cases, judged cases/s (triage's replays excluded), findings by
        class (the oracle) and each one, which message ids x mutation kinds were sent."""
        by_class: dict[str, int] = {}
        for f in self.findings:
            by_class[f.signature.oracle] = by_class.get(f.signature.oracle, 0) + 1
        s = {"protocol": "nsqd", "engine": self.engine, "seed": self.seed, "cases": self.cases,
             "elapsed_s": round(elapsed, 2), "cases_per_s": round(self.cases / elapsed, 1) if elapsed else 0,
             "fuzz_s": round(self.fuzz_s, 2), "triage_s": round(self.triage_s, 2),
             "judged_cases_per_s": round(self.cases / self.fuzz_s, 1) if self.fuzz_s else 0,
             "by_kind": self.by_kind, "tried": self.tried, "findings_by_class": by_class,
             "findings": [{"signature": f.signature.describe(), "oracle": f.signature.oracle, "rule": f.signature.rule,
                           "count": f.count, "replays": f.replays, "engine": "stateful" if f.program is not None
                           else "stateless"} for f in self.findings],
             "unconfirmed": self.unconfirmed, "restarts": self.restarts, "db": self.db,
             "jobs": len(self.workers) if self.workers is not None else 1}
        if self.workers is not None:
            s["workers"] = self.workers
        if self.out is not None:
            (self.out / "summary.json").write_text(json.dumps(s, indent=2) + "\n")
        return s


def write_finding(d: Path, f: Finding, spawn: str | None, target: tuple[str, int] | None, *, probe: bool) -> None:
    d.mkdir(parents=True, exist_ok=True)
    data = b"".join(w.data for w in f.writes())
    doc = {"protocol": "nsqd", "oracle": f.signature.oracle, "kind": f.signature.kind, "access": f.signature.access,
           "frames": list(f.signature.frames), "rule": f.signature.rule, "level": "MUST",
           "description": f.signature.describe(), "detail": f.detail, "note": f.note, "replays": f.replays,
           "probe": probe, "writes": [{"hex": w.data.hex(), "end": w.end} for w in f.writes()],
           "expect": [list(c.expect) for c in f.cases if c.check], "or_error": any(c.or_error for c in f.cases)}
    if f.program is not None:
        doc["program"] = f.program
    (d / "finding.json").write_text(json.dumps(doc, indent=2) + "\n")
    write_stream_repro(d, doc, f.traffic)
    (d / "input.hex").write_text(data.hex(" ") + "\n")
    (d / "input.py").write_text(f"# {f.signature.describe()}\nINPUT = {data!r}\n")
    (d / "stderr.txt").write_text("\n".join(f.stderr) + "\n")
    how = ["--spawn", spawn] if spawn else (["--target", f"{target[0]}:{target[1]}"] if target else [])
    (d / "replay.txt").write_text(shlex.join(["mcp-fuzz", "--protocol", "nsqd", "--replay", str(d.resolve()), *how]) + "\n")


def replay_stream_finding(path: str, target: tuple[str, int] | None, spawn: str | None,
                          prog: str = "mcp-fuzz") -> int:
    """Replay a finding (``finding-N/``, its finding.json, repro.mcap or repro.pcap) once in a
    fresh backend: 1 reproduced, 0 not, 2 unreadable."""
    doc_path = path
    try:
        doc = load_stream_finding(path)
        writes = [Write(bytes.fromhex(w["hex"]), w.get("end", "")) for w in doc["writes"]]
        expect = tuple(doc.get("expect", [[]])[0]) if doc.get("expect") else ()
        sig = Signature(doc["oracle"], doc["kind"], tuple(doc.get("frames", [])), doc["rule"], doc.get("access", ""))
        program = None
        if doc.get("program"):
            from fuzz.stream_stateful import Op

            program = [Op.from_json(o) for o in doc["program"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"{prog}: error: {'--replay: ' if prog == 'mcp-fuzz' else ''}cannot read {doc_path}: {exc}")
        return 2
    if not writes and program is None:
        print(f"{prog}: {sig.describe()}: observed over a campaign (connect/close cycles); replay it with "
              "mcp-conform --protocol nsqd --select NSQD-CON-3")
        return 2
    backend = Backend(target, spawn)
    if program is not None:
        from fuzz.stream_stateful import play_program

        try:
            seen = play_program(backend, program)
        finally:
            backend.close()
        if seen is not None and _same(seen.signature, sig):
            print(f"reproduced {sig.rule}: {sig.describe()}")
            return 1
        print(f"did not reproduce {sig.describe()}" + (f" (saw {seen.signature.describe()})" if seen else ""))
        return 0
    try:
        case = Case(_replay_kind(sig), tuple(writes), bool(expect), sig.kind if expect else "", expect=expect,
                    or_error=bool(doc.get("or_error")), check=bool(expect))
        ok, backend, hit = _reproduces(backend, [case], sig, probe=bool(doc.get("probe")))
    finally:
        backend.close()
    if ok:
        print(f"reproduced {sig.rule}: {sig.describe()}")
        return 1
    print(f"did not reproduce {sig.describe()}" + (f" (saw {hit.signature.describe()})" if hit else ""))
    return 0

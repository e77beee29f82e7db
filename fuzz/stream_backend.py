"""The backend under ``mcp-fuzz --protocol nsqd`` and the replay of cases on it (issue 21).

:class:`Backend` holds a session (spawned, attached or the embedded default) and the current
connection; ``run`` writes a case and asks the oracles of ``fuzz.stream_oracles`` what they
saw, ``probe`` checks that a command still takes its effect. ``_reproduces`` replays cases in
a fresh process, as triage and ``--replay`` do (``fuzz.stream_campaign``).
"""

from __future__ import annotations

import contextlib
import random
import time
from dataclasses import dataclass
from typing import Any

from fuzz.stream_findings import TrafficLog
from fuzz.stream_mutators import Case, valid_values
from fuzz.stream_oracles import CLOSE_RULE, Signature, parse_sanitizer, same_finding
from harness.config import RunConfig
from harness.stream_session import Conn, StreamSession
from spec import NSQD
from spec.stream_codec import encode

__all__ = ["Backend", "Hit", "message_names"]

_same, _CLOSE_RULE = same_finding, CLOSE_RULE
_PROBES = (("STOP_TEST", NSQD.states["STOP_TEST"]), ("CAPTURE_IMAGES", NSQD.states["CAPTURE_IMAGES"]))


@dataclass
class Hit:
    signature: Signature
    detail: str
    stderr: tuple[str, ...] = ()


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

"""The per-case context of an Nsqd backend case (``--protocol nsqd``): the ``node`` fixture.

A case opens connections (:meth:`StreamCaseContext.open`), sends frames whole, split or
batched, then calls one verify helper; the helpers raise ``CaseFailure`` naming the rule,
what was expected and what was seen. Every frame the backend sends on any connection is
judged on the way (NSQD-FRM-1: its length; NSQD-MSG-2: its layout, its id, UPDATE's state),
so a broken sender fails under its own rule whatever case saw it. A spawned backend that
dies is an NSQD-ROB-1 failure naming the rule the case's input tested, with the signal, the
sanitizer's summary line first, and the bytes sent in hex (the session restarts it for the
next case). Before its verdict a case proves the backend alive after its last write
(:meth:`StreamCaseContext.conclude`): a death seen late is still the case's that caused it.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

from mcp_conform.conformance._case_base import CaseBase
from mcp_conform.harness.errors import CaseFailure, Inconclusive, NodeLost
from mcp_conform.harness.nsqd_session import Conn, StreamSession
from mcp_conform.spec.nsqd_codec import encode, frame

__all__ = ["StreamCaseContext"]

#: How long a backend that refused, closed or stopped serving a new connection may take to be
#: seen dead: a dying process closes its sockets a moment before it is reaped (a loaded host,
#: a sanitizer writing its report). Waited only on that path, a failing case's: a backend still
#: running after it fails the same rule, only with no death to name (CI beside other workers
#: once saw a Python backend that aborts 0.3 s after closing its listener still running at 1 s).
DYING_S = 3.0


class StreamCaseContext(CaseBase):
    """What a backend case sees (see the module docstring)."""

    subject = "the backend"
    session: StreamSession

    def __init__(self, session: StreamSession, case_id: str, rules: tuple[str, ...]) -> None:
        super().__init__(session, case_id, rules)
        self.spec = session.spec
        self.params = self.spec.params
        self.window = float(self.params["effect_window_s"])
        self.gap_max = float(self.params["update_gap_max_s"])

    # -- frames -------------------------------------------------------------------------
    def encode(self, name: str, **values: Any) -> bytes:
        return encode(self.spec, name, **values)

    def frame(self, msg_id: int, body: bytes = b"", *, length: int | None = None) -> bytes:
        return frame(self.spec, msg_id, body, length=length)

    def state_value(self, name: str) -> int:
        return self.spec.states[name]

    # -- failures -----------------------------------------------------------------------
    def _sent_hex(self) -> list[str]:
        return [f"sent {len(data)} B: {data[:64].hex(' ')}{' …' if len(data) > 64 else ''}"
                for _, data in self.session.sent_log[-6:]]

    def fail(self, rule: str, expected: str, actual: str, evidence: Sequence[str] = ()) -> CaseFailure:
        """The failure to raise; a dead backend is reported instead, under the case's rule
        (a connection the backend closed may be its death on the way: a moment's grace)."""
        closed = any(c.closed_at is not None for c in self.session.conns)
        death = self.session.death(grace=0.5 if closed else 0.05)
        if death is not None:
            ev = ([death.sanitizer] if death.sanitizer else []) + self._sent_hex() + [f"stderr: {line}" for line in death.stderr[-6:]]
            # one fault, one root: a death is NSQD-ROB-1's ("no input ends the backend"),
            # whatever the case was testing, which the evidence names with the bytes sent
            ev.append(f"while testing {', '.join(self.rules)} ({self.case_id})")
            return CaseFailure("NSQD-ROB-1", "the backend survives the input and keeps serving", death.describe(),
                               ev, relies_on=())
        return CaseFailure(rule, expected, actual, list(evidence) + self._sent_hex())

    def check_stream(self, conn: Conn) -> None:
        """What the backend sent on ``conn`` so far obeys NSQD-FRM-1 and NSQD-MSG-2."""
        conn.pump(0)
        v = conn.violation()
        if v is not None:
            raise self.fail(v.rule, v.expected, v.actual, list(v.evidence))

    # -- connections ----------------------------------------------------------------------
    def open(self) -> Conn:
        """A connection the backend accepted and sent an UPDATE on (else the case cannot run)."""
        conn = self.session.connect()
        if conn is not None and conn.wait_for(lambda: bool(conn.updates()) or conn.framing_error is not None
                                              or any(r.problem for r in conn.frames),
                                              self.gap_max + 0.5):
            self.check_stream(conn)
            return conn
        if conn is not None:
            self.check_stream(conn)
        # refused or closed: a dying backend closes its sockets a moment before it is reaped
        death = self.session.death(grace=DYING_S if conn is None or conn.closed_at is not None else 0.0)
        if death is not None:
            raise self.fail(self.rules[0], "", "")
        raise NodeLost("the backend accepted no connection or sent no UPDATE on it "
                       f"within {self.gap_max + 0.5:g} s")

    def state(self, conn: Conn) -> int | None:
        ups = conn.updates()
        return ups[-1].values["state"] if ups else None  # type: ignore[index]

    def settle(self, conn: Conn, *, avoid: tuple[int, ...] = ()) -> int:
        """Bring the backend to a known state outside ``avoid`` (CAPTURE_IMAGES, else STOP_TEST)
        and return it; Inconclusive when it does not get there."""
        for name in ("CAPTURE_IMAGES", "STOP_TEST", "TAKEOFF"):
            target = self.spec.message(name).effect.to[0]
            if target in avoid:
                continue
            since = time.monotonic()
            conn.send(self.encode(name))
            if conn.wait_for(lambda t=target, s=since: any(u.values["state"] == t for u in conn.updates(s)),  # type: ignore[index]
                             self.window):
                self.check_stream(conn)
                conn.pump(0.05)
                return target
            self.check_stream(conn)
        raise Inconclusive("the backend did not reach a known flight state (CAPTURE_IMAGES, STOP_TEST or "
                           "TAKEOFF) to start this case from: its effect is judged by NSQD-MSG-3's cases")

    def probe(self, conn: Conn) -> tuple[str, int]:
        """A command whose effect this backend was seen to take, sent whole (a control for
        cases that judge framing or streams by a command's effect: a wrong effect is
        NSQD-MSG-3's failure, not theirs); found once per run."""
        found = self.session.proven_probe
        if found is None:
            for name in ("STOP_TEST", "CAPTURE_IMAGES", "STOP_HOVER_TEST", "TAKEOFF"):
                target = self.spec.message(name).effect.to[0]
                try:
                    self.settle(conn, avoid=(target,))
                except Inconclusive:
                    continue
                since = time.monotonic()
                conn.send(self.encode(name))
                if conn.wait_for(lambda t=target, s=since: any(u.values["state"] == t for u in conn.updates(s)),  # type: ignore[index]
                                 self.window):
                    found = (name, target)
                    break
            self.check_stream(conn)
            if found is None:
                raise Inconclusive("no command was seen to take its effect (STOP_TEST, CAPTURE_IMAGES, "
                                   "STOP_HOVER_TEST, TAKEOFF): NSQD-MSG-3's cases say why")
            self.session.proven_probe = found
        return found

    def conclude(self) -> None:
        """Before the case's verdict: the backend proven alive after the case's last write
        (NSQD-ROB-1), so a death on it is this case's failure, with the write that killed it
        in the evidence, not the next case's (a closed connection, or a backend that stopped
        serving, may be a death whose process has not ended yet). The case's connections
        are closed (read to the end first: a FIN, not a reset), then a new one must be
        accepted and sent UPDATE; a case that proved it already (:meth:`expect_alive`, a
        new connection served after its last write) costs nothing."""
        if self.session.proven_alive():
            return
        for c in list(self.session.conns):
            c.pump(0)
            c.close()
        self.session.conns.clear()
        timeout = self.gap_max + 0.5
        if self.session.live(timeout):
            return
        self.session.death(grace=DYING_S)  # the process's end follows its sockets' by a moment
        raise self.fail("NSQD-ROB-1", "after the case's input, a new connection accepted and sent UPDATE",
                        f"no UPDATE on a new connection within {timeout:g} s")

    # -- verify helpers -------------------------------------------------------------------
    def expect_state(self, conn: Conn, states: tuple[int, ...], since: float, rule: str, what: str,
                     *, or_error: bool = False) -> None:
        """An UPDATE after ``since`` shows one of ``states`` within the effect window (or,
        with ``or_error``, an ERROR says the autopilot refused: D-6)."""
        def seen() -> bool:
            if any(u.values["state"] in states for u in conn.updates(since)):  # type: ignore[index]
                return True
            return or_error and bool(conn.errors(since))
        ok = conn.wait_for(seen, self.window)
        self.check_stream(conn)
        if not ok:
            got = [self.spec.state_name(u.values["state"]) for u in conn.updates(since)]  # type: ignore[index]
            names = " or ".join(self.spec.state_name(s) for s in states)
            closed = " (the backend closed the connection)" if conn.closed_at else ""
            raise self.fail(rule, f"after {what}, UPDATE.state {names} within {self.window:g} s",
                            f"states seen: {', '.join(dict.fromkeys(got)) or 'no UPDATE'}{closed}")

    def expect_unchanged(self, conn: Conn, prior: int, since: float, rule: str, what: str) -> None:
        """Two UPDATEs after ``since`` (bounded by the effect window) still show ``prior``;
        a close by the backend is allowed (D-3) and then a new connection must show it."""
        conn.wait_for(lambda: len(conn.updates(since)) >= 2, self.window)
        self.check_stream(conn)
        states = [u.values["state"] for u in conn.updates(since)]  # type: ignore[index]
        if conn.closed_at is not None and not states:
            other = self.open()
            other.wait_for(lambda: len(other.updates()) >= 1, self.gap_max)
            states = [u.values["state"] for u in other.updates()]  # type: ignore[index]
        changed = [s for s in states if s != prior]
        if changed:
            raise self.fail(rule, f"after {what}, the flight state stays {self.spec.state_name(prior)}",
                            f"UPDATE.state became {self.spec.state_name(changed[0])}")

    def expect_error(self, conn: Conn, since: float, rule: str, what: str) -> None:
        ok = conn.wait_for(lambda: bool(conn.errors(since)), self.window)
        self.check_stream(conn)
        if not ok:
            raise self.fail(rule, f"an ERROR frame after {what}", f"no ERROR within {self.window:g} s"
                            + (" (the backend closed the connection)" if conn.closed_at else ""))

    def expect_closed(self, conn: Conn, rule: str, what: str) -> None:
        window = float(self.params["close_window_s"])
        ok = conn.wait_for(lambda: conn.closed_at is not None, window)
        if not ok:
            if self.session.death() is not None:
                raise self.fail(rule, "", "")
            raise self.fail(rule, f"the backend closes the connection after {what}",
                            f"still open {window:g} s later ({len(conn.updates())} UPDATEs on it)")

    def expect_alive(self, rule: str = "NSQD-ROB-1", what: str = "the input") -> Conn:
        """The backend still serves: a new connection is accepted and gets UPDATE."""
        for c in list(self.session.conns):
            c.close()
            self.session.conns.remove(c)
        conn = self.session.connect()
        ok = conn is not None and conn.wait_for(lambda: bool(conn.updates()), self.gap_max + 0.5)
        if conn is not None:
            self.check_stream(conn)
        if not ok:
            raise self.fail(rule, f"after {what}, a new connection accepted and sent UPDATE",
                            "refused" if conn is None else f"no UPDATE within {self.gap_max + 0.5:g} s")
        return conn  # type: ignore[return-value]



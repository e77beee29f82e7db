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
The connections, the failures, the liveness proof and the close and alive checks are the
shared core's (``conformance._conn_case.ConnCaseBase``), Nsqd its declared parameter; this
module adds Nsqd's frames, flight states and verify helpers.
"""

from __future__ import annotations

from typing import Any

from mcp_conform.conformance._conn_case import ConnCaseBase
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.harness.nsqd_session import Conn, StreamSession
from mcp_conform.spec.nsqd_codec import encode, frame

__all__ = ["SETTLE_COMMANDS", "StreamCaseContext"]

#: The commands :meth:`StreamCaseContext.settle` brings the backend to a known state with, in order.
SETTLE_COMMANDS = ("CAPTURE_IMAGES", "STOP_TEST", "TAKEOFF")


class StreamCaseContext(ConnCaseBase):
    """What a backend case sees (see the module docstring)."""

    death_rule = "NSQD-ROB-1"
    session: StreamSession

    def __init__(self, session: StreamSession, case_id: str, rules: tuple[str, ...]) -> None:
        super().__init__(session, case_id, rules)
        self.window = float(self.params["effect_window_s"])

    # -- frames -------------------------------------------------------------------------
    def encode(self, name: str, **values: Any) -> bytes:
        return encode(self.spec, name, **values)

    def frame(self, msg_id: int, body: bytes = b"", *, length: int | None = None) -> bytes:
        return frame(self.spec, msg_id, body, length=length)

    def state_value(self, name: str) -> int:
        return self.spec.states[name]

    # -- the backend's flight state ---------------------------------------------------------
    def state(self, conn: Conn) -> int | None:
        ups = conn.updates()
        return ups[-1].values["state"] if ups else None  # type: ignore[index]

    def lands(self, conn: Conn, name: str, target: int) -> bool:
        """Command ``name`` sent whole, and its effect (an UPDATE showing state ``target``)
        seen within the effect window."""
        since = self.now()
        conn.send(self.encode(name))
        return conn.wait_for(lambda: any(u.values["state"] == target for u in conn.updates(since)),  # type: ignore[index]
                             self.window)

    def settle(self, conn: Conn, *, avoid: tuple[int, ...] = ()) -> int:
        """Bring the backend to a known state outside ``avoid`` (CAPTURE_IMAGES, else STOP_TEST,
        else TAKEOFF) and return it; Inconclusive when it does not get there. A command this
        backend was seen not to take within the effect window is tried after the others for
        the rest of the run (never dropped: it goes back in line once seen to land), so a
        backend whose CAPTURE_IMAGES lands elsewhere (NSQD-MSG-3's failure, judged by its own
        case) costs one window per run, not one per case. A case judging NSQD-MSG-3 starts
        with :meth:`start_outside` instead (judged even when none lands)."""
        missed = self.session.settle_missed
        order = [n for n in SETTLE_COMMANDS if n not in missed] + [n for n in missed]
        for name in order:
            target = self.spec.message(name).effect.to[0]
            if target in avoid:
                continue
            if self.lands(conn, name, target):
                if name in missed:
                    missed.remove(name)
                self.check_stream(conn)
                return target
            if name not in missed:
                missed.append(name)
            self.check_stream(conn)
        raise Inconclusive("the backend did not reach a known flight state (CAPTURE_IMAGES, STOP_TEST or "
                           "TAKEOFF) to start this case from: NSQD-MSG-3's cases of those commands judge them")

    def start_outside(self, conn: Conn, avoid: tuple[int, ...]) -> tuple[int, str]:
        """Where a case judging a command's effect (NSQD-MSG-3) starts from: a state outside
        ``avoid`` (the command's ``to``), settled (:meth:`settle`) or else the one the backend
        shows now, and how it got there (for the failure's wording). Any state outside ``to``
        shows the effect (NSQD-MSG-3 is unconditional: the handler sets the state, or the
        autopilot refuses with ERROR; ``to`` names where the backend's own loop may move it
        after), so the unsettled start cannot fail a correct backend (it may pass a fault
        only where the loop itself moves the state into ``to``). A backend that ignores the
        settling commands is judged this way by each command's own case (at most one of
        CAPTURE_IMAGES, STOP_TEST and HOVER is the state it sits in: the others' cases
        judge); Inconclusive only when its state is unknown (no UPDATE: NSQD-CON-1 and
        NSQD-MSG-1 judge that) or already inside ``to`` (the effect could not be told from no
        effect). Once every settling command was seen
        not to land this run, the state it shows now is taken without trying them again (one
        window per case, not four, on a backend that ignores them all)."""
        now = self.state(conn) if set(SETTLE_COMMANDS) <= set(self.session.settle_missed) else None
        if now is not None and now not in avoid:
            return now, self._unsettled(now)
        try:
            return self.settle(conn, avoid=avoid), "settled"
        except Inconclusive as unsettled:
            now = self.state(conn)
            if now is None or now in avoid:
                where = "no UPDATE" if now is None else f"it shows {self.spec.state_name(now)}"
                raise Inconclusive(f"{unsettled} ({where}, where this command's effect cannot be seen)") from None
            return now, self._unsettled(now)

    def _unsettled(self, now: int) -> str:
        return (f"from {self.spec.state_name(now)}, unsettled: none of {', '.join(SETTLE_COMMANDS)} was seen "
                "to take its effect")

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
                if self.lands(conn, name, target):
                    found = (name, target)
                    break
            self.check_stream(conn)
            if found is None:
                raise Inconclusive("no command was seen to take its effect (STOP_TEST, CAPTURE_IMAGES, "
                                   "STOP_HOVER_TEST, TAKEOFF): NSQD-MSG-3's cases say why")
            self.session.proven_probe = found
        return found

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

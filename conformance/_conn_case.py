"""What a case against a node that serves connections shares, whatever its stream protocol
(``harness.stream_session.ConnSessionBase``, the runner its client): a connection the node
accepted and sent its first frame on (:meth:`ConnCaseBase.open`), every frame it sends judged
on the way by the protocol's sender rules (``conn.violation()``), a death reported under the
protocol's robustness rule whatever the case tested (with the bytes sent and the case's rules
in the evidence), and the node proven alive after the case's last write before its verdict
(:meth:`ConnCaseBase.conclude`: a death seen late is still the case's that caused it).

A protocol declares, never copies: its robustness rule (``death_rule``); its first frame is
its session's (``first_sign``) and its connection says which frames are that sign
(``conn.signs()``). Nsqd's context (``conformance.nsqd_case``) stands on it.
"""

from __future__ import annotations

from typing import Any

from mcp_conform.conformance._case_base import SpecCaseBase
from mcp_conform.harness.errors import NodeLost

__all__ = ["DYING_S", "ConnCaseBase"]

#: How long a node that refused, closed or stopped serving a new connection may take to be
#: seen dead: a dying process closes its sockets a moment before it is reaped (a loaded host,
#: a sanitizer writing its report). Waited only on that path, a failing case's: a node still
#: running after it fails the same rule, only with no death to name (CI beside other workers
#: once saw a Python backend that aborts 0.3 s after closing its listener still running at 1 s).
DYING_S = 3.0


class ConnCaseBase(SpecCaseBase):
    """A case on connections to the node (see the module docstring); ``gap_max``: the
    session's bound on the gap between the node's frames. Every death is reported under
    ``death_rule`` (the shared core's ``fail``), with the bytes the case sent."""

    def __init__(self, session: Any, case_id: str, rules: tuple[str, ...]) -> None:
        super().__init__(session, case_id, rules)
        self.gap_max = float(self.params[session.gap_param])

    # -- failures -----------------------------------------------------------------------
    def traffic(self) -> list[str]:
        """The bytes the case sent, the last six writes."""
        return [f"sent {len(data)} B: {data[:64].hex(' ')}{' …' if len(data) > 64 else ''}"
                for _, data in self.session.sent_log[-6:]]

    def death_grace(self) -> float:
        """A connection the node closed may be its death on the way: a moment's grace."""
        return 0.5 if any(c.closed_at is not None for c in self.session.conns) else 0.05

    def check_stream(self, conn: Any) -> None:
        """What the node sent on ``conn`` so far obeys the protocol's sender rules."""
        conn.pump(0)
        v = conn.violation()
        if v is not None:
            raise self.fail(v.rule, v.expected, v.actual, list(v.evidence))

    # -- connections ----------------------------------------------------------------------
    def open(self) -> Any:
        """A connection the node accepted and sent its first frame on (else the case cannot run)."""
        conn = self.session.connect()
        if conn is not None and conn.wait_for(lambda: bool(conn.signs()) or conn.framing_error is not None
                                              or any(r.problem for r in conn.frames),
                                              self.gap_max + 0.5):
            self.check_stream(conn)
            return conn
        if conn is not None:
            self.check_stream(conn)
        # refused or closed: a dying node closes its sockets a moment before it is reaped
        death = self.session.death(grace=DYING_S if conn is None or conn.closed_at is not None else 0.0)
        if death is not None:
            raise self.fail(self.rules[0], "", "")
        raise NodeLost(f"{self.subject} accepted no connection or sent no {self.session.first_sign} on it "
                       f"within {self.gap_max + 0.5:g} s")

    def conclude(self) -> None:
        """Before the case's verdict: the node proven alive after the case's last write
        (:attr:`death_rule`), so a death on it is this case's failure, with the write that
        killed it in the evidence, not the next case's (a closed connection, or a node that
        stopped serving, may be a death whose process has not ended yet). The case's
        connections are closed (read to the end first: a FIN, not a reset), then a new one
        must be accepted and sent its first frame; a case that proved it already
        (:meth:`expect_alive`, a new connection served after its last write) costs nothing."""
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
        sign = self.session.first_sign
        raise self.fail(self.death_rule, f"after the case's input, a new connection accepted and sent {sign}",
                        f"no {sign} on a new connection within {timeout:g} s")

    # -- verify helpers -------------------------------------------------------------------
    def expect_closed(self, conn: Any, rule: str, what: str) -> None:
        """The node closes ``conn`` within ``close_window_s``."""
        window = float(self.params["close_window_s"])
        ok = conn.wait_for(lambda: conn.closed_at is not None, window)
        if not ok:
            if self.session.death() is not None:
                raise self.fail(rule, "", "")
            raise self.fail(rule, f"{self.subject} closes the connection after {what}",
                            f"still open {window:g} s later ({len(conn.signs())} {self.session.first_sign}s on it)")

    def expect_alive(self, rule: str | None = None, what: str = "the input") -> Any:
        """The node still serves: a new connection is accepted and gets its first frame."""
        rule = rule or self.death_rule
        for c in list(self.session.conns):
            c.close()
            self.session.conns.remove(c)
        conn = self.session.connect()
        sign = self.session.first_sign
        ok = conn is not None and conn.wait_for(lambda: bool(conn.signs()), self.gap_max + 0.5)
        if conn is not None:
            self.check_stream(conn)
        if not ok:
            if conn is None or conn.closed_at is not None:
                # refused or closed: a dying node closes its sockets a moment before it is
                # reaped (a backend that closes its listener and aborts 0.3 s later: the death,
                # not "refused", is the failure; a profile run of the slow tier saw
                # "refused" there under load: 0.5 s, a closed connection's grace, was too short)
                self.session.death(grace=DYING_S)
            raise self.fail(rule, f"after {what}, a new connection accepted and sent {sign}",
                            "refused" if conn is None else f"no {sign} within {self.gap_max + 0.5:g} s")
        return conn

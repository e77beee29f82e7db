"""What a case on the runner's link shares, whatever the protocol (``harness.link.Link``; the
sessions of ``harness.link_session``): sending a protocol message, letting time pass with the
link read, failures carrying the node's death and the case's traffic both ways
(:class:`LinkCaseBase`, on ``conformance._case_base.SpecCaseBase``: the run's clock and the
case's start, as Nsqd's); and, where the runner plays a node
and the judged peer is started afresh for each behaviour of it
(``harness.link_session.PlayedNodeSession``), the peer's run and the waits for what it does
(:class:`PlayedPeerCaseBase`: a peer does its work once, then goes quiet or ends).

A protocol declares, never copies: how a message is built (``message``), the periodic
messages a failure's traffic leaves out (``QUIET``) and its peer's beat (``beat``). MAVLink's
contexts (``conformance.mavlink_case``, ``conformance.mavlink_gcs_case``) stand on it.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from mcp_conform.conformance._case_base import SpecCaseBase
from mcp_conform.harness.errors import Inconclusive

__all__ = ["LinkCaseBase", "PlayedPeerCaseBase"]

#: how long a peer's work may take before a case counts it as done
SETTLE_MAX_S = 30.0
#: a peer that sent nothing but its beat for this long has done its work
SETTLE_QUIET_S = 2.0


class LinkCaseBase(SpecCaseBase):
    """A case on the session's link (:attr:`link`); a failure says a spawned node
    that died first, and ends with the case's traffic both ways (the shared core's ``fail``)."""

    #: the periodic messages a failure's traffic leaves out
    QUIET: frozenset[str] = frozenset()

    @property
    def link(self) -> Any:
        """The session's link (a peer's: the current run's); Inconclusive without one."""
        if self.session.link is None:
            raise Inconclusive(f"no link to {self.subject}")
        return self.session.link

    def message(self, name: str, **fields: Any) -> Any:
        """The protocol's message ``name`` with ``fields``."""
        raise NotImplementedError

    def send(self, name: str, **fields: Any) -> float:
        """Send message ``name`` to the node under test; its send time (:meth:`now`'s clock)."""
        return float(self.link.send(self.message(name, **fields)))

    def watch(self, seconds: float) -> None:
        """Let ``seconds`` pass, the link read meanwhile."""
        self.link.watch(seconds)

    def traffic(self) -> list[str]:
        """The case's last four frames each way, the periodic ones (``QUIET``) left out."""
        sent = [f"sent {name} ({len(data)} B, +{t - self.t0:.3f} s): {data[:48].hex(' ')}"
                for t, name, data in self.link.sent if t >= self.t0 and name not in self.QUIET][-4:]
        got = [f"got +{r.t - self.t0:.3f} s: {r.describe()}" for r in self.link.received(self.t0)
               if r.name not in self.QUIET][-4:]
        return sent + got

    def expect_frames(self, frames: Sequence[Any], check: Callable[[Any], str | None],
                      rule: str, expected: str) -> None:
        """Every frame of ``frames`` passes ``check`` (which returns a problem or None):
        ``CaseBase.expect_all`` over frames."""
        self.expect_all(frames, check, rule, expected, noun="frames")


class PlayedPeerCaseBase(LinkCaseBase):
    """A case against the peer the runner starts for a behaviour of the node it plays: it
    asks for the run it observes (:meth:`run`), waits for what the peer does (:meth:`wait`,
    :meth:`settle`, :meth:`resends`), then judges the peer's frames (:meth:`from_peer`); a
    case whose rule the peer never exercises is SKIPPED (:meth:`need`). ``beat``: the peer's
    periodic message, which is not its work."""

    beat = ""

    def __init__(self, session: Any, case_id: str, rules: tuple[str, ...]) -> None:
        super().__init__(session, case_id, rules)
        self.since = session.run_started

    def run(self, behaviour: Any = None) -> None:
        """The peer's run against a played node that behaves so (see the session; None: as the
        session's first run, ``first_behaviour``)."""
        self.since = self.session.run(self.session.first_behaviour if behaviour is None else behaviour)

    @property
    def on_link(self) -> float:
        """When the peer was first seen on this run's link: its TCP connection accepted; over
        UDP, where its start cannot be seen, its first frame. The time its process takes to
        start (an interpreter and its imports: seconds on a loaded host) is no gap in its
        beat: over UDP the link is open before it is spawned."""
        first = self.session.first_frame
        if self.session.scheme == "tcp" or first is None:
            return float(self.since)
        return max(self.since, first)

    def ended(self) -> bool:
        """The peer's process ended, or it closed the TCP link."""
        return not self.session.alive_process() or self.link.closed_at is not None

    def wait(self, pred: Callable[[], Any], timeout: float) -> bool:
        """Wait until ``pred()`` holds, ``timeout`` s pass or the peer ended; ``pred()``."""
        self.link.wait_for(lambda: bool(pred()) or self.ended(), max(0.0, timeout))
        return bool(pred())

    def quiet(self) -> bool:
        """The peer sent nothing but its beat for ``SETTLE_QUIET_S``."""
        work = [r.t for r in self.from_peer() if r.name != self.beat]
        last = work[-1] if work else (self.session.first_frame or self.now())
        return self.now() - last >= SETTLE_QUIET_S

    def settle(self) -> None:
        """Wait until the peer has done its work: it ended, or it is :meth:`quiet` (at most
        ``SETTLE_MAX_S``)."""
        self.wait(self.quiet, SETTLE_MAX_S)

    def await_work(self, pred: Callable[[], Any]) -> bool:
        """Wait until ``pred()`` holds, or the peer ended or is :meth:`quiet` (at most
        ``SETTLE_MAX_S``); ``pred()``."""
        self.wait(lambda: bool(pred()) or self.quiet(), SETTLE_MAX_S)
        return bool(pred())

    def resends(self, frames: Callable[[], list[Any]], bound: int, quiet: float, total: float) -> list[Any]:
        """Watch ``frames()`` (a message and its copies) grow until more than ``1 + bound``
        came, ``quiet`` s passed after the last, the peer ended, or ``total`` s passed; the
        frames then."""
        end = self.now() + total
        while self.now() < end:
            got = frames()
            last = got[-1].t if got else self.since
            if len(got) > 1 + bound or self.now() - last >= quiet or self.ended():
                break
            n = len(got)
            self.link.wait_for(lambda n=n: len(frames()) > n or self.ended(), min(quiet, end - self.now()))
        return frames()

    def from_peer(self, *names: str) -> list[Any]:
        """The peer's frames of this run (of messages ``names``, when given)."""
        return [r for r in self.link.received() if not r.bad and (not names or r.name in names)]

    def need(self, frames: Sequence[Any], what: str) -> Sequence[Any]:
        """``frames``, or SKIPPED: the peer never did ``what``."""
        if not frames:
            raise Inconclusive(f"{self.subject} sent no {what} on its run (it never exercised the rule)")
        return frames

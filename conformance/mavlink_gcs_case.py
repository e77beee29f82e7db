"""The per-case context of a MAVLink ground-station case (``--protocol mavlink --role gcs``):
the ``node`` fixture, on :class:`~conformance.mavlink_case.MavlinkCaseBase`.

A case asks for the run it observes (:meth:`MavlinkGcsCaseContext.run`: the ground station
against the runner's vehicle with a ``Behaviour``), waits for what the ground station does
(:meth:`wait`, :meth:`settle`, :meth:`resends`), then judges its frames (:meth:`from_gcs`) and
what the runner's vehicle sent (:meth:`runner_sent`). A case whose rule the ground station
never exercises (it sent no command, no PARAM_SET, no mission) is SKIPPED (:meth:`need`).
Every message, field and constant comes from pymavlink's dialect; the times from
``spec/mavlink.yaml``'s parameters.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

from mcp_conform.conformance.mavlink_case import MavlinkCaseBase
from mcp_conform.harness.errors import Inconclusive
from mcp_conform.harness.mavlink_gcs_session import MavlinkGcsSession
from mcp_conform.harness.mavlink_gcs_vehicle import ARDUPILOT, Behaviour, command_key
from mcp_conform.harness.mavlink_session import DIALECT, Link, Received

__all__ = ["GLOBAL_FRAMES", "MavlinkGcsCaseContext", "degrees_sent"]

#: the global frames: in MISSION_ITEM_INT and COMMAND_INT their x, y are degrees * 1E7, with
#: or without the _INT suffix (common.xml, MISSION_ITEM_INT.x: "global: latitude in degrees *10^7")
GLOBAL_FRAMES = frozenset(getattr(DIALECT, f"MAV_FRAME_GLOBAL{s}{i}") for s in ("", "_RELATIVE_ALT", "_TERRAIN_ALT")
                          for i in ("", "_INT"))
#: how long a ground station's work may take before a case counts it as done
SETTLE_MAX_S = 30.0
#: a ground station that sent nothing but HEARTBEATs for this long has done its work
SETTLE_QUIET_S = 2.0


def degrees_sent(x: int, y: int) -> bool:
    """D-6: x and y both non-zero and within -90..90, -180..180: degrees sent unscaled."""
    return x != 0 and y != 0 and -90 <= x <= 90 and -180 <= y <= 180


class MavlinkGcsCaseContext(MavlinkCaseBase):
    """What a ground-station case sees (see the module docstring)."""

    subject = "the ground station"
    session: MavlinkGcsSession

    def __init__(self, session: MavlinkGcsSession, case_id: str, rules: tuple[str, ...]) -> None:
        super().__init__(session, case_id, rules)
        self.since = session.run_started

    @property
    def link(self) -> Link:  # type: ignore[override]  # the current run's
        if self.session.link is None:
            raise Inconclusive("no link to the ground station")
        return self.session.link

    @property
    def vehicle_ids(self) -> tuple[int, int]:
        """The runner's vehicle's system and component IDs."""
        return self.session.vehicle.ids if self.session.vehicle is not None else (1, 1)

    # -- runs and waits ------------------------------------------------------------------
    def run(self, behaviour: Behaviour = ARDUPILOT) -> None:
        """The ground station's run against a vehicle that behaves so (see the session)."""
        self.since = self.session.run(behaviour)

    @property
    def on_link(self) -> float:
        """When the ground station was first seen on this run's link: its TCP connection
        accepted; over UDP, where its start cannot be seen, its first frame. The time its
        process takes to start (an interpreter and its imports: seconds on a loaded host) is
        no gap in its heartbeat (MAV-HB-2): over UDP the link is open before it is spawned."""
        first = self.session.first_frame
        if self.session.scheme == "tcp" or first is None:
            return self.since
        return max(self.since, first)

    def ended(self) -> bool:
        """The ground station's process ended, or it closed the TCP link."""
        return not self.session.alive_process() or self.link.closed_at is not None

    def wait(self, pred: Callable[[], Any], timeout: float) -> bool:
        """Wait until ``pred()`` holds, ``timeout`` s pass or the ground station ended; ``pred()``."""
        self.link.wait_for(lambda: bool(pred()) or self.ended(), max(0.0, timeout))
        return bool(pred())

    def quiet(self) -> bool:
        """The ground station sent nothing but HEARTBEATs for ``SETTLE_QUIET_S``."""
        work = [r.t for r in self.from_gcs() if r.name != "HEARTBEAT"]
        last = work[-1] if work else (self.session.first_frame or self.now())
        return self.now() - last >= SETTLE_QUIET_S

    def settle(self) -> None:
        """Wait until the ground station has done its work: it ended, or it is :meth:`quiet`
        (at most ``SETTLE_MAX_S``)."""
        self.wait(self.quiet, SETTLE_MAX_S)

    def await_work(self, pred: Callable[[], Any]) -> bool:
        """Wait until ``pred()`` holds, or the ground station ended or is :meth:`quiet` (at
        most ``SETTLE_MAX_S``); ``pred()``."""
        self.wait(lambda: bool(pred()) or self.quiet(), SETTLE_MAX_S)
        return bool(pred())

    def resends(self, frames: Callable[[], list[Received]], bound: int, quiet: float, total: float) -> list[Received]:
        """Watch ``frames()`` (a message and its copies) grow until more than ``1 + bound``
        came, ``quiet`` s passed after the last, the ground station ended, or ``total`` s
        passed; the frames then."""
        end = self.now() + total
        while self.now() < end:
            got = frames()
            last = got[-1].t if got else self.since
            if len(got) > 1 + bound or self.now() - last >= quiet or self.ended():
                break
            n = len(got)
            self.link.wait_for(lambda n=n: len(frames()) > n or self.ended(), min(quiet, end - self.now()))
        return frames()

    # -- what came and what went --------------------------------------------------------------
    def from_gcs(self, *names: str) -> list[Received]:
        """The ground station's frames of this run (of messages ``names``, when given)."""
        return [r for r in self.link.received() if not r.bad and (not names or r.name in names)]

    def runner_sent(self, *names: str) -> list[tuple[float, Any]]:
        """What the runner's vehicle sent on this run's link (messages ``names``): (time, message)."""
        parser = DIALECT.MAVLink(None)
        out = []
        for t, name, data in self.link.sent:
            if name in names:
                out += [(t, m) for m in parser.parse_buffer(data) or []]
        return out

    def need(self, frames: Sequence[Received], what: str) -> Sequence[Received]:
        """``frames``, or SKIPPED: the ground station never did ``what``."""
        if not frames:
            raise Inconclusive(f"the ground station sent no {what} on its run (it never exercised the rule)")
        return frames

    def transmissions(self, command: int) -> list[Received]:
        """The first command carrying ``command`` and its retransmissions (``command_key``:
        the same message and parameters), in order."""
        sent = [r for r in self.from_gcs("COMMAND_LONG", "COMMAND_INT") if r.msg.command == command]
        return [r for r in sent if command_key(r.msg) == command_key(sent[0].msg)]

    def first_command(self) -> int:
        """The first command the ground station sent (waited for); SKIPPED when none came."""
        self.await_work(lambda: self.from_gcs("COMMAND_LONG", "COMMAND_INT"))
        first = self.need(self.from_gcs("COMMAND_LONG", "COMMAND_INT"), "COMMAND_LONG or COMMAND_INT")[0]
        return int(first.msg.command)

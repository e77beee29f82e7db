"""The per-case context of a MAVLink ground-station case (``--protocol mavlink --role gcs``):
the ``node`` fixture, on the shared core's case against a peer the runner starts afresh per
behaviour of the node it plays (``conformance._link_case.PlayedPeerCaseBase``: the runs, the
waits, SKIPPED when the rule is never exercised) and :class:`~conformance.mavlink_case.MavlinkCaseBase`.

A case asks for the run it observes (:meth:`MavlinkGcsCaseContext.run`: the ground station
against the runner's vehicle with a ``Behaviour``), waits for what the ground station does
(:meth:`wait`, :meth:`settle`, :meth:`resends`), then judges its frames (:meth:`from_gcs`) and
what the runner's vehicle sent (:meth:`runner_sent`). A case whose rule the ground station
never exercises (it sent no command, no PARAM_SET, no mission) is SKIPPED (:meth:`need`).
Every message, field and constant comes from pymavlink's dialect; the times from
``spec/mavlink.yaml``'s parameters.
"""

from __future__ import annotations

from typing import Any

from mcp_conform.conformance._link_case import PlayedPeerCaseBase
from mcp_conform.conformance.mavlink_case import MavlinkCaseBase
from mcp_conform.harness.mavlink_gcs_session import MavlinkGcsSession
from mcp_conform.harness.mavlink_gcs_vehicle import ARDUPILOT, Behaviour, command_key
from mcp_conform.harness.mavlink_session import DIALECT, Link, Received

__all__ = ["GLOBAL_FRAMES", "MavlinkGcsCaseContext", "degrees_sent"]

#: the global frames: in MISSION_ITEM_INT and COMMAND_INT their x, y are degrees * 1E7, with
#: or without the _INT suffix (common.xml, MISSION_ITEM_INT.x: "global: latitude in degrees *10^7")
GLOBAL_FRAMES = frozenset(getattr(DIALECT, f"MAV_FRAME_GLOBAL{s}{i}") for s in ("", "_RELATIVE_ALT", "_TERRAIN_ALT")
                          for i in ("", "_INT"))
def degrees_sent(x: int, y: int) -> bool:
    """D-6: x and y both non-zero and within -90..90, -180..180: degrees sent unscaled."""
    return x != 0 and y != 0 and -90 <= x <= 90 and -180 <= y <= 180


class MavlinkGcsCaseContext(PlayedPeerCaseBase, MavlinkCaseBase):
    """What a ground-station case sees (see the module docstring)."""

    subject = "the ground station"
    beat = "HEARTBEAT"
    session: MavlinkGcsSession
    link: Link

    @property
    def vehicle_ids(self) -> tuple[int, int]:
        """The runner's vehicle's system and component IDs."""
        return self.session.vehicle.ids if self.session.vehicle is not None else (1, 1)

    def run(self, behaviour: Behaviour = ARDUPILOT) -> None:
        """The ground station's run against a vehicle that behaves so (see the session)."""
        super().run(behaviour)

    # -- what came and what went --------------------------------------------------------------
    def from_gcs(self, *names: str) -> list[Received]:
        """The ground station's frames of this run (of messages ``names``, when given)."""
        return self.from_peer(*names)

    def runner_sent(self, *names: str) -> list[tuple[float, Any]]:
        """What the runner's vehicle sent on this run's link (messages ``names``): (time, message)."""
        parser = DIALECT.MAVLink(None)
        out = []
        for t, name, data in self.link.sent:
            if name in names:
                out += [(t, m) for m in parser.parse_buffer(data) or []]
        return out

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

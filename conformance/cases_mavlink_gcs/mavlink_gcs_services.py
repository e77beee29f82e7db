"""What a ground station under test does, read as MAVLink's microservices have it, for the
ground-station cases of this package (``--protocol mavlink --role gcs``): MAVLink's content,
beside its cases. The ``node`` fixture (``conformance.mavlink_gcs_case.MavlinkGcsCaseContext``,
the shared played-peer case's plumbing) takes them as :class:`GcsServices`.

- Commands (https://mavlink.io/en/services/command.html): the first command the ground
  station sent, and its retransmissions (the same message and parameters:
  ``vehicle.behaviour.command_key``).
- What the runner's vehicle sent, parsed back by the dialect.
- Positions: the global frames, whose x, y are degrees * 1E7, and a position sent in
  unscaled degrees (D-6).

Every message, field and constant comes from pymavlink's dialect (``spec.MAVLINK.dialect``).
"""

from __future__ import annotations

from typing import Any

from mcp_conform.conformance._link_case import PlayedPeerCaseBase
from mcp_conform.conformance.cases_mavlink.mavlink_services import MavlinkServices
from mcp_conform.harness.mavlink_session import DIALECT, Received
from mcp_conform.vehicle.behaviour import command_key

__all__ = ["GLOBAL_FRAMES", "GcsServices", "degrees_sent"]

#: the global frames: in MISSION_ITEM_INT and COMMAND_INT their x, y are degrees * 1E7, with
#: or without the _INT suffix (common.xml, MISSION_ITEM_INT.x: "global: latitude in degrees *10^7")
GLOBAL_FRAMES = frozenset(getattr(DIALECT, f"MAV_FRAME_GLOBAL{s}{i}") for s in ("", "_RELATIVE_ALT", "_TERRAIN_ALT")
                          for i in ("", "_INT"))
def degrees_sent(x: int, y: int) -> bool:
    """D-6: x and y both non-zero and within -90..90, -180..180: degrees sent unscaled."""
    return x != 0 and y != 0 and -90 <= x <= 90 and -180 <= y <= 180


class GcsServices(PlayedPeerCaseBase, MavlinkServices):
    """The ground station's commands, and what the runner's vehicle sent, on this run's link."""

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
        sent = [r for r in self.from_peer("COMMAND_LONG", "COMMAND_INT") if r.msg.command == command]
        return [r for r in sent if command_key(r.msg) == command_key(sent[0].msg)]

    def first_command(self) -> int:
        """The first command the ground station sent (waited for); SKIPPED when none came."""
        self.await_work(lambda: self.from_peer("COMMAND_LONG", "COMMAND_INT"))
        first = self.need(self.from_peer("COMMAND_LONG", "COMMAND_INT"), "COMMAND_LONG or COMMAND_INT")[0]
        return int(first.msg.command)

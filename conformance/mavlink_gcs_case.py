"""The per-case context of a MAVLink ground-station case (``--protocol mavlink --role gcs``):
the ``node`` fixture, on the shared core's case against a peer the runner starts afresh per
behaviour of the node it plays (``conformance._link_case.PlayedPeerCaseBase``: the runs, the
waits, SKIPPED when the rule is never exercised) and :class:`~conformance.mavlink_case.MavlinkCaseBase`.

A case asks for the run it observes (``run``: the ground station against the runner's vehicle
with a ``Behaviour``, ArduPilot's by default: the session's ``first_behaviour``), waits for
what the ground station does (``wait``, ``settle``, ``resends``), then judges its frames
(:meth:`from_gcs`) and what the runner's vehicle sent (``runner_sent``). A case whose rule
the ground station never exercises (it sent no command, no PARAM_SET, no mission) is SKIPPED
(``need``). What the cases read of MAVLink's microservices is MAVLink's content, beside its
cases (``conformance.cases_mavlink_gcs.mavlink_gcs_services``).
"""

from __future__ import annotations

from mcp_conform.conformance.cases_mavlink_gcs.mavlink_gcs_services import GcsServices
from mcp_conform.conformance.mavlink_case import MavlinkCaseBase
from mcp_conform.harness.mavlink_gcs_session import MavlinkGcsSession
from mcp_conform.harness.mavlink_session import Link, Received

__all__ = ["MavlinkGcsCaseContext"]


class MavlinkGcsCaseContext(GcsServices, MavlinkCaseBase):
    """What a ground-station case sees (see the module docstring)."""

    beat = "HEARTBEAT"
    session: MavlinkGcsSession
    link: Link

    @property
    def vehicle_ids(self) -> tuple[int, int]:
        """The runner's vehicle's system and component IDs."""
        return self.session.vehicle.ids if self.session.vehicle is not None else (1, 1)

    def from_gcs(self, *names: str) -> list[Received]:
        """The ground station's frames of this run (of messages ``names``, when given)."""
        return self.from_peer(*names)

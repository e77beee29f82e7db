"""The per-case context of a MAVLink vehicle case (``--protocol mavlink``): the ``node`` fixture.

A case sends as a ground station on the session's link (:meth:`MavlinkCaseContext.send`,
``command_long``, ``command_int``, :meth:`send_raw`), then calls one verify helper, which
raises ``CaseFailure`` naming the rule, what was expected and what was seen, with the
frames of the case as evidence. The context is the shared core's case on a link
(``conformance._link_case.LinkCaseBase``) with MAVLink declared: its messages, built by the
link's pymavlink encoder, the periodic ones a failure's traffic leaves out, and the vehicle
under test's identity (its first HEARTBEAT's). The verify helpers speak MAVLink's
microservices, which are MAVLink's content, beside its cases
(``conformance.cases_mavlink.mavlink_services``: commands, heartbeat, parameters, missions).
"""

from __future__ import annotations

from typing import Any

from mcp_conform.conformance._link_case import LinkCaseBase
from mcp_conform.conformance.cases_mavlink.mavlink_services import VehicleServices
from mcp_conform.harness.mavlink_session import DIALECT, Link, MavlinkSession, Received

__all__ = ["MavlinkCaseBase", "MavlinkCaseContext"]


class MavlinkCaseBase(LinkCaseBase):
    """What a case of either MAVLink role has (``--role vehicle``: :class:`MavlinkCaseContext`;
    ``--role gcs``: ``conformance.mavlink_gcs_case``): the shared core's case on a link with
    MAVLink's messages and the dialect."""

    link: Link
    #: the periodic messages a failure's traffic leaves out
    QUIET = frozenset({"HEARTBEAT", "ATTITUDE", "GLOBAL_POSITION_INT", "VFR_HUD", "SYS_STATUS", "GPS_RAW_INT"})
    mav = DIALECT

    def message(self, name: str, **fields: Any) -> Any:
        """The dialect's message ``name`` with ``fields`` (the others as the encoder's defaults)."""
        return getattr(self.link.encoder, name.lower() + "_encode")(**fields)


class MavlinkCaseContext(MavlinkCaseBase, VehicleServices):
    """What a vehicle case sees (see the module docstring)."""

    session: MavlinkSession

    def __init__(self, session: MavlinkSession, case_id: str, rules: tuple[str, ...]) -> None:
        super().__init__(session, case_id, rules)
        self.sysid, self.compid = session.vehicle
        self.ack_max = float(self.params["command_ack_max_s"])
        self.reply_max = float(self.params["param_reply_max_s"])

    def send_raw(self, data: bytes, name: str) -> float:
        t = self.link.send_raw(data, name)
        self.link.skip_seq()
        return t

    def from_vehicle(self, since: float = 0.0, name: str | None = None) -> list[Received]:
        """Frames of the vehicle under test (its system and component) since ``since``."""
        return [r for r in self.link.received(since, name) if not r.bad
                and (r.msg.get_srcSystem(), r.msg.get_srcComponent()) == (self.sysid, self.compid)]

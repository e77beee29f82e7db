"""The vehicle the runner plays in ``--protocol mavlink --role gcs``: the reference vehicle's
model, the project's simulated ArduCopter (``vehicle.model.VehicleModel``, sans-I/O: each frame
of the ground station in, the autopilot's answers out, telemetry and HEARTBEAT on its clock),
asking for items with MISSION_REQUEST_INT,
and the :class:`Behaviour` by which it departs from ArduPilot on purpose for one run, to see
what the ground station does then (MAV-CMD-6..17, MAV-PRM-14..16, MAV-MIS-20..24). A reference
node like ``mcp-vehicle``, driven in-process: the session (``harness.mavlink_gcs_session``) runs
it on the runner's link."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass
from typing import Any

from mcp_conform.spec import MAVLINK
from mcp_conform.vehicle.model import VehicleConfig, VehicleModel

__all__ = ["ARDUPILOT", "Behaviour", "RunnerVehicle", "command_key"]

DIALECT: Any = MAVLINK.dialect
COMMANDS = ("COMMAND_LONG", "COMMAND_INT")
ITEMS = ("MISSION_ITEM_INT", "MISSION_ITEM")


@dataclass(frozen=True)
class Behaviour:
    """How the runner's vehicle departs from ArduPilot's answers over one run (the defaults:
    it does not). "The first command" is the first COMMAND_LONG/COMMAND_INT (:func:`command_key`):
    its every transmission is treated alike, other commands are answered as ArduPilot does."""

    name: str = "ardupilot"
    #: no COMMAND_ACK for the first command (MAV-CMD-6, MAV-CMD-8, MAV-CMD-9)
    withhold_command_ack: bool = False
    #: the first command answered MAV_RESULT_IN_PROGRESS, its final ACK this many seconds later (MAV-CMD-10)
    in_progress_s: float = 0.0
    #: the first command's ACKs name another command (MAV-CMD-17)
    wrong_command_ack: bool = False
    #: no PARAM_VALUE for the first PARAM_SET (MAV-PRM-16)
    withhold_param_value: bool = False
    #: every MISSION_COUNT left unanswered (MAV-MIS-22, MAV-MIS-23)
    ignore_mission_count: bool = False
    #: the first upload's item with this seq answered MISSION_ACK MAV_MISSION_ERROR (MAV-MIS-24)
    error_ack_item: int | None = None
    #: the first item with this seq not taken: ArduPilot requests it again after its timeout (MAV-MIS-20)
    drop_item: int | None = None
    #: the first parameter list without the PARAM_VALUEs of these indices (MAV-PRM-14)
    list_gaps: tuple[int, ...] = ()
    #: the first parameter list backwards, every third PARAM_VALUE twice (MAV-PRM-15, D-5)
    list_shuffled: bool = False


ARDUPILOT = Behaviour()


def command_key(msg: Any) -> tuple[Any, ...]:
    """What makes a COMMAND_LONG or COMMAND_INT the same command again (a retransmission):
    its message, command id and parameters; ``confirmation`` aside (MAV_CMD_REQUEST_MESSAGE
    for two messages is two commands)."""
    fields = ("param1", "param2", "param3", "param4") + (
        ("param5", "param6", "param7") if msg.get_type() == "COMMAND_LONG" else ("frame", "x", "y", "z"))
    return (msg.get_type(), msg.command, *(getattr(msg, f) for f in fields))


class RunnerVehicle:
    """The simulated ArduCopter answering the ground station with one :class:`Behaviour`;
    :meth:`answer` and :meth:`tick` return the messages to send (called under ``lock``), at
    ``now``, the run clock's (``harness.clock``; the host's ``time.monotonic()`` by default)."""

    def __init__(self, behaviour: Behaviour, now: float | None = None) -> None:
        self.behaviour = behaviour
        self.lock = threading.Lock()
        self.model = VehicleModel(VehicleConfig(mission_request_int=True),
                                  now=time.monotonic() if now is None else now)
        self.ids = (self.model.config.sysid, self.model.config.compid)
        self.first_command: tuple[Any, ...] | None = None  # its command_key
        self._done: set[str] = set()  # the one-off departures already made
        self._held: list[tuple[float, Any]] = []  # (due, message): final ACKs held back

    def _once(self, what: str) -> bool:
        fresh = what not in self._done
        self._done.add(what)
        return fresh

    def answer(self, msg: Any, now: float) -> list[Any]:
        b, name = self.behaviour, msg.get_type()
        if name == "MISSION_COUNT" and b.ignore_mission_count:
            return []
        if name in ITEMS and msg.seq == b.drop_item and self._once("drop"):
            return []
        if (name in ITEMS and msg.seq == b.error_ack_item and self.model.missions.upload is not None
                and self._once("error-ack")):
            self.model.missions.upload = None  # ArduPilot ends the transfer on a bad item
            return [DIALECT.MAVLink_mission_ack_message(msg.get_srcSystem(), msg.get_srcComponent(),
                                                        DIALECT.MAV_MISSION_ERROR, msg.mission_type)]
        replies = list(self.model.handle(msg, now))
        if name in COMMANDS:
            if self.first_command is None:
                self.first_command = command_key(msg)
            if command_key(msg) == self.first_command:
                replies = self._first_command(msg, replies, now)
        if name == "PARAM_REQUEST_LIST" and (b.list_gaps or b.list_shuffled) and self._once("list"):
            values = [r for r in replies if r.get_type() == "PARAM_VALUE" and r.param_index not in b.list_gaps]
            if b.list_shuffled:
                values = [w for i, v in enumerate(reversed(values)) for w in ([v, v] if i % 3 == 0 else [v])]
            replies = [r for r in replies if r.get_type() != "PARAM_VALUE"] + values
        if name == "PARAM_SET" and b.withhold_param_value and self._once("param"):
            replies = [r for r in replies if r.get_type() != "PARAM_VALUE"]
        return replies

    def _first_command(self, msg: Any, replies: list[Any], now: float) -> list[Any]:
        b = self.behaviour
        acks = [r for r in replies if r.get_type() == "COMMAND_ACK"]
        others = [r for r in replies if r.get_type() != "COMMAND_ACK"]
        if b.withhold_command_ack:
            return others
        if b.wrong_command_ack:
            for a in acks:  # the ACK of another command: MAV_CMD_REQUEST_MESSAGE, or DO_SET_MODE
                a.command = (DIALECT.MAV_CMD_DO_SET_MODE if msg.command == DIALECT.MAV_CMD_REQUEST_MESSAGE
                             else DIALECT.MAV_CMD_REQUEST_MESSAGE)
            return others + acks
        if b.in_progress_s > 0 and acks:
            progress = DIALECT.MAVLink_command_ack_message(msg.command, DIALECT.MAV_RESULT_IN_PROGRESS, 0, 0,
                                                          msg.get_srcSystem(), msg.get_srcComponent())
            if self._once("in-progress"):
                self._held += [(now + b.in_progress_s, a) for a in acks]
            return [*others, progress]
        return replies

    def tick(self, now: float) -> list[Any]:
        out = list(self.model.tick(now)) + [m for _, m in self.model.take_outbox()]
        due = [m for t, m in self._held if t <= now]
        self._held = [(t, m) for t, m in self._held if t > now]
        return out + due

"""Observation records and ArduCopter constants shared by the vehicle model and server.

Every timestamp in this package is a ``time.monotonic()`` reading (seconds, float), taken
on the host that runs the vehicle. Records are frozen dataclasses; their ``detail`` /
``fields`` mappings are fresh copies owned by the record and must be treated as read-only.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from pymavlink import mavutil

#: ArduCopter custom_mode numbers by name (pymavlink's table, so ``set_mode("RTL")`` agrees).
COPTER_MODES: dict[str, int] = {name: num for num, name in mavutil.mode_mapping_acm.items()}
#: ArduCopter custom_mode names by number.
COPTER_MODE_NAMES: dict[int, str] = dict(mavutil.mode_mapping_acm)

STABILIZE = COPTER_MODES["STABILIZE"]  # 0
AUTO = COPTER_MODES["AUTO"]  # 3
GUIDED = COPTER_MODES["GUIDED"]  # 4
LOITER = COPTER_MODES["LOITER"]  # 5
RTL = COPTER_MODES["RTL"]  # 6
LAND = COPTER_MODES["LAND"]  # 9

#: Modes that need a position estimate (a GPS fix) to be entered, as in ArduCopter.
POSITION_MODES: frozenset[int] = frozenset(
    COPTER_MODES[n]
    for n in ("AUTO", "GUIDED", "LOITER", "RTL", "CIRCLE", "POSHOLD", "BRAKE", "SMART_RTL",
              "FOLLOW", "ZIGZAG", "AUTO_RTL")
    if n in COPTER_MODES
)
#: Modes from which ArduCopter refuses to arm.
NO_ARM_MODES: frozenset[int] = frozenset({AUTO, RTL, LAND})
#: Modes that get MAV_MODE_FLAG_GUIDED_ENABLED in the heartbeat's base_mode.
GUIDED_FLAG_MODES: frozenset[int] = POSITION_MODES

#: Event kinds the model records (``Event.kind``).
EVENT_KINDS: tuple[str, ...] = (
    "frame",  # a MAVLink frame was received (detail: type, msgid, srcsys, srccomp, version)
    "bad_data",  # bytes that were not a valid frame (detail: bytes, reason)
    "command",  # a COMMAND_LONG/COMMAND_INT was handled (detail: command, name, result, ...)
    "arm",  # the vehicle armed
    "disarm",  # the vehicle disarmed (detail: reason)
    "mode",  # the flight mode changed (detail: mode, custom_mode, previous, via)
    "rtl",  # RTL was requested, by mode or NAV_RETURN_TO_LAUNCH (detail: via, accepted)
    "takeoff",  # NAV_TAKEOFF was requested (detail: alt, accepted)
    "reached",  # the climb reached the takeoff altitude (detail: alt)
    "busy",  # the vehicle started carrying out an earlier command a node may wait for: a
    #          take-off climbing, an AUTO mission flying (detail: action, as pending_action says)
    "idle",  # ... and stopped (detail: action, the last one shown)
    "landed",  # a descent reached the ground (detail: mode)
    "fix",  # telemetry started reporting a 3D fix
    "fix_lost",  # telemetry stopped reporting a fix
    "mission",  # a mission upload completed or was cleared (detail: count)
    "request",  # the peer asked the autopilot for something, with the answer (see below);
    #             ``--record FILE`` writes these, one JSON line each
    "item_reached",  # AUTO completed a mission command (detail: seq, command)
    "mission_complete",  # AUTO ran past the last mission item (detail: items)
    "error",  # the vehicle failed on a message (its own bug; detail: type, error, conn)
    "probe",  # a passthrough probe arrived (detail: token)
    "connect",  # a TCP client connected, a UDP peer was first heard (detail: conn, peer,
    #             transport)
    "disconnect",  # a TCP client went away (detail: conn, peer)
)


#: What a peer may ask of the autopilot (``Event.detail["request"]`` of a "request" event).
#: The vehicle records EVERY such request with the answer it gave, accepted or not, so a
#: checker judges what the node attempted, not only what the vehicle could do.
REQUESTS: tuple[str, ...] = (
    "arm",  # MAV_CMD_COMPONENT_ARM_DISARM param1 = 1 (forced: param2 = 2989)
    "disarm",  # MAV_CMD_COMPONENT_ARM_DISARM param1 = 0 (forced: param2 = 21196)
    "mode",  # SET_MODE or MAV_CMD_DO_SET_MODE (detail: mode, custom_mode = the mode asked for)
    "rtl",  # MAV_CMD_NAV_RETURN_TO_LAUNCH
    "land",  # MAV_CMD_NAV_LAND
    "takeoff",  # MAV_CMD_NAV_TAKEOFF (detail: alt)
    "mission_start",  # MAV_CMD_MISSION_START
    "command",  # any other COMMAND_LONG / COMMAND_INT (detail: params); one the vehicle does
    #             not handle is MAV_RESULT_UNSUPPORTED, as ArduPilot answers it
    "message",  # MAV_CMD_REQUEST_MESSAGE, REQUEST_AUTOPILOT_CAPABILITIES, GET_HOME_POSITION
    #             (detail: params; param1 is the message id)
    "message_interval",  # MAV_CMD_SET_MESSAGE_INTERVAL / GET_MESSAGE_INTERVAL (detail: params)
    "data_stream",  # REQUEST_DATA_STREAM (detail: stream, rate in Hz; no answer is sent)
    "reposition",  # MAV_CMD_DO_REPOSITION (vehicle.guided)
    "yaw",  # MAV_CMD_CONDITION_YAW
    "speed",  # MAV_CMD_DO_CHANGE_SPEED
    "position_target",  # SET_POSITION_TARGET_LOCAL_NED / _GLOBAL_INT (detail: frame,
    #                     type_mask, position [lat, lon, alt above home] or None, velocity
    #                     [n, e, d], note); not in GUIDED: "denied", ignored as ArduCopter does
    # the parameter protocol and MAVFTP (vehicle.params):
    "param_list",  # PARAM_REQUEST_LIST
    "param_read",  # PARAM_REQUEST_READ (detail: param, index)
    "param_set",  # PARAM_SET (detail: param, value); an unknown or non-ASCII name is "denied"
    #               and nothing is stored or answered
    "ftp",  # FILE_TRANSFER_PROTOCOL (detail: opcode); answered with a NAK
    # the mission protocol (vehicle.mission):
    "mission_upload",  # MISSION_COUNT (detail: count); via "timeout" when it was cancelled
    "mission_item",  # MISSION_ITEM / MISSION_ITEM_INT (detail: seq, frame, current, x, y, z;
    #                  command is the item's MAV_CMD)
    "guided_item",  # MISSION_ITEM[_INT] with current 2/3: fly there in GUIDED
    "mission_download",  # MISSION_REQUEST_LIST
    "mission_read",  # MISSION_REQUEST / MISSION_REQUEST_INT (detail: seq)
    "mission_clear",  # MISSION_CLEAR_ALL
    "mission_set_current",  # MISSION_SET_CURRENT (detail: seq)
)
#: The answers a request can get (``Event.detail["result"]``).
ACCEPTED_RESULT = "accepted"
DENIED_RESULT = "denied"

# The detail of a "request" event (every key always present; JSON-serialisable values):
#   request   one of REQUESTS
#   result    "accepted" or "denied"
#   reason    why it was denied, as the autopilot says it ("PreArm: Need 3D Fix",
#             "Flight mode change failed: RTL needs a position (no GPS fix)", "latitude
#             357713312 is not in degrees (-90..90); a degE7 value sent as degrees?"), else None
#   via       the message that carried it: "COMMAND_LONG", "SET_MODE", "MISSION_ITEM", ...
#   command   the MAV_CMD number (None for SET_MODE and mission messages other than items);
#   name      its MAV_CMD_ name, else the message name
#   mav_result  the MAV_RESULT of the COMMAND_ACK, or the MAV_MISSION_RESULT of the
#             MISSION_ACK sent back (None when the answer was not an ACK)
#   answer    what the vehicle sent back: "MAV_RESULT_FAILED", "MISSION_ACK
#             MAV_MISSION_INVALID_PARAM5_X", "MISSION_REQUEST seq=2", "MISSION_COUNT count=3",
#             "PARAM_VALUE RTL_ALT=2000", "FILE_TRANSFER_PROTOCOL NAK FileNotFound"; "none"
#             when the vehicle answers nothing (as ArduPilot, e.g. PARAM_SET of an unknown name)
#   srcsys, srccomp, conn  who asked: MAVLink system and component ids, link number
# plus, by request: "arm"/"disarm": forced (bool); "mode"/"rtl"/"land"/"mission_start":
# mode and custom_mode (the mode asked for, "MODE(n)" when unknown); "takeoff": alt;
# "command": params (the 7 parameters); the mission requests as listed above.


@dataclass(frozen=True)
class Event:
    """One observation: ``t`` is ``time.monotonic()``; ``detail`` depends on ``kind``."""

    t: float
    kind: str
    detail: dict[str, Any] = field(default_factory=dict, hash=False, compare=False)


@dataclass(frozen=True)
class Frame:
    """One MAVLink frame the vehicle received, exactly as it arrived.

    ``raw`` is the complete frame (header to CRC, signature included if any), ``version``
    is 1 or 2 (from the start byte), ``fields`` is pymavlink's decoded field dict (without
    ``mavpackettype``), ``conn`` numbers the TCP connection it came on (1, 2, ...; 0 when
    it was fed to the model directly).
    """

    t: float
    msg_type: str
    msgid: int
    raw: bytes
    fields: dict[str, Any] = field(hash=False, compare=False)
    srcsys: int = 0
    srccomp: int = 0
    seq: int = 0
    version: int = 2
    conn: int = 0


#: Unparsed records kept (oldest dropped beyond this), and bytes kept of each (its ``length``
#: says how many arrived): what arrives altered is judged against what was sent (MCP-PAY-8).
MAX_UNPARSED = 256
MAX_UNPARSED_BYTES = 1024


@dataclass(frozen=True)
class Unparsed:
    """Bytes the vehicle received on a link that did not parse as a MAVLink frame.

    MCP-PAY-8: "A drone linked to an autopilot forwards each delivered Mav_Passthrough frame
    to it exactly once." A frame altered on its way (truncated, corrupted) arrives as such
    bytes: a frame with a bad CRC, bytes before any start marker, a frame of an unknown
    message id (also handled as a frame, as before), or an incomplete frame after which
    nothing came for ``codec.STALE`` seconds. ``t`` is when its first byte arrived, ``seen``
    when the vehicle knew it did not parse (both ``time.monotonic()``); ``raw`` holds at
    most ``MAX_UNPARSED_BYTES`` of the ``length`` bytes; ``conn`` numbers the link.
    """

    t: float
    raw: bytes
    reason: str
    length: int = 0
    conn: int = 0
    seen: float = 0.0


def mode_name(custom_mode: int) -> str:
    """The ArduCopter name of ``custom_mode`` (``"MODE(n)"`` when unknown)."""
    return COPTER_MODE_NAMES.get(custom_mode, f"MODE({custom_mode})")


def is_rtl_request(event: Event) -> bool:
    """An RTL request: a mode change to RTL (SET_MODE, DO_SET_MODE) or NAV_RETURN_TO_LAUNCH,
    whatever the vehicle answered (MCP-BLK-7 judges the attempt)."""
    d = event.detail
    return event.kind == "request" and (d.get("request") == "rtl"
                                        or (d.get("request") == "mode" and d.get("mode") == "RTL"))


def describe_request(event: Event) -> str:
    """One line for evidence: what was asked, how, and the vehicle's answer."""
    d = event.detail
    what = str(d.get("request", "?"))
    if what in ("mode", "rtl", "land", "mission_start") and d.get("mode"):
        what = f"{what} {d['mode']}" if what == "mode" else f"{what} (mode {d['mode']})"
    elif what in ("arm", "disarm") and d.get("forced"):
        what += " (forced)"
    elif what == "takeoff":
        what += f" to {d.get('alt')} m"
    answer = str(d.get("result", "?"))
    if d.get("reason"):
        answer += f": {d['reason']}"
    via, name = d.get("via"), d.get("name")
    how = f"{via}" if name in (None, via) else f"{via} {name}"
    return f"{what} request ({how}) -> {answer}"

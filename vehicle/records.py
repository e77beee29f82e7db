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
    "landed",  # a descent reached the ground (detail: mode)
    "fix",  # telemetry started reporting a 3D fix
    "fix_lost",  # telemetry stopped reporting a fix
    "mission",  # a mission upload completed or was cleared (detail: count)
    "request",  # a request of the peer and the vehicle's answer (detail: request, answer,
    #             accepted, why, srcsys, srccomp, conn, and what it named: command, params,
    #             mode, seq, x, y, z...); ``--record FILE`` writes these, one JSON line each
    "item_reached",  # AUTO completed a mission command (detail: seq, command)
    "mission_complete",  # AUTO ran past the last mission item (detail: items)
    "error",  # the vehicle failed on a message (its own bug; detail: type, error, conn)
    "probe",  # a passthrough probe arrived (detail: token)
    "connect",  # a TCP client connected, a UDP peer was first heard (detail: conn, peer,
    #             transport)
    "disconnect",  # a TCP client went away (detail: conn, peer)
)


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


def mode_name(custom_mode: int) -> str:
    """The ArduCopter name of ``custom_mode`` (``"MODE(n)"`` when unknown)."""
    return COPTER_MODE_NAMES.get(custom_mode, f"MODE({custom_mode})")

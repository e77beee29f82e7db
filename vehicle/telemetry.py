"""What the vehicle streams and sends on request, as ArduCopter 4.x does (sans-I/O).

Messages (``TelemetryMessages.message(msgid, now)`` builds each; None when there is
nothing to say):

* SYS_STATUS with ArduPilot's sensor bits (``GCS::update_sensor_status_flags`` and
  ``GCS_MAVLINK_Copter``): gyro, accel, mag, baro, GPS (healthy only with a 3D fix), AHRS,
  the rate/attitude/yaw/altitude/position controllers, motor outputs (enabled when armed),
  battery, logging; the geofence bit is present and healthy but not enabled (FENCE_ENABLE 0;
  healthy means "not breached", so MAVProxy reports no breach); MAV_SYS_STATUS_PREARM_CHECK
  is present and enabled (ARMING_CHECK 1) and healthy when armed or when the pre-arm checks
  pass, which here means a 3D fix (no fix: not healthy, so "no fix -> not armable", the rule
  MCP-BLK-4/5 rely on).
* EKF_STATUS_REPORT (``NavEKF3::send_status_report``): with a fix attitude, velocities,
  relative/absolute horizontal and vertical position and their predicted forms; without,
  attitude, vertical velocity/position and EKF_CONST_POS_MODE, as an EKF without GPS
  reports (dronekit's ``ekf_ok`` and ``is_armable`` follow the fix).
* EXTENDED_SYS_STATE (``GCS_MAVLINK_Copter::landed_state``): ON_GROUND, TAKEOFF while a
  takeoff climbs, LANDING while RTL/LAND descend, IN_AIR otherwise; vtol_state
  MAV_VTOL_STATE_UNDEFINED, as a copter reports it.
* HOME_POSITION once home is set (at the first fix, when ArduPilot sends it unasked) and then
  every ``HOME_INTERVAL`` s; AUTOPILOT_VERSION with ArduCopter's capability bits and
  ``flight_sw_version`` = major<<24 | minor<<16 | patch<<8 | FIRMWARE_VERSION_TYPE_OFFICIAL
  (``AP_FWVersion``; dronekit shows "APM:Copter-4.5.7").
* GPS_RAW_INT, GLOBAL_POSITION_INT (alt AMSL, relative_alt), LOCAL_POSITION_NED (from home),
  VFR_HUD, ATTITUDE, MISSION_CURRENT, POSITION_TARGET_GLOBAL_INT (while GUIDED has a target).

``Streams`` schedules them: the HEARTBEAT at ``heartbeat_hz`` (no stream holds it, so no
REQUEST_DATA_STREAM touches it), the rest at ``telemetry_hz`` as if every SRn_ stream rate were
set to it. MAV_CMD_SET_MESSAGE_INTERVAL sets one message's interval as
``GCS_MAVLINK::set_message_interval`` does (0: the default, -1: stop, over 60 s: 60 s; a message
the vehicle cannot send: MAV_RESULT_FAILED; an interval under 80 % of the main loop's period is
that, ``cap_message_interval``: "It can't be greater than 0.8 * SCHED_LOOP_RATE", i.e.
``loop_period_us/800`` ms, 3 ms at ArduCopter's 400 Hz), the HEARTBEAT's included:
ArduPilot maps MAVLINK_MSG_ID_HEARTBEAT to MSG_HEARTBEAT (``mavlink_id_to_ap_message_id``), a
deferred message whose interval ``set_ap_message_interval`` sets like any other (1 s at start,
``initialise_message_intervals_from_streamrates``; 0 restores it, 1 s,
``get_default_interval_for_ap_message``) and which ``deferred_message_to_send_index`` skips
while its interval is 0: -1 is ACCEPTED and the HEARTBEAT stops until an interval is set
again, as mavlink.io's message-rates page has it for any message ("To silence a message, set
param2 ... to -1"). REQUEST_DATA_STREAM sets every message of a stream
(``handle_request_data_stream``: start_stop 0 stops, 1 sets the rate in Hz, anything else is
ignored; ArduCopter's stream lists below). Rates are the vehicle's, not per link (ArduPilot's
are per link: there a HEARTBEAT stopped on one link still goes out on the others).
"""

from __future__ import annotations

import math
from collections.abc import Callable

from pymavlink.dialects.v20 import ardupilotmega as mav

from .codec import MAVLinkMessage

#: ArduCopter's main loop period (SCHED_LOOP_RATE 400 Hz), which caps a message's rate.
LOOP_PERIOD_US = 2500
#: The shortest interval a message gets (``cap_message_interval``: ``loop_period_us/800.0f``
#: stored in a uint16_t of milliseconds: 3 ms at 400 Hz).
MIN_INTERVAL_MS = int(LOOP_PERIOD_US / 800)
#: Seconds between HOME_POSITION messages once home is set.
HOME_INTERVAL = 5.0
#: The version the vehicle reports (AUTOPILOT_VERSION, banner).
FIRMWARE_VERSION = (4, 5, 7)

# The messages of each MAV_DATA_STREAM, as ArduCopter's GCS_Mavlink.cpp lists them (only
# those this vehicle sends; EXTENDED_SYS_STATE and HOME_POSITION are sent outside the streams
# by ArduCopter and are given here to EXTENDED_STATUS so that a stream request covers them).
_ID = {name: getattr(mav, f"MAVLINK_MSG_ID_{name}") for name in (
    "SYS_STATUS", "MISSION_CURRENT", "GPS_RAW_INT", "POSITION_TARGET_GLOBAL_INT",
    "GLOBAL_POSITION_INT", "LOCAL_POSITION_NED", "ATTITUDE", "VFR_HUD", "EKF_STATUS_REPORT",
    "EXTENDED_SYS_STATE", "HOME_POSITION", "AUTOPILOT_VERSION", "HEARTBEAT")}
STREAMS: dict[int, tuple[int, ...]] = {
    mav.MAV_DATA_STREAM_EXTENDED_STATUS: (
        _ID["SYS_STATUS"], _ID["MISSION_CURRENT"], _ID["GPS_RAW_INT"],
        _ID["POSITION_TARGET_GLOBAL_INT"], _ID["EXTENDED_SYS_STATE"]),
    mav.MAV_DATA_STREAM_POSITION: (_ID["GLOBAL_POSITION_INT"], _ID["LOCAL_POSITION_NED"]),
    mav.MAV_DATA_STREAM_EXTRA1: (_ID["ATTITUDE"],),
    mav.MAV_DATA_STREAM_EXTRA2: (_ID["VFR_HUD"],),
    mav.MAV_DATA_STREAM_EXTRA3: (_ID["EKF_STATUS_REPORT"],),
}
#: Streamed messages, in the order they go out.
STREAMED: tuple[int, ...] = (
    _ID["SYS_STATUS"], _ID["GPS_RAW_INT"], _ID["GLOBAL_POSITION_INT"], _ID["VFR_HUD"],
    _ID["ATTITUDE"], _ID["MISSION_CURRENT"], _ID["EKF_STATUS_REPORT"],
    _ID["EXTENDED_SYS_STATE"], _ID["LOCAL_POSITION_NED"], _ID["POSITION_TARGET_GLOBAL_INT"],
    _ID["HOME_POSITION"])
#: Messages sent only on request (REQUEST_MESSAGE, or an interval set for them).
ON_REQUEST: tuple[int, ...] = (_ID["AUTOPILOT_VERSION"], _ID["HEARTBEAT"])


def message_name(msgid: int) -> str:
    cls = mav.mavlink_map.get(msgid)
    return cls.msgname if cls is not None else f"message {msgid}"


def capabilities() -> int:
    """ArduCopter's MAV_PROTOCOL_CAPABILITY bits (``GCS_MAVLINK_Copter::capabilities`` and
    ``GCS_MAVLINK::capabilities``), less those of what this vehicle does not serve: FTP,
    fence and rally missions, attitude targets, flight termination, terrain."""
    return (mav.MAV_PROTOCOL_CAPABILITY_MISSION_FLOAT | mav.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | mav.MAV_PROTOCOL_CAPABILITY_MISSION_INT | mav.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
            | mav.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_GLOBAL_INT
            | mav.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mav.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST)


def flight_sw_version(version: tuple[int, int, int] = FIRMWARE_VERSION) -> int:
    major, minor, patch = version
    return (major << 24) | (minor << 16) | (patch << 8) | mav.FIRMWARE_VERSION_TYPE_OFFICIAL


class Streams:
    """Per-message intervals (seconds; 0 = not sent) and when each is next due."""

    def __init__(self, defaults: dict[int, float], now: float) -> None:
        self._defaults = dict(defaults)
        self.interval = dict(defaults)
        self._due = dict.fromkeys(defaults, now)

    def known(self, msgid: int) -> bool:
        return msgid in self._defaults

    def set_interval(self, msgid: int, interval_us: float, now: float) -> tuple[int, str]:
        """MAV_CMD_SET_MESSAGE_INTERVAL: (MAV_RESULT, why when refused); the HEARTBEAT's too
        (-1 stops it, as ArduPilot's ``set_message_interval``: see the module docstring)."""
        if msgid not in self._defaults:
            return mav.MAV_RESULT_FAILED, f"{message_name(msgid)} is not sent by this vehicle"
        if not math.isfinite(interval_us):
            return mav.MAV_RESULT_FAILED, f"interval {interval_us} is not a number"
        us = int(interval_us)
        if us == 0:
            seconds = self._defaults[msgid]
        elif us == -1:
            seconds = 0.0
        elif us < 0:
            return mav.MAV_RESULT_FAILED, f"interval {us} us is negative (only -1 stops)"
        else:
            ms = min(us, 60_000_000) / 1000
            seconds = (MIN_INTERVAL_MS if ms * 800 < LOOP_PERIOD_US else ms) / 1000
        self.interval[msgid] = seconds
        self._due[msgid] = now + seconds if seconds else math.inf
        return mav.MAV_RESULT_ACCEPTED, ""

    def set_rate(self, msgid: int, hz: float, now: float) -> None:
        """A stream rate (REQUEST_DATA_STREAM): ``hz`` 0 stops the message."""
        seconds = 1.0 / hz if hz > 0 else 0.0
        self.interval[msgid] = seconds
        self._due[msgid] = now + seconds if seconds else math.inf

    def interval_us(self, msgid: int) -> int:
        """MESSAGE_INTERVAL.interval_us: -1 stopped, 0 unknown, else microseconds."""
        if msgid not in self.interval:
            return 0
        s = self.interval[msgid]
        return int(round(s * 1e6)) if s else -1

    def due(self, now: float) -> list[int]:
        """The messages due at ``now`` (each rescheduled, missed slots skipped)."""
        out = []
        for msgid, period in self.interval.items():
            if period and now >= self._due[msgid]:
                out.append(msgid)
                nxt = self._due[msgid] + period
                self._due[msgid] = nxt if nxt > now else now + period
        return out

    def next_deadline(self) -> float:
        return min((t for m, t in self._due.items() if self.interval[m]), default=math.inf)


#: A builder of one message at ``now`` (None: nothing to send now).
Builder = Callable[[float], "MAVLinkMessage | None"]


_SENSORS = (
    mav.MAV_SYS_STATUS_SENSOR_3D_GYRO | mav.MAV_SYS_STATUS_SENSOR_3D_ACCEL
    | mav.MAV_SYS_STATUS_SENSOR_3D_MAG | mav.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE
    | mav.MAV_SYS_STATUS_SENSOR_GPS | mav.MAV_SYS_STATUS_SENSOR_ANGULAR_RATE_CONTROL
    | mav.MAV_SYS_STATUS_SENSOR_ATTITUDE_STABILIZATION | mav.MAV_SYS_STATUS_SENSOR_YAW_POSITION
    | mav.MAV_SYS_STATUS_SENSOR_Z_ALTITUDE_CONTROL
    | mav.MAV_SYS_STATUS_SENSOR_XY_POSITION_CONTROL | mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS
    | mav.MAV_SYS_STATUS_AHRS | mav.MAV_SYS_STATUS_SENSOR_BATTERY | mav.MAV_SYS_STATUS_LOGGING
)
_EKF_GOOD = (mav.EKF_ATTITUDE | mav.EKF_VELOCITY_HORIZ | mav.EKF_VELOCITY_VERT
             | mav.EKF_POS_HORIZ_REL | mav.EKF_POS_HORIZ_ABS | mav.EKF_POS_VERT_ABS
             | mav.EKF_PRED_POS_HORIZ_REL | mav.EKF_PRED_POS_HORIZ_ABS)
_EKF_NO_GPS = (mav.EKF_ATTITUDE | mav.EKF_VELOCITY_VERT | mav.EKF_POS_VERT_ABS
               | mav.EKF_CONST_POS_MODE)


def sys_status(fix: bool, armed: bool, fence_enabled: bool) -> MAVLinkMessage:
    """SYS_STATUS as ArduCopter fills it (see the module docstring)."""
    present = _SENSORS | mav.MAV_SYS_STATUS_GEOFENCE | mav.MAV_SYS_STATUS_PREARM_CHECK
    enabled = (_SENSORS | mav.MAV_SYS_STATUS_PREARM_CHECK) & ~(
        0 if armed else mav.MAV_SYS_STATUS_SENSOR_MOTOR_OUTPUTS)
    if fence_enabled:
        enabled |= mav.MAV_SYS_STATUS_GEOFENCE
    health = _SENSORS | mav.MAV_SYS_STATUS_GEOFENCE
    if not fix:
        health &= ~mav.MAV_SYS_STATUS_SENSOR_GPS
    if armed or fix:
        health |= mav.MAV_SYS_STATUS_PREARM_CHECK
    return mav.MAVLink_sys_status_message(
        present, enabled, health, 200, 12600, 1000 if armed else 50, 100, 0, 0, 0, 0, 0, 0)


def ekf_status_report(fix: bool) -> MAVLinkMessage:
    """EKF_STATUS_REPORT: good position flags only with a GPS fix."""
    if fix:
        return mav.MAVLink_ekf_status_report_message(_EKF_GOOD, 0.02, 0.03, 0.02, 0.01, 0.0)
    return mav.MAVLink_ekf_status_report_message(_EKF_NO_GPS, 0.02, 0.0, 0.02, 0.01, 0.0)


def autopilot_version(sysid: int) -> MAVLinkMessage:
    """AUTOPILOT_VERSION of a simulated ArduCopter (SITL's board and ids are 0)."""
    return mav.MAVLink_autopilot_version_message(
        capabilities(), flight_sw_version(), 0, 0, 0, b"simveh00", b"\0" * 8, b"\0" * 8,
        0, 0, sysid, b"\0" * 18)


def home_position(lat: float, lon: float, alt: float, usec: int) -> MAVLinkMessage:
    """HOME_POSITION at (lat, lon, AMSL alt); local x/y/z 0 (home is the EKF origin here)."""
    return mav.MAVLink_home_position_message(
        int(round(lat * 1e7)), int(round(lon * 1e7)), int(round(alt * 1000)), 0.0, 0.0, 0.0,
        [1.0, 0.0, 0.0, 0.0], 0.0, 0.0, 0.0, usec)

"""The MAVLink mission protocol as ArduCopter 4.x answers it (sans-I/O).

This follows ArduPilot's ``libraries/GCS_MAVLink/MissionItemProtocol.cpp``,
``MissionItemProtocol_Waypoints.cpp``, ``GCS_Common.cpp`` (``handle_mission_item``) and
``libraries/AP_Mission/AP_Mission.cpp`` (the item conversions and checks):

* Upload: MISSION_COUNT truncates the stored mission to ``count`` items and starts a
  transfer owned by the sender (sysid, compid) and its link; the vehicle asks for each item
  in turn with **MISSION_REQUEST** (ArduPilot's ``queued_request_send`` sends
  MISSION_REQUEST, not MISSION_REQUEST_INT, to every peer; ``request_int=True`` asks with
  MISSION_REQUEST_INT instead, as the mission-protocol page and PX4 do). Either MISSION_ITEM
  or MISSION_ITEM_INT is accepted as the answer (MISSION_ITEM draws the warning
  "got MISSION_ITEM; GCS should send MISSION_ITEM_INT" once per transfer).
* Each item is checked as ``AP_Mission`` checks it: a MISSION_ITEM whose x/y is not a
  latitude/longitude in degrees (``|x| > 90``: the classic degE7 integer sent as degrees)
  is answered MAV_MISSION_INVALID_PARAM5_X (PARAM6_Y for y) *before* the transfer sees it,
  so the transfer goes on and the same item is asked for again; a MISSION_ITEM_INT whose
  x is outside +-90e7 (PARAM5_X), y outside +-180e7 (PARAM6_Y), z NaN or beyond 83 km
  (PARAM7), an unknown command (UNSUPPORTED) or frame (UNSUPPORTED_FRAME) ends the transfer
  with that code. A wrong ``seq`` gets MAV_MISSION_INVALID_SEQUENCE (transfer continues);
  an item from another system/component gets MAV_MISSION_DENIED.
* **Unrequested items are refused**: a MISSION_ITEM[_INT] while no upload is in progress
  gets MISSION_ACK MAV_MISSION_ERROR and changes nothing (``GCS_Common.cpp``: "if
  (!prot->receiving) send_mission_ack(... MAV_MISSION_ERROR)").
* A request not answered within 1 s is sent again; 8 s without an item cancels the upload
  (MISSION_ACK MAV_MISSION_OPERATION_CANCELLED, "Mission upload timeout"); the items
  received so far stay stored, as in ArduPilot.
* Download: MISSION_REQUEST_LIST -> MISSION_COUNT; MISSION_REQUEST_INT -> MISSION_ITEM_INT,
  MISSION_REQUEST -> MISSION_ITEM; item 0 is always home; a seq past the end gets
  MISSION_COUNT and MISSION_ACK MAV_MISSION_ERROR; any of them during an upload gets
  MAV_MISSION_DENIED. MISSION_CLEAR_ALL is refused (ERROR) during an upload or while the
  mission runs.

Differences from ArduCopter (also in ``mcp-vehicle --help``): only the mission type
MISSION is stored (fence and rally transfers get MAV_MISSION_UNSUPPORTED, except an empty
one); at most ``max_items`` items (700).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from .codec import MAVLinkMessage

#: Seconds without an item before ArduPilot cancels an upload (``upload_timeout_ms``).
UPLOAD_TIMEOUT = 8.0
#: Seconds before an unanswered item request is sent again (``wp_recv_timeout_ms``).
REQUEST_RESEND = 1.0
#: ``LOCATION_ALT_MAX_M`` in ArduPilot (a 24-bit centimetre altitude).
LOCATION_ALT_MAX_M = 83000.0

_C = mav
#: Commands whose x/y are not a latitude/longitude (``convert_MISSION_ITEM_to_MISSION_ITEM_INT``).
XY_NOT_LOCATION = frozenset({
    _C.MAV_CMD_DO_DIGICAM_CONTROL, _C.MAV_CMD_DO_DIGICAM_CONFIGURE,
    _C.MAV_CMD_NAV_ATTITUDE_TIME, _C.MAV_CMD_DO_GIMBAL_MANAGER_PITCHYAW,
})
#: Commands stored with a location (``AP_Mission::stored_in_location``).
LOCATION_COMMANDS = frozenset({
    _C.MAV_CMD_NAV_WAYPOINT, _C.MAV_CMD_NAV_LOITER_UNLIM, _C.MAV_CMD_NAV_LOITER_TURNS,
    _C.MAV_CMD_NAV_LOITER_TIME, _C.MAV_CMD_NAV_RETURN_TO_LAUNCH, _C.MAV_CMD_NAV_LAND,
    _C.MAV_CMD_NAV_TAKEOFF, _C.MAV_CMD_NAV_CONTINUE_AND_CHANGE_ALT,
    _C.MAV_CMD_NAV_LOITER_TO_ALT, _C.MAV_CMD_NAV_SPLINE_WAYPOINT,
    _C.MAV_CMD_NAV_GUIDED_ENABLE, _C.MAV_CMD_DO_SET_HOME, _C.MAV_CMD_DO_LAND_START,
    _C.MAV_CMD_DO_GO_AROUND, _C.MAV_CMD_DO_SET_ROI, _C.MAV_CMD_DO_SET_ROI_LOCATION,
    _C.MAV_CMD_NAV_VTOL_TAKEOFF, _C.MAV_CMD_NAV_VTOL_LAND, _C.MAV_CMD_NAV_PAYLOAD_PLACE,
})
#: Commands ``AP_Mission::mavlink_int_to_mission_cmd`` converts (others: UNSUPPORTED).
MISSION_COMMANDS = LOCATION_COMMANDS | XY_NOT_LOCATION | frozenset({
    _C.MAV_CMD_NAV_ALTITUDE_WAIT, _C.MAV_CMD_NAV_DELAY, _C.MAV_CMD_CONDITION_DELAY,
    _C.MAV_CMD_CONDITION_DISTANCE, _C.MAV_CMD_CONDITION_YAW, _C.MAV_CMD_DO_SET_MODE,
    _C.MAV_CMD_DO_JUMP, _C.MAV_CMD_DO_CHANGE_SPEED, _C.MAV_CMD_DO_SET_RELAY,
    _C.MAV_CMD_DO_REPEAT_RELAY, _C.MAV_CMD_DO_SET_SERVO, _C.MAV_CMD_DO_REPEAT_SERVO,
    _C.MAV_CMD_DO_SET_ROI_NONE, _C.MAV_CMD_DO_MOUNT_CONTROL, _C.MAV_CMD_DO_SET_CAM_TRIGG_DIST,
    _C.MAV_CMD_DO_FENCE_ENABLE, _C.MAV_CMD_DO_PARACHUTE, _C.MAV_CMD_DO_INVERTED_FLIGHT,
    _C.MAV_CMD_DO_GRIPPER, _C.MAV_CMD_DO_AUTOTUNE_ENABLE, _C.MAV_CMD_DO_GUIDED_LIMITS,
    _C.MAV_CMD_DO_SET_REVERSE, _C.MAV_CMD_DO_ENGINE_CONTROL, _C.MAV_CMD_DO_SPRAYER,
    _C.MAV_CMD_DO_AUX_FUNCTION, _C.MAV_CMD_DO_SET_RESUME_REPEAT_DIST,
    _C.MAV_CMD_DO_PAUSE_CONTINUE, _C.MAV_CMD_DO_WINCH, _C.MAV_CMD_IMAGE_START_CAPTURE,
    _C.MAV_CMD_IMAGE_STOP_CAPTURE, _C.MAV_CMD_VIDEO_START_CAPTURE,
    _C.MAV_CMD_VIDEO_STOP_CAPTURE, _C.MAV_CMD_DO_VTOL_TRANSITION,
})
#: Frames a location item may use (``mavlink_int_to_mission_cmd``).
LOCATION_FRAMES = frozenset({
    _C.MAV_FRAME_MISSION, _C.MAV_FRAME_GLOBAL, _C.MAV_FRAME_GLOBAL_INT,
    _C.MAV_FRAME_GLOBAL_RELATIVE_ALT, _C.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    _C.MAV_FRAME_GLOBAL_TERRAIN_ALT, _C.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
})
#: The "navigation" commands (``AP_Mission::is_nav_cmd``: ids up to NAV_LAST).
NAV_LAST = _C.MAV_CMD_NAV_LAST

ACCEPTED = mav.MAV_MISSION_ACCEPTED


def result_name(code: int) -> str:
    """``MAV_MISSION_RESULT`` name of ``code`` (e.g. ``"MAV_MISSION_INVALID_PARAM5_X"``)."""
    entry = mav.enums["MAV_MISSION_RESULT"].get(code)
    return entry.name if entry is not None else str(code)


def command_name(cmd: int) -> str:
    entry = mav.enums["MAV_CMD"].get(cmd)
    return entry.name if entry is not None else str(cmd)


def is_nav(cmd: int) -> bool:
    return cmd <= NAV_LAST or cmd == _C.MAV_CMD_NAV_SET_YAW_SPEED


def _statustext(severity: int, text: str) -> MAVLinkMessage:
    return mav.MAVLink_statustext_message(severity, text.encode("ascii")[:50])


@dataclass
class Answer:
    """What the protocol does with one message: replies to the sender and the record."""

    replies: list[MAVLinkMessage] = field(default_factory=list)
    #: MISSION_ACK result (None when the message is answered with an item or a request).
    result: int | None = None
    why: str = ""


@dataclass
class _Upload:
    conn: int
    sysid: int
    compid: int
    request_i: int
    request_last: int
    last_receive: float
    last_request: float
    item_warning_sent: bool = False


class MissionProtocol:
    """ArduCopter's waypoint MissionItemProtocol: stored items and the upload in progress.

    Items are kept as MISSION_ITEM_INT field dicts (x/y in degE7 for location commands).
    ``home`` returns (lat, lon, alt AMSL) for item 0 of a download; ``running`` says whether
    the mission is being flown (clearing is then refused).
    """

    def __init__(self, home: Callable[[], tuple[float, float, float]],
                 running: Callable[[], bool], *, request_int: bool = False,
                 max_items: int = 700) -> None:
        self.items: list[dict[str, Any]] = []
        self.upload: _Upload | None = None
        self.request_int = request_int
        self.max_items = max_items
        self.current = 0
        self._home = home
        self._running = running
        self._request_warning_sent = False

    # ------------------------------------------------------------------ helpers
    def _ack(self, src: tuple[int, int], result: int, mission_type: int = 0) -> MAVLinkMessage:
        return mav.MAVLink_mission_ack_message(src[0], src[1], result, mission_type)

    def _refuse(self, src: tuple[int, int], result: int, why: str,
                mission_type: int = 0) -> Answer:
        return Answer([self._ack(src, result, mission_type)], result, why)

    def _request(self, up: _Upload) -> MAVLinkMessage:
        cls = (mav.MAVLink_mission_request_int_message if self.request_int
               else mav.MAVLink_mission_request_message)
        return cls(up.sysid, up.compid, up.request_i, 0)

    # ------------------------------------------------------------------ upload
    def count(self, f: dict[str, Any], src: tuple[int, int], conn: int, now: float) -> Answer:
        """MISSION_COUNT: start (or restart) an upload."""
        count, mtype = int(f["count"]), int(f.get("mission_type", 0) or 0)
        if mtype != mav.MAV_MISSION_TYPE_MISSION:
            if count == 0:
                return Answer([self._ack(src, ACCEPTED, mtype)], ACCEPTED, "empty transfer")
            return self._refuse(src, mav.MAV_MISSION_UNSUPPORTED,
                                f"mission type {mtype} is not simulated", mtype)
        up = self.upload
        if up is not None and (up.sysid, up.compid) != src:
            return self._refuse(src, mav.MAV_MISSION_DENIED,
                                f"an upload by {up.sysid}/{up.compid} is in progress")
        if count > self.max_items:
            ans = self._refuse(src, mav.MAV_MISSION_NO_SPACE,
                               f"Only {self.max_items} items are supported")
            ans.replies.insert(0, _statustext(mav.MAV_SEVERITY_WARNING, ans.why))
            return ans
        del self.items[count:]  # ArduPilot truncates the stored mission at once
        self.upload = None
        if count == 0:
            return self._complete(src, "empty mission")
        self.upload = _Upload(conn, src[0], src[1], 0, count - 1, now, now)
        return Answer([self._request(self.upload)], None, f"requesting {count} items")

    def item(self, msg_type: str, f: dict[str, Any], src: tuple[int, int],
             now: float) -> Answer:
        """MISSION_ITEM / MISSION_ITEM_INT (``current`` 0/1; guided items are the model's)."""
        item = dict(f)
        item.pop("target_system", None)
        item.pop("target_component", None)
        mtype = int(item.get("mission_type", 0) or 0)
        is_float = msg_type == "MISSION_ITEM"
        if is_float:
            result, why = convert_float_item(item)
            if result != ACCEPTED:
                return self._refuse(src, result, why, mtype)
        if mtype != mav.MAV_MISSION_TYPE_MISSION:
            return self._refuse(src, mav.MAV_MISSION_UNSUPPORTED,
                                f"mission type {mtype} is not simulated", mtype)
        up = self.upload
        replies: list[MAVLinkMessage] = []
        if is_float and up is not None and not up.item_warning_sent:
            up.item_warning_sent = True
            replies.append(_statustext(mav.MAV_SEVERITY_WARNING,
                                       "got MISSION_ITEM; GCS should send MISSION_ITEM_INT"))
        if up is None:
            return self._refuse(src, mav.MAV_MISSION_ERROR,
                                "unrequested item: no upload in progress")
        seq = int(item["seq"])
        if seq != up.request_i:
            ans = self._refuse(src, mav.MAV_MISSION_INVALID_SEQUENCE,
                               f"item {seq} arrived, item {up.request_i} was requested")
            ans.replies[:0] = replies
            return ans
        if src != (up.sysid, up.compid):
            return self._refuse(src, mav.MAV_MISSION_DENIED,
                                f"the upload belongs to {up.sysid}/{up.compid}")
        result, why = check_item(item)
        if result == ACCEPTED and int(item["command"]) == mav.MAV_CMD_DO_JUMP:
            target = int(item["param1"])
            if target == 0 or (target >= len(self.items) and target > up.request_last):
                result, why = mav.MAV_MISSION_ERROR, f"DO_JUMP to {target} is outside the mission"
        if result == ACCEPTED and seq > len(self.items):
            result, why = mav.MAV_MISSION_ERROR, f"item {seq} is beyond the end of the mission"
        if result != ACCEPTED:
            self.upload = None  # ArduPilot ends the transfer on a bad item
            ans = self._refuse(src, result, why + "; upload cancelled")
            ans.replies[:0] = replies
            return ans
        item["type"] = msg_type
        if seq < len(self.items):
            self.items[seq] = item
        else:
            self.items.append(item)
        up.last_receive = now
        up.request_i += 1
        if up.request_i > up.request_last:
            ans = self._complete(src, f"item {seq} stored; flight plan received")
            ans.replies[:0] = replies
            return ans
        up.last_request = now
        return Answer([*replies, self._request(up)], None, f"item {seq} stored")

    def _complete(self, src: tuple[int, int], why: str) -> Answer:
        self.upload = None
        return Answer([_statustext(mav.MAV_SEVERITY_INFO, "Flight plan received"),
                       self._ack(src, ACCEPTED)], ACCEPTED, why)

    def update(self, now: float) -> tuple[int, list[MAVLinkMessage], str | None]:
        """Resend a due item request or cancel a stalled upload: (conn, messages, why)."""
        up = self.upload
        if up is None:
            return 0, [], None
        if now - up.last_receive > UPLOAD_TIMEOUT:
            self.upload = None
            return up.conn, [
                _statustext(mav.MAV_SEVERITY_WARNING, "Mission upload timeout"),
                mav.MAVLink_mission_ack_message(up.sysid, up.compid,
                                                mav.MAV_MISSION_OPERATION_CANCELLED, 0),
            ], f"no item for {UPLOAD_TIMEOUT:g} s after item {up.request_i - 1}"
        if now - up.last_request > REQUEST_RESEND:
            up.last_request = now
            return up.conn, [self._request(up)], None
        return 0, [], None

    # ------------------------------------------------------------------ download, clear
    def request_list(self, f: dict[str, Any], src: tuple[int, int]) -> Answer:
        mtype = int(f.get("mission_type", 0) or 0)
        if self.upload is not None:
            return self._refuse(src, mav.MAV_MISSION_DENIED, "an upload is in progress", mtype)
        count = len(self.items) if mtype == mav.MAV_MISSION_TYPE_MISSION else 0
        return Answer([mav.MAVLink_mission_count_message(src[0], src[1], count, mtype)], None,
                      f"{count} items")

    def request_item(self, msg_type: str, f: dict[str, Any], src: tuple[int, int]) -> Answer:
        """MISSION_REQUEST_INT (-> MISSION_ITEM_INT) or MISSION_REQUEST (-> MISSION_ITEM)."""
        mtype = int(f.get("mission_type", 0) or 0)
        if self.upload is not None:
            return self._refuse(src, mav.MAV_MISSION_DENIED, "an upload is in progress", mtype)
        if mtype != mav.MAV_MISSION_TYPE_MISSION:
            return self._refuse(src, mav.MAV_MISSION_UNSUPPORTED,
                                f"mission type {mtype} is not simulated", mtype)
        seq = int(f["seq"])
        replies: list[MAVLinkMessage] = []
        if msg_type == "MISSION_REQUEST" and not self._request_warning_sent:
            self._request_warning_sent = True
            replies.append(_statustext(mav.MAV_SEVERITY_WARNING,
                                       "got MISSION_REQUEST; use MISSION_REQUEST_INT!"))
        if seq != 0 and seq >= len(self.items):
            count = mav.MAVLink_mission_count_message(src[0], src[1], len(self.items), 0)
            return Answer([*replies, count, self._ack(src, mav.MAV_MISSION_ERROR)],
                          mav.MAV_MISSION_ERROR, f"no item {seq}")
        it = self.stored(seq)
        x, y = it["x"], it["y"]
        if msg_type == "MISSION_REQUEST":
            cls = mav.MAVLink_mission_item_message
            if int(it["command"]) not in XY_NOT_LOCATION:
                x, y = x * 1e-7, y * 1e-7
        else:
            cls = mav.MAVLink_mission_item_int_message
        msg = cls(src[0], src[1], seq, it["frame"], it["command"], int(seq == self.current),
                  1, it["param1"], it["param2"], it["param3"], it["param4"], x, y, it["z"], 0)
        return Answer([*replies, msg], None, f"item {seq}")

    def stored(self, seq: int) -> dict[str, Any]:
        """Item ``seq`` as stored (item 0 is always home, as ``read_cmd_from_storage`` says)."""
        if seq == 0:
            lat, lon, alt = self._home()
            return {"seq": 0, "frame": mav.MAV_FRAME_GLOBAL, "command": mav.MAV_CMD_NAV_WAYPOINT,
                    "param1": 0.0, "param2": 0.0, "param3": 0.0, "param4": 0.0,
                    "x": int(round(lat * 1e7)), "y": int(round(lon * 1e7)), "z": float(alt)}
        return self.items[seq]

    def clear_all(self, f: dict[str, Any], src: tuple[int, int]) -> Answer:
        mtype = int(f.get("mission_type", 0) or 0)
        if mtype != mav.MAV_MISSION_TYPE_MISSION:
            return Answer([self._ack(src, ACCEPTED, mtype)], ACCEPTED, "nothing stored")
        if self.upload is not None:
            return self._refuse(src, mav.MAV_MISSION_ERROR, "an upload is in progress")
        if self._running():
            return self._refuse(src, mav.MAV_MISSION_ERROR, "the mission is running")
        self.items = []
        self.current = 0
        return Answer([self._ack(src, ACCEPTED)], ACCEPTED, "mission cleared")

    # ------------------------------------------------------------------ execution helpers
    def next_command(self, start: int) -> int | None:
        """Index of the first stored command at or after ``start`` (item 0 is home)."""
        start = max(start, 1)
        return start if start < len(self.items) else None

    def first_nav(self, start: int = 1) -> dict[str, Any] | None:
        for i in range(max(start, 1), len(self.items)):
            if is_nav(int(self.items[i]["command"])):
                return self.items[i]
        return None

    def current_message(self) -> MAVLinkMessage:
        """MISSION_CURRENT as ArduCopter streams it (seq, total = items after home)."""
        total = max(len(self.items) - 1, 0)
        return mav.MAVLink_mission_current_message(self.current, total, 0, 0)


def convert_float_item(item: dict[str, Any]) -> tuple[int, str]:
    """MISSION_ITEM -> MISSION_ITEM_INT in place (degrees x1e7), ArduPilot's checks first."""
    if int(item["command"]) in XY_NOT_LOCATION:
        item["x"], item["y"] = int(item["x"]), int(item["y"])
        return ACCEPTED, ""
    x, y = float(item["x"]), float(item["y"])
    if not (math.isfinite(x) and abs(x) <= 90.0):
        return (mav.MAV_MISSION_INVALID_PARAM5_X,
                f"latitude {x:.9g} is not in degrees (-90..90)"
                + ("; a degE7 value sent as degrees?" if abs(x) > 1e6 else ""))
    if not (math.isfinite(y) and abs(y) <= 180.0):
        return (mav.MAV_MISSION_INVALID_PARAM6_Y,
                f"longitude {y:.9g} is not in degrees (-180..180)"
                + ("; a degE7 value sent as degrees?" if abs(y) > 1e6 else ""))
    item["x"], item["y"] = int(x * 1e7), int(y * 1e7)
    return ACCEPTED, ""


def check_item(item: dict[str, Any]) -> tuple[int, str]:
    """``AP_Mission::mavlink_int_to_mission_cmd``'s verdict on a MISSION_ITEM_INT."""
    cmd = int(item["command"])
    if cmd not in MISSION_COMMANDS:
        return mav.MAV_MISSION_UNSUPPORTED, f"command {command_name(cmd)} is not supported"
    if cmd in LOCATION_COMMANDS:
        x, y, z = int(item["x"]), int(item["y"]), float(item["z"])
        if abs(x) > 900_000_000:
            return mav.MAV_MISSION_INVALID_PARAM5_X, f"latitude {x} degE7 is out of range"
        if abs(y) > 1_800_000_000:
            return mav.MAV_MISSION_INVALID_PARAM6_Y, f"longitude {y} degE7 is out of range"
        if math.isnan(z) or abs(z) >= LOCATION_ALT_MAX_M:
            return mav.MAV_MISSION_INVALID_PARAM7, f"altitude {z:g} m is out of range"
        if int(item["frame"]) not in LOCATION_FRAMES:
            return mav.MAV_MISSION_UNSUPPORTED_FRAME, f"frame {item['frame']} is not supported"
    return ACCEPTED, ""

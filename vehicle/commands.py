"""The commands of ``VehicleModel``: COMMAND_LONG / COMMAND_INT (arm and disarm with
ArduPilot's checks and force magic, mode changes, takeoff, RTL, land, mission start), SET_MODE,
STATUSTEXT and the parameter protocol, each recorded as a request with the vehicle's answer
(``records.REQUESTS``). A mixin: it uses the model's state, ``record`` and ``_request``."""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Iterable
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from .codec import MAVLinkMessage
from .mission import command_name
from .probe import probe_token
from .records import (
    ACCEPTED_RESULT,
    AUTO,
    COPTER_MODE_NAMES,
    DENIED_RESULT,
    GUIDED,
    LAND,
    NO_ARM_MODES,
    POSITION_MODES,
    RTL,
    Event,
    mode_name,
)
from .telemetry import STREAMS, Streams, message_name

if TYPE_CHECKING:
    from .flight import AutoMission

#: MAV_CMD_COMPONENT_ARM_DISARM param2 values that skip ArduPilot's checks.
FORCE_ARM_MAGIC = 2989.0
FORCE_DISARM_MAGIC = 21196.0
#: SET_MODE's message id, used by ArduPilot as the "command" of its COMMAND_ACK.
SET_MODE_ACK_COMMAND = 11
#: Result used where ArduCopter refuses a command (its checks failing give FAILED).
REFUSED = mav.MAV_RESULT_FAILED
#: Why a mode change without MAV_MODE_FLAG_CUSTOM_MODE_ENABLED is refused (ArduPilot maps
#: only custom modes).
NO_CUSTOM_FLAG = "base_mode lacks MAV_MODE_FLAG_CUSTOM_MODE_ENABLED (only custom modes are accepted)"
#: Commands about what the vehicle sends (``_stream_command``).
_STREAM_COMMANDS = frozenset({
    mav.MAV_CMD_REQUEST_MESSAGE, mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES,
    mav.MAV_CMD_GET_HOME_POSITION, mav.MAV_CMD_SET_MESSAGE_INTERVAL,
    mav.MAV_CMD_GET_MESSAGE_INTERVAL})
#: Commands that are mode changes: MAV_CMD -> (request name, the mode it enters).
_MODE_COMMANDS: dict[int, tuple[str, int]] = {
    mav.MAV_CMD_NAV_RETURN_TO_LAUNCH: ("rtl", RTL),
    mav.MAV_CMD_NAV_LAND: ("land", LAND),
    mav.MAV_CMD_MISSION_START: ("mission_start", AUTO),
}



class CommandMessages:
    """The handlers ``VehicleModel`` dispatches commands, modes and parameters to."""

    config: Any
    armed: bool
    custom_mode: int
    altitude: float
    rtl_commanded: bool
    home_set: bool
    streams: Streams
    _target_alt: float | None
    _target_pos: tuple[float, float] | None
    _guided_vel: tuple[float, float, float] | None
    taking_off: bool
    _auto: AutoMission
    _conn: int
    _probes: Counter[str]
    _why: str

    if TYPE_CHECKING:
        @property
        def mode(self) -> str: ...

        def record(self, now: float, kind: str, **detail: Any) -> Event: ...

        def has_fix(self, now: float) -> bool: ...

        def message(self, msgid: int, now: float) -> MAVLinkMessage | None: ...

        def _cmd_reposition(self, msg: MAVLinkMessage, p: tuple[float, ...],
                            now: float) -> tuple[int, list]: ...

        def _cmd_condition_yaw(self, p: tuple[float, ...]) -> int: ...

        def _cmd_change_speed(self, p: tuple[float, ...]) -> int: ...

    def _ack(self, msg: MAVLinkMessage, command: int, result: int) -> MAVLinkMessage:
        return mav.MAVLink_command_ack_message(
            command, result, 0, 0, msg.get_srcSystem(), msg.get_srcComponent()
        )

    def _on_statustext(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        token = probe_token(f.get("text"))
        if token is not None:
            self._probes[token] += 1
            self.record(now, "probe", token=token, count=self._probes[token])
        return []

    def _on_request_data_stream(self, msg: MAVLinkMessage, f: dict[str, Any],
                                now: float) -> Iterable:
        """REQUEST_DATA_STREAM as ``GCS_MAVLINK::handle_request_data_stream`` takes it: no
        answer; start_stop 0 stops the stream, 1 sets its rate (Hz), others are ignored."""
        stream, rate = int(f["req_stream_id"]), int(f["req_message_rate"])
        start = int(f["start_stop"])
        hz = 0 if start == 0 else rate
        if start not in (0, 1):
            why = f"start_stop {start} is neither 0 nor 1: ignored"
        elif stream != mav.MAV_DATA_STREAM_ALL and stream not in STREAMS:
            why = f"stream {stream} has nothing this vehicle sends: ignored"
        else:
            why = ""
            every = stream == mav.MAV_DATA_STREAM_ALL
            ids = [m for ids in STREAMS.values() for m in ids] if every else STREAMS[stream]
            for msgid in ids:
                self.streams.set_rate(msgid, hz, now)
        self._request(now, msg, "data_stream", not why, why or None,
                      "none" if why else f"{hz} Hz", stream=stream, rate=hz)
        return []

    def _on_set_mode(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        custom = int(f["custom_mode"])
        if f["base_mode"] & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            result, notes = self._set_mode(custom, now, "SET_MODE")
        else:
            result, notes = REFUSED, []
            self._why = NO_CUSTOM_FLAG
        self._command_request(now, msg, "mode", None, result, notes, mode=mode_name(custom),
                              custom_mode=custom)
        return [*notes, self._ack(msg, SET_MODE_ACK_COMMAND, result)]

    def _on_command_long(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        params = tuple(float(f[f"param{i}"]) for i in range(1, 8))
        return self._command(msg, int(f["command"]), params, now)

    def _on_command_int(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        params = (float(f["param1"]), float(f["param2"]), float(f["param3"]),
                  float(f["param4"]), float(f["x"]), float(f["y"]), float(f["z"]))
        return self._command(msg, int(f["command"]), params, now)

    def _command(
        self, msg: MAVLinkMessage, cmd: int, p: tuple[float, ...], now: float
    ) -> list[MAVLinkMessage]:
        out: list[MAVLinkMessage] = []
        result = mav.MAV_RESULT_ACCEPTED
        request: str = "command"
        extra: dict[str, Any] = {"params": list(p)}
        if cmd == mav.MAV_CMD_COMPONENT_ARM_DISARM:
            result, out = self._arm_disarm(p[0], p[1], now)
            if p[0] in (0.0, 1.0):
                request = "arm" if p[0] == 1.0 else "disarm"
                extra = {"forced": p[1] == (FORCE_ARM_MAGIC if p[0] == 1.0 else FORCE_DISARM_MAGIC)}
        elif cmd == mav.MAV_CMD_DO_SET_MODE:
            custom = _int(p[1])
            request, extra = "mode", {"mode": mode_name(custom), "custom_mode": custom}
            if _int(p[0]) & mav.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
                result, out = self._set_mode(custom, now, "DO_SET_MODE")
            else:
                result = REFUSED
                self._why = NO_CUSTOM_FLAG
        elif cmd in _MODE_COMMANDS:
            request, mode = _MODE_COMMANDS[cmd]
            extra = {"mode": mode_name(mode), "custom_mode": mode}
            result, out = self._set_mode(mode, now, command_name(cmd)[8:])
            if cmd == mav.MAV_CMD_MISSION_START and result == mav.MAV_RESULT_ACCEPTED \
                    and not self._auto.running:
                self._auto.start_or_resume(now)
        elif cmd == mav.MAV_CMD_NAV_TAKEOFF:
            request, extra = "takeoff", {"alt": p[6]}
            result = self._takeoff(p[6], now)
        elif cmd in _STREAM_COMMANDS:
            result, out, request = self._stream_command(msg, cmd, p, now)
        elif cmd == mav.MAV_CMD_DO_REPOSITION:
            request = "reposition"
            result, out = self._cmd_reposition(msg, p, now)
        elif cmd == mav.MAV_CMD_CONDITION_YAW:
            request, result = "yaw", self._cmd_condition_yaw(p)
        elif cmd == mav.MAV_CMD_DO_CHANGE_SPEED:
            request, result = "speed", self._cmd_change_speed(p)
        else:
            result = mav.MAV_RESULT_UNSUPPORTED
            self._why = f"{command_name(cmd)} is not a command this vehicle handles"
        self._command_request(now, msg, request, cmd, result, out, **extra)
        self.record(now, "command", command=cmd, name=command_name(cmd), params=p, result=result,
                    srcsys=msg.get_srcSystem())
        return [*out, self._ack(msg, cmd, result)]

    def _stream_command(self, msg: MAVLinkMessage, cmd: int, p: tuple[float, ...],
                        now: float) -> tuple[int, list[MAVLinkMessage], str]:
        """REQUEST_MESSAGE, REQUEST_AUTOPILOT_CAPABILITIES, GET_HOME_POSITION and
        SET/GET_MESSAGE_INTERVAL, as ``GCS_MAVLINK``'s handlers answer them."""
        wanted = int(p[0]) if math.isfinite(p[0]) and 0 <= p[0] < 2 ** 24 else -1
        if cmd == mav.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
            if p[0] != 1.0:
                self._why = f"param1 {p[0]:g} is not 1"
                return mav.MAV_RESULT_FAILED, [], "message"
            wanted = mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION
        elif cmd == mav.MAV_CMD_GET_HOME_POSITION:
            if not self.home_set:
                self._why = "home is not set (no GPS fix yet)"
                return mav.MAV_RESULT_FAILED, [], "message"
            wanted = mav.MAVLINK_MSG_ID_HOME_POSITION
        elif cmd == mav.MAV_CMD_SET_MESSAGE_INTERVAL:
            result, self._why = self.streams.set_interval(wanted, p[1], now)
            return result, [], "message_interval"
        if not self.streams.known(wanted):
            self._why = f"{message_name(wanted)} is not a message the vehicle sends"
            return mav.MAV_RESULT_FAILED, [], "message"
        if cmd == mav.MAV_CMD_GET_MESSAGE_INTERVAL:
            return mav.MAV_RESULT_ACCEPTED, [mav.MAVLink_message_interval_message(
                wanted, self.streams.interval_us(wanted))], "message_interval"
        reply = self.message(wanted, now)  # ArduPilot accepts, and may have nothing to send
        return mav.MAV_RESULT_ACCEPTED, [reply] if reply is not None else [], "message"

    def _command_request(self, now: float, msg: MAVLinkMessage, request: str,
                         command: int | None, result: int, out: list[MAVLinkMessage],
                         **extra: Any) -> Event:
        """Record a command or SET_MODE with its MAV_RESULT; a refusal's reason is its
        STATUSTEXT (as the autopilot says it) and what the model noted."""
        why, self._why = self._why, ""
        accepted = result == mav.MAV_RESULT_ACCEPTED
        if not accepted:
            text = next((str(m.text) for m in out if m.get_type() == "STATUSTEXT"), "")
            why = f"{text}: {why}" if text and why else (text or why)
        return self._request(now, msg, request, accepted, why, result_text(result),
                             command=command, mav_result=result, **extra)

    def _request(self, now: float, msg: MAVLinkMessage, request: str, accepted: bool,
                 reason: str | None, answer: str, *, command: int | None = None,
                 mav_result: int | None = None, **extra: Any) -> Event:
        """Record what the peer asked for and the answer it got (``records.REQUESTS``)."""
        return self.record(
            now, "request", request=request, result=ACCEPTED_RESULT if accepted else DENIED_RESULT,
            reason=None if accepted else (reason or answer), via=msg.get_type(), command=command,
            name=command_name(command) if command is not None else msg.get_type(),
            mav_result=mav_result, answer=answer, srcsys=msg.get_srcSystem(),
            srccomp=msg.get_srcComponent(), conn=self._conn, **extra)

    def _arm_disarm(self, p1: float, p2: float, now: float) -> tuple[int, list[MAVLinkMessage]]:
        if p1 == 1.0:
            if self.armed:
                return mav.MAV_RESULT_ACCEPTED, []
            if p2 != FORCE_ARM_MAGIC:
                if not self.has_fix(now):
                    return REFUSED, [_statustext(mav.MAV_SEVERITY_CRITICAL, "PreArm: Need 3D Fix")]
                if self.custom_mode in NO_ARM_MODES:
                    return REFUSED, [_statustext(mav.MAV_SEVERITY_CRITICAL,
                                                 "Arm: Mode not armable")]
            self.armed = True
            self.record(now, "arm", mode=self.mode, forced=p2 == FORCE_ARM_MAGIC)
            return mav.MAV_RESULT_ACCEPTED, []
        if p1 == 0.0:
            if not self.armed:
                return mav.MAV_RESULT_ACCEPTED, []
            if self.altitude > 0.0 and p2 != FORCE_DISARM_MAGIC:
                self._why = "Disarm: flying (needs the force value in param2)"
                return REFUSED, []
            self._disarm(now, "command")
            return mav.MAV_RESULT_ACCEPTED, []
        self._why = f"param1 {p1:g} is neither 1 (arm) nor 0 (disarm)"
        return REFUSED, []

    def _disarm(self, now: float, reason: str) -> None:
        self.armed = False
        self.altitude = 0.0
        self._target_alt = None
        self._target_pos = None
        self._guided_vel = None
        self.taking_off = False
        self.record(now, "disarm", reason=reason, mode=self.mode)

    def _set_mode(self, custom: int, now: float, via: str) -> tuple[int, list[MAVLinkMessage]]:
        known = custom in COPTER_MODE_NAMES
        ok = known and (custom not in POSITION_MODES or self.has_fix(now))
        refusal = "Flight mode change failed"
        if not known:
            self._why = f"unknown mode {custom}"
        elif not ok:
            self._why = f"{mode_name(custom)} needs a position (no GPS fix)"
        elif custom == AUTO and custom != self.custom_mode:
            refusal, self._why = self._auto.refusal() or ("", "")
            ok = not refusal
        if custom == RTL:
            self.rtl_commanded = True
            self.record(now, "rtl", via=via, accepted=ok)
        if not ok:
            return REFUSED, [_statustext(mav.MAV_SEVERITY_WARNING, refusal)]
        if custom == AUTO and self.custom_mode != AUTO:
            self._auto.start_or_resume(now)
        elif custom != AUTO:
            self._auto.stop()
        if custom != self.custom_mode:
            previous = self.mode
            self.custom_mode = custom
            self.record(now, "mode", mode=self.mode, custom_mode=custom, previous=previous,
                        via=via)
        return mav.MAV_RESULT_ACCEPTED, []

    def _takeoff(self, alt: float, now: float) -> int:
        checks = (
            (self.armed, "Takeoff: not armed"),
            (self.custom_mode == GUIDED, f"Takeoff: mode {self.mode} is not GUIDED"),
            (self.altitude <= 0.0 and self._target_alt is None, "Takeoff: already flying"),
            (math.isfinite(alt) and alt > 0, f"Takeoff: bad altitude {alt}"),
        )
        failed = [why for passed, why in checks if not passed]
        ok = not failed
        self._why = failed[0] if failed else ""
        self.record(now, "takeoff", alt=alt, accepted=ok)
        if ok:
            self._target_alt = alt
            self.taking_off = True
        return mav.MAV_RESULT_ACCEPTED if ok else REFUSED


def _int(value: float) -> int:
    """``int(value)``, or -1 for NaN/inf (a hostile parameter never raises)."""
    return int(value) if math.isfinite(value) and abs(value) < 2 ** 31 else -1


def result_text(result: int) -> str:
    """``MAV_RESULT`` name of ``result`` (e.g. ``"MAV_RESULT_FAILED"``)."""
    entry = mav.enums["MAV_RESULT"].get(result)
    return entry.name if entry is not None else str(result)


def _statustext(severity: int, text: str) -> MAVLinkMessage:
    return mav.MAVLink_statustext_message(severity, text.encode("ascii")[:50])



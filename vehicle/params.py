"""ArduCopter's parameters as the parameter protocol serves them, and MAVFTP refused at once.

The table is a sensible subset of ArduCopter 4.5's, with ArduPilot's names, storage types and
defaults (``ArduCopter/Parameters.cpp`` and the libraries' ``var_info`` tables: SYSID_THISMAV
is an ``AP_Int16``, RTL_ALT an ``AP_Int32`` in cm, WPNAV_SPEED an ``AP_Float`` in cm/s ...).
The values are stored and served; GUID_TIMEOUT is the only one the model flies by
(``vehicle.guided``).

The protocol, as ``libraries/GCS_MAVLink/GCS_Param.cpp`` answers it (and mavlink.io's
"Parameter Protocol" page describes it):

* PARAM_REQUEST_LIST: every parameter as PARAM_VALUE, index 0..count-1, after the banner
  STATUSTEXTs ArduPilot sends first (``send_banner``); the server paces them on the link
  (``vehicle.server``: PARAM_BATCH every PARAM_PERIOD, as ``queued_param_send`` does).
* PARAM_REQUEST_READ: by ``param_index`` unless it is -1, else by name; an index out of range
  or an unknown name gets no answer. The reply carries the request's index (-1 reads as
  65535 in the unsigned field, as ArduPilot sends it).
* PARAM_SET: the name is cut at 16 characters or the first NUL and looked up; an unknown
  name, or a NaN/inf value, is ignored (no PARAM_VALUE), so a name that is not ASCII is never
  stored. A known name is set as ``AP_Param::set_float`` sets it (integers: value + 0.01 away
  from zero, clamped to the type's range, truncated) and answered with its PARAM_VALUE
  (index 65535, as ``GCS::send_parameter_value`` sends it).
* PARAM_VALUE carries the value as a float: an integer parameter is cast to float (ArduPilot
  advertises MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_C_CAST; it does not byte-pack), with the
  ``MAV_PARAM_TYPE`` of its storage type (``GCS_MAVLINK::mav_param_type``).

MAVFTP (FILE_TRANSFER_PROTOCOL, mavlink.io "File Transfer Protocol"): the vehicle keeps no
files, so every request is answered at once with a NAK (ResetSessions with an ACK), and a
client such as MAVProxy, which first asks for ``@PARAM/param.pck``, falls back to
PARAM_REQUEST_LIST instead of waiting for its timeout. ArduPilot serves that file; here it
is "not found". The vehicle does not advertise MAV_PROTOCOL_CAPABILITY_FTP.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from pymavlink.dialects.v20 import ardupilotmega as mav

from .codec import MAVLinkMessage

if TYPE_CHECKING:
    from .records import Event

INT8, INT16, INT32, REAL32 = (mav.MAV_PARAM_TYPE_INT8, mav.MAV_PARAM_TYPE_INT16,
                              mav.MAV_PARAM_TYPE_INT32, mav.MAV_PARAM_TYPE_REAL32)
#: The range of each integer storage type (``AP_Param::set_float`` clamps to it).
_RANGES = {INT8: (-128, 127), INT16: (-32768, 32767), INT32: (-2147483648, 2147483647)}
#: ArduPilot's longest parameter name (AP_MAX_NAME_SIZE).
MAX_NAME = 16
#: PARAM_VALUE.param_index of an answer to a set or a by-name read (-1 as uint16).
NO_INDEX = 65535


@dataclass(frozen=True)
class ParamSpec:
    name: str
    type: int
    default: float


def copter_parameters(sysid: int) -> tuple[ParamSpec, ...]:
    """The served subset of ArduCopter 4.5's table (name, MAV_PARAM_TYPE, default)."""
    table = (
        ("FORMAT_VERSION", INT16, 120), ("SYSID_THISMAV", INT16, sysid),
        ("SYSID_MYGCS", INT16, 255), ("PILOT_TKOFF_ALT", REAL32, 0.0),
        ("PILOT_SPEED_UP", INT16, 250), ("RTL_ALT", INT32, 1500), ("RTL_SPEED", INT16, 0),
        ("RTL_LOIT_TIME", INT32, 5000), ("LAND_SPEED", INT16, 50), ("ANGLE_MAX", INT16, 3000),
        ("FRAME_CLASS", INT8, 1), ("FRAME_TYPE", INT8, 1), ("ARMING_CHECK", INT32, 1),
        ("DISARM_DELAY", INT8, 10), ("FENCE_ENABLE", INT8, 0), ("FS_THR_ENABLE", INT8, 1),
        ("FS_GCS_ENABLE", INT8, 0), ("GUID_TIMEOUT", REAL32, 3.0), ("WP_YAW_BEHAVIOR", INT8, 2),
        ("WPNAV_SPEED", REAL32, 500.0), ("WPNAV_RADIUS", REAL32, 200.0),
        ("WPNAV_SPEED_UP", REAL32, 250.0), ("WPNAV_SPEED_DN", REAL32, 150.0),
        ("LOIT_SPEED", REAL32, 1250.0), ("GPS_TYPE", INT8, 1), ("AHRS_EKF_TYPE", INT8, 3),
        ("EK3_ENABLE", INT8, 1), ("BATT_MONITOR", INT8, 4), ("BATT_CAPACITY", INT32, 3300),
        ("SERIAL0_BAUD", INT32, 115), ("SERIAL0_PROTOCOL", INT8, 2),
        ("LOG_BITMASK", INT32, 176126),
    )
    return tuple(ParamSpec(n, t, float(d)) for n, t, d in table)


def param_name(raw: Any) -> str | None:
    """The parameter name in a received ``param_id`` (str or bytes), cut at the first NUL and
    at 16 characters as ArduPilot cuts it; None unless it is printable ASCII."""
    if isinstance(raw, (bytes, bytearray)):
        try:
            raw = bytes(raw).decode("ascii")
        except UnicodeDecodeError:
            return None
    if not isinstance(raw, str):
        return None
    name = raw.split("\0", 1)[0][:MAX_NAME]
    if not name or not all(33 <= ord(c) < 127 for c in name):
        return None
    return name


class ParamTable:
    """The parameters' values, in their table order (the PARAM_VALUE index)."""

    def __init__(self, specs: Iterable[ParamSpec]) -> None:
        self._specs = {s.name: s for s in specs}
        self._names = list(self._specs)
        self._values = {s.name: s.default for s in self._specs.values()}

    def __len__(self) -> int:
        return len(self._names)

    def __contains__(self, name: object) -> bool:
        return name in self._specs

    def __getitem__(self, name: str) -> float:
        return self._values[name]

    def names(self) -> list[str]:
        return list(self._names)

    def as_dict(self) -> dict[str, float]:
        return dict(self._values)

    def type_of(self, name: str) -> int:
        return self._specs[name].type

    def set(self, name: str, value: float) -> float | None:
        """Store ``value`` as ``AP_Param::set_float`` does; the stored value, or None when
        ignored (unknown name, NaN or inf)."""
        if name not in self._specs or not math.isfinite(value):
            return None
        ptype = self._specs[name].type
        if ptype in _RANGES:
            lo, hi = _RANGES[ptype]
            value = float(int(min(max(value + math.copysign(0.01, value), lo), hi)))
        else:
            value = struct.unpack("<f", struct.pack("<f", value))[0]  # an AP_Float is 32-bit
        self._values[name] = value
        return value

    def value_message(self, name: str, index: int) -> MAVLinkMessage:
        """PARAM_VALUE for ``name``: the value cast to float, its MAV_PARAM_TYPE."""
        return mav.MAVLink_param_value_message(
            name.encode("ascii"), self._values[name], self._specs[name].type, len(self._names),
            index)


class ParamMessages:
    """The parameter protocol and MAVFTP handlers of ``VehicleModel`` (a mixin)."""

    params: ParamTable
    _conn: int

    if TYPE_CHECKING:
        def _request(self, now: float, msg: MAVLinkMessage, request: str, accepted: bool,
                     reason: str | None, answer: str, *, command: int | None = None,
                     mav_result: int | None = None, **extra: Any) -> Event: ...

        def banner(self) -> list[MAVLinkMessage]: ...

    def _on_param_request_list(self, msg: MAVLinkMessage, f: dict[str, Any],
                               now: float) -> Iterable:
        names = self.params.names()
        self._request(now, msg, "param_list", True, None, f"PARAM_VALUE x{len(names)}")
        return [*self.banner(), *(self.params.value_message(n, i) for i, n in enumerate(names))]

    def _on_param_request_read(self, msg: MAVLinkMessage, f: dict[str, Any],
                               now: float) -> Iterable:
        index = int(f.get("param_index", -1))
        names = self.params.names()
        if index != -1:
            name = names[index] if 0 <= index < len(names) else None
            why = f"no parameter at index {index} (count {len(names)})"
        else:
            name = param_name(f.get("param_id"))
            why = f"unknown parameter {_shown(f.get('param_id'))}"
            if name not in self.params:
                name = None
        if name is None:
            self._request(now, msg, "param_read", False, why + ": no answer, as ArduPilot",
                          "none", param=_shown(f.get("param_id")), index=index)
            return []
        self._request(now, msg, "param_read", True, None, f"PARAM_VALUE {name}",
                      param=name, index=index)
        return [self.params.value_message(name, index & 0xFFFF)]

    def _on_param_set(self, msg: MAVLinkMessage, f: dict[str, Any], now: float) -> Iterable:
        raw, value = f.get("param_id"), float(f.get("param_value", math.nan))
        name = param_name(raw)
        if name is None or name not in self.params:
            self._request(now, msg, "param_set", False,
                          f"unknown parameter {_shown(raw)}: ignored (no PARAM_VALUE), "
                          "as ArduPilot",
                          "none", param=_shown(raw), value=value)
            return []
        stored = self.params.set(name, value)
        if stored is None:
            self._request(now, msg, "param_set", False,
                          f"{name}: value {value} is not finite: ignored (no PARAM_VALUE)",
                          "none", param=name, value=value)
            return []
        self._request(now, msg, "param_set", True, None, f"PARAM_VALUE {name}={stored:g}",
                      param=name, value=value)
        return [self.params.value_message(name, NO_INDEX)]

    def _on_file_transfer_protocol(self, msg: MAVLinkMessage, f: dict[str, Any],
                                   now: float) -> Iterable:
        payload = bytes(f.get("payload") or b"")
        reply, answer = ftp_reply(payload)
        if reply is None:
            self._request(now, msg, "ftp", False, answer, "none")
            return []
        ok = answer.startswith("ACK")
        self._request(now, msg, "ftp", ok, None if ok else "the vehicle keeps no files",
                      "FILE_TRANSFER_PROTOCOL " + answer,
                      opcode=payload[3] if len(payload) > 3 else None)
        return [mav.MAVLink_file_transfer_protocol_message(
            0, msg.get_srcSystem(), msg.get_srcComponent(), reply)]


# ---------------------------------------------------------------------- MAVFTP
#: MAVFTP opcodes and NAK error codes (mavlink.io "File Transfer Protocol"; pymavlink's
#: dialect has no enum for them).
FTP_RESET_SESSIONS, FTP_ACK, FTP_NAK = 2, 128, 129
FTP_ERRORS = {1: "Fail", 4: "InvalidSession", 7: "UnknownCommand", 10: "FileNotFound"}
#: Opcodes that name a file or directory (answered FileNotFound), and those that use a
#: session (InvalidSession: none is ever open); other known opcodes fail.
_FTP_NAMED = frozenset({3, 4, 6, 8, 9, 10, 11, 12, 13, 14, 16})
_FTP_SESSION = frozenset({1, 5, 7, 15})
_FTP_KNOWN = frozenset(range(0, 17))
#: seq, session, opcode, size, req_opcode, burst_complete, padding, offset
FTP_HEADER = struct.Struct("<HBBBBBBI")


def ftp_reply(payload: bytes) -> tuple[bytes | None, str]:
    """The 251-byte FTP reply to a request ``payload`` and how it reads ("NAK
    FileNotFound"); (None, why) when the payload is too short to answer."""
    if len(payload) < FTP_HEADER.size:
        return None, f"FILE_TRANSFER_PROTOCOL payload of {len(payload)} bytes: no header"
    seq, session, opcode, _size, _req, _burst, _pad, offset = FTP_HEADER.unpack_from(payload)
    if opcode == FTP_RESET_SESSIONS:
        head, data, answer = FTP_ACK, b"", "ACK ResetSessions"
    else:
        code = 10 if opcode in _FTP_NAMED else 4 if opcode in _FTP_SESSION else (
            1 if opcode in _FTP_KNOWN else 7)
        head, data, answer = FTP_NAK, bytes([code]), "NAK " + FTP_ERRORS[code]
    body = FTP_HEADER.pack((seq + 1) & 0xFFFF, session, head, len(data), opcode, 0, 0, offset)
    return (body + data).ljust(251, b"\0"), answer


def _shown(raw: Any) -> str:
    """A received param_id for the record: ASCII-safe, at most 32 characters, quoted."""
    if isinstance(raw, (bytes, bytearray)):
        raw = bytes(raw).decode("ascii", "backslashreplace")
    return repr(str(raw)[:32].encode("ascii", "backslashreplace").decode("ascii"))

"""``--record FILE``: one JSON line per request the peer made, with the vehicle's answer.

Each line is a ``request`` event of the model, its detail as ``vehicle.records`` documents
it, plus ``t`` (seconds since the vehicle started): ``request`` (arm, disarm, mode, rtl,
takeoff, mission_start, command, message, message_interval, data_stream, reposition, yaw,
speed, position_target, param_list, param_read, param_set, ftp, mission_upload,
mission_item, ...: ``records.REQUESTS``), ``result``
("accepted" or "denied"), ``reason`` ("PreArm: Need 3D Fix", "latitude 357713312 is not in
degrees (-90..90); a degE7 value sent as degrees?", ...), ``answer`` (``MAV_RESULT_FAILED``,
``MISSION_ACK MAV_MISSION_INVALID_PARAM5_X``, ``MISSION_REQUEST seq=1``, ...), ``via`` (the
MAVLink message), ``command``/``name``, ``mav_result``, the sender (``srcsys``, ``srccomp``,
``conn``) and what the request named (``mode``, ``alt``, ``params``, ``seq``, ``x``/``y``/``z``
...). Lines are flushed as written, so the file is complete up to the last request even if
the vehicle is killed.
"""

from __future__ import annotations

import json
import math
import threading
from typing import IO, Any

from .records import Event

#: The event kind written to the record file.
REQUEST_KIND = "request"


def _plain(value: Any) -> Any:
    """JSON-safe copy (non-finite floats become strings, bytes become text)."""
    if isinstance(value, float) and not math.isfinite(value):
        return str(value)
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).split(b"\0", 1)[0].decode("ascii", "replace")
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    return value


def request_line(event: Event, t0: float) -> str:
    """The JSON line for a ``request`` event (time relative to ``t0``)."""
    return json.dumps({"t": round(event.t - t0, 6), **_plain(event.detail)}, sort_keys=False)


class RecordFile:
    """Appends request events to an open text file, one JSON object per line."""

    def __init__(self, stream: IO[str], t0: float) -> None:
        self._stream = stream
        self._t0 = t0
        self._lock = threading.Lock()
        self.written = 0

    def __call__(self, event: Event) -> None:
        if event.kind != REQUEST_KIND:
            return
        line = request_line(event, self._t0)
        with self._lock:
            self._stream.write(line + "\n")
            self._stream.flush()
            self.written += 1


def read_records(path: str) -> list[dict[str, Any]]:
    """The records of a ``--record`` file (for tests and tools)."""
    with open(path, encoding="utf-8") as f:
        return [json.loads(line) for line in f if line.strip()]

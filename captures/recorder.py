"""MCAP recording of a run (DESIGN.md "Captures").

One file per run, four channels, every message JSON (schema encoding ``jsonschema``):

- ``/mcp/tx`` and ``/mcp/rx``: each datagram the runner sent or received, decoded through
  ``spec.codec`` where it decodes (dst, src, seq, action name, a payload summary), else the
  ``DecodeError``'s rule and reason (and the header, when a whole one is there), plus the
  raw bytes as base64 and hex and the peer address;
- ``/mavlink``: frames on the vehicle link (direction, message type, raw base64);
- ``/conformance/case``: case start and end marks, the end with its outcome.

``log_time`` is the run clock (``time.time_ns()``) given by the caller, so a case's
``capture`` range in the JSON report finds its traffic. The recorder is thread-safe (the
driver's receiver thread calls it) and ``close()`` is idempotent; it is also called at
interpreter exit, so a run interrupted by an exception or SIGTERM leaves a valid file.
"""

from __future__ import annotations

import atexit
import base64
import json
import threading
import time
import weakref
from pathlib import Path
from typing import IO, Any

from mcap.writer import CompressionType, Writer

from spec.codec import Action, DecodeError, MissionItem, decode, peek_header

__all__ = ["CHANNELS", "McapRecorder", "RecorderError", "summarize_payload"]

PROFILE = "mcp-conform"
_STR = {"type": "string"}
_INT = {"type": "integer"}
_NULLABLE_INT = {"type": ["integer", "null"]}

_DATAGRAM_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "mcp.Datagram",
    "description": "One MCP datagram as the runner sent or received it.",
    "type": "object",
    "properties": {
        "direction": {"enum": ["tx", "rx"]},
        "peer": _STR,
        "length": _INT,
        "decoded": {"type": "boolean"},
        "dst": _NULLABLE_INT,
        "src": _NULLABLE_INT,
        "seq": _NULLABLE_INT,
        "action": _NULLABLE_INT,
        "action_name": {"type": ["string", "null"]},
        "payload": {},
        "error_rule": {"type": ["string", "null"]},
        "error_reason": {"type": ["string", "null"]},
        "raw_base64": _STR,
        "raw_hex": _STR,
    },
    "required": ["direction", "peer", "length", "decoded", "raw_base64", "raw_hex"],
}
_MAVLINK_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "mcp.MavlinkFrame",
    "description": "One MAVLink frame on the vehicle link.",
    "type": "object",
    "properties": {
        "direction": _STR,
        "msg_type": {"type": ["string", "null"]},
        "length": _INT,
        "raw_base64": _STR,
    },
    "required": ["direction", "length", "raw_base64"],
}
_CASE_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "mcp.CaseMark",
    "description": "The start or end of a conformance case.",
    "type": "object",
    "properties": {
        "case": _STR,
        "event": {"enum": ["start", "end"]},
        "outcome": {"type": ["string", "null"]},
        "rules": {"type": "array", "items": _STR},
    },
    "required": ["case", "event", "rules"],
}

#: topic -> (schema name, JSON schema)
CHANNELS: dict[str, tuple[str, dict[str, Any]]] = {
    "/mcp/tx": ("mcp.Datagram", _DATAGRAM_SCHEMA),
    "/mcp/rx": ("mcp.Datagram", _DATAGRAM_SCHEMA),
    "/mavlink": ("mcp.MavlinkFrame", _MAVLINK_SCHEMA),
    "/conformance/case": ("mcp.CaseMark", _CASE_SCHEMA),
}
_MAX_ITEMS = 16  # payload summary: mission items listed in full up to this many


class RecorderError(Exception):
    """The capture file cannot be written (one line, names the file)."""


def _item(item: MissionItem) -> dict[str, Any]:
    return {k: (round(v, 7) if isinstance(v, float) else v) for k, v in item._asdict().items()}


def summarize_payload(payload: Any) -> Any:
    """A JSON-able summary of a decoded payload (see ``spec.codec.Message``)."""
    if payload is None or isinstance(payload, (int, str)):
        return payload
    if isinstance(payload, (bytes, bytearray)):
        return {"mavlink_frame_len": len(payload), "hex": bytes(payload).hex()}
    if isinstance(payload, MissionItem):
        return _item(payload)
    if isinstance(payload, (tuple, list)):
        items = [_item(i) if isinstance(i, MissionItem) else repr(i) for i in payload[:_MAX_ITEMS]]
        return {"count": len(payload), "items": items}
    return repr(payload)


def _action_name(code: int | None) -> str | None:
    if code is None:
        return None
    try:
        return Action(code).name
    except ValueError:
        return None


def _peer(addr: Any) -> str:
    if isinstance(addr, (tuple, list)) and len(addr) >= 2:
        return f"{addr[0]}:{addr[1]}"
    return "" if addr is None else str(addr)


def datagram_record(direction: str, data: bytes, addr: Any) -> dict[str, Any]:
    """The JSON body of one ``/mcp/tx`` or ``/mcp/rx`` message."""
    data = bytes(data)
    rec: dict[str, Any] = {
        "direction": direction, "peer": _peer(addr), "length": len(data), "decoded": False,
        "dst": None, "src": None, "seq": None, "action": None, "action_name": None,
        "payload": None, "error_rule": None, "error_reason": None,
    }
    try:
        msg = decode(data)
    except DecodeError as exc:
        rec["error_rule"], rec["error_reason"] = exc.rule, exc.reason
        header = peek_header(data)
        if header is not None:
            rec["dst"], rec["src"], rec["seq"], rec["action"] = header
            rec["action_name"] = _action_name(header[3])
    except Exception as exc:  # a codec bug must not lose the datagram
        rec["error_rule"], rec["error_reason"] = None, f"{type(exc).__name__}: {exc}"
    else:
        rec.update(decoded=True, dst=msg.dst, src=msg.src, seq=msg.seq, action=int(msg.action),
                   action_name=_action_name(int(msg.action)), payload=summarize_payload(msg.payload))
    rec["raw_base64"] = base64.b64encode(data).decode("ascii")
    rec["raw_hex"] = data.hex()
    return rec


class McapRecorder:
    """Writes one MCAP file; every method may be called from any thread."""

    def __init__(self, path: str | Path, *, library: str = "mcp-conform") -> None:
        self.path = Path(path)
        self._lock = threading.Lock()
        self._closed = False
        self.counts: dict[str, int] = {topic: 0 for topic in CHANNELS}
        try:
            self._file: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as exc:
            raise RecorderError(f"--capture: cannot write {str(self.path)!r}: {exc.strerror}") from None
        try:
            compression = CompressionType.LZ4
            import lz4  # noqa: F401
        except ImportError:
            compression = CompressionType.NONE
        self._writer = Writer(self._file, compression=compression, chunk_size=256 * 1024)
        self._writer.start(profile=PROFILE, library=library)
        self._channels: dict[str, int] = {}
        schemas: dict[str, int] = {}
        for topic, (name, schema) in CHANNELS.items():
            if name not in schemas:
                schemas[name] = self._writer.register_schema(
                    name=name, encoding="jsonschema", data=json.dumps(schema).encode())
            self._channels[topic] = self._writer.register_channel(
                topic=topic, message_encoding="json", schema_id=schemas[name])
        self._seq = 0
        _LIVE.add(self)

    # ------------------------------------------------------------------ writing
    @property
    def closed(self) -> bool:
        return self._closed

    def _write(self, topic: str, body: dict[str, Any], t_ns: int | None) -> None:
        data = json.dumps(body, separators=(",", ":")).encode()
        t = int(t_ns) if t_ns is not None else time.time_ns()
        with self._lock:
            if self._closed:
                return
            self._seq += 1
            self._writer.add_message(channel_id=self._channels[topic], log_time=t, data=data,
                                     publish_time=t, sequence=self._seq)
            self.counts[topic] += 1

    def datagram(self, direction: str, data: bytes, addr: Any, t_ns: int | None = None) -> None:
        """One datagram: ``direction`` is ``tx`` (the runner sent it) or ``rx``."""
        if direction not in ("tx", "rx"):
            raise ValueError(f"datagram direction must be 'tx' or 'rx', not {direction!r}")
        self._write(f"/mcp/{direction}", datagram_record(direction, data, addr), t_ns)

    def mavlink(self, direction: str, frame: bytes, t_ns: int | None = None,
                msg_type: str | None = None) -> None:
        """One frame on the vehicle link (``direction`` e.g. ``rx`` = received by the vehicle)."""
        raw = bytes(frame)
        body = {"direction": direction, "msg_type": msg_type, "length": len(raw),
                "raw_base64": base64.b64encode(raw).decode("ascii")}
        self._write("/mavlink", body, t_ns)

    def case_mark(self, case_id: str, event: str, t_ns: int | None = None,
                  outcome: str | None = None, rules: tuple[str, ...] | list[str] = ()) -> None:
        """A case's ``start`` or ``end`` (the end carries the outcome)."""
        if event not in ("start", "end"):
            raise ValueError(f"case_mark event must be 'start' or 'end', not {event!r}")
        body = {"case": case_id, "event": event, "outcome": outcome, "rules": list(rules)}
        self._write("/conformance/case", body, t_ns)

    def close(self) -> None:
        """Write the summary and footer; safe to call more than once and from any thread."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            try:
                self._writer.finish()
            finally:
                self._file.close()
                _LIVE.discard(self)

    def __enter__(self) -> McapRecorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


_LIVE: weakref.WeakSet[McapRecorder] = weakref.WeakSet()


@atexit.register
def _close_all() -> None:
    """An interrupted run still leaves valid files."""
    for rec in list(_LIVE):
        try:
            rec.close()
        except Exception:  # noqa: BLE001 - best effort at exit
            pass

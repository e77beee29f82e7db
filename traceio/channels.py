"""The channels of an mcp-conform capture and their JSON schemas: the file format
``traceio.recorder`` writes and ``traceio.reader`` reads, written down (docs/design.md "Captures").

``CHANNELS``: every run's (``/mcp/tx``, ``/mcp/rx``, ``/mcp/burst`` for MCP-ROB-7's flood,
``/mavlink``, ``/conformance/case``, ``/impair``, ``/vehicle``); :func:`stream_channels`: a
stream protocol's, named after it (Nsqd: ``/nsqd/tx``, ``/nsqd/rx``, ``/nsqd/conn``), registered
with its first frame, and ``STREAM_CHANNELS`` those of every stream protocol in the profile table
(``spec.profiles``: framing ``stream``); :func:`foxglove_channels`: Foxglove's well-known ones where ``foxglove-sdk`` is installed.
``traceio.live`` serves the same channels to a Foxglove WebSocket client.
"""

from __future__ import annotations

from typing import Any, NamedTuple

from mcp_conform.spec.profiles import PROFILES, pick
from mcp_conform.traceio import fox

__all__ = ["CHANNELS", "HEX_LIMIT", "STREAM_CHANNELS", "StreamTopics", "foxglove_channels", "stream_channels",
           "stream_topics"]

_STR = {"type": "string"}
_B64 = {"type": "string", "contentEncoding": "base64"}
_ADDR = {"type": ["string", "null"], "description": "host:port"}
#: datagrams longer than this keep only base64 (a 65507-byte one would triple the file)
HEX_LIMIT = 4096
_INT = {"type": "integer"}
_NULLABLE_INT = {"type": ["integer", "null"]}

_DATAGRAM_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "mcp.Datagram",
    "description": "One MCP datagram as the recording endpoint sent (tx) or received (rx) it.",
    "type": "object",
    "properties": {
        "direction": {"enum": ["tx", "rx"]},
        "peer": _STR,
        "local": _ADDR,
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
        "raw_base64": _B64,
        "raw_hex": {"type": "string", "description": f"the raw bytes in hex, up to {HEX_LIMIT} bytes "
                                                     "(raw_base64 holds every datagram whole)"},
        "run_delay_ns": {"type": "integer", "minimum": 0,
                         "description": "the sender's cumulative run delay (ns: time runnable but "
                                        "waiting for a CPU) as the datagram came, when the recorder "
                                        "spawned it (MCP-RTX-3 excuses a late copy the host caused)"},
    },
    "required": ["direction", "peer", "length", "decoded", "raw_base64"],
}
_BURST_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "mcp.Burst",
    "description": "Datagrams sent as one burst (e.g. the MCP-ROB-7 flood), recorded as a count: "
                   "datagram i of the burst is cycle[i % len(cycle)].",
    "type": "object",
    "properties": {
        "direction": {"enum": ["tx", "rx"]},
        "peer": _STR,
        "local": _ADDR,
        "count": _INT,
        "first_t_ns": _INT,
        "last_t_ns": _INT,
        "cycle": {"type": "array", "items": _DATAGRAM_SCHEMA},
    },
    "required": ["direction", "peer", "count", "first_t_ns", "last_t_ns", "cycle"],
}
_MAVLINK_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "mcp.MavlinkFrame",
    "description": "One MAVLink frame on the autopilot link; direction from the autopilot's "
                   "point of view (rx: the autopilot received it, tx: the autopilot sent it).",
    "type": "object",
    "properties": {
        "direction": {"enum": ["tx", "rx"]},
        "msg_type": {"type": ["string", "null"]},
        "length": _INT,
        "drone": _NULLABLE_INT,
        "message": {"type": ["object", "null"],
                    "description": "the decoded message: pymavlink's to_dict() (ardupilotmega), "
                                   "NaN as null, byte arrays as hex"},
        "decode_error": {"type": ["string", "null"], "description": "why the frame did not decode"},
        "raw_base64": _B64,
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
        "evidence": {"type": ["string", "null"], "description": "why the case failed (end marks)"},
    },
    "required": ["case", "event", "rules"],
}

_IMPAIR_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "mcp.Impairment",
    "description": "What an impaired link (harness.impair) did to one datagram: dropped it (and "
                   "why), or delivered copies after a delay, perhaps reordered, corrupted or cut.",
    "type": "object",
    "properties": {
        "direction": _STR,
        "n": _INT,
        "size": _INT,
        "dropped": {"type": ["string", "null"]},
        "deliveries": {"type": "array", "items": {"type": "object", "properties": {
            "delay_ms": {"type": "number"}, "size": _INT,
            "kinds": {"type": "array", "items": _STR}}}},
        "raw_base64": _B64,
    },
    "required": ["direction", "n", "size", "deliveries", "raw_base64"],
}
_VEHICLE_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "mcp.VehicleEvent",
    "description": "An event of the simulated vehicle the run observed on the drone's autopilot "
                   "link (link connected, GPS fix gained or lost), as the run's monitor got it.",
    "type": "object",
    "properties": {"kind": _STR, "drone": _NULLABLE_INT, "detail": {"type": ["string", "null"]}},
    "required": ["kind"],
}

_STREAM_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "Frame",
    "description": "Bytes on a stream protocol's connection: tx what the runner "
                   "wrote in one write, rx one frame the backend sent (or the bytes its deframer "
                   "refused), decoded where they decode.",
    "type": "object",
    "properties": {
        "direction": {"enum": ["tx", "rx"]},
        "conn": _INT,
        "peer": _STR,
        "msg_id": _NULLABLE_INT,
        "name": {"type": ["string", "null"]},
        "fields": {"type": ["object", "null"]},
        "problem": {"type": ["string", "null"]},
        "length": _INT,
        "raw_base64": _B64,
    },
    "required": ["direction", "conn", "length", "raw_base64"],
}
_CONN_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "Connection",
    "description": "A stream protocol's connection opened by the runner, or closed by either side "
                   "(by: client or backend; how: fin or rst), with its addresses.",
    "type": "object",
    "properties": {
        "event": {"enum": ["open", "close"]},
        "conn": _INT,
        "peer": _STR,
        "local": _ADDR,
        "by": {"type": ["string", "null"]},
        "how": {"type": ["string", "null"]},
    },
    "required": ["event", "conn"],
}
class StreamTopics(NamedTuple):
    """A stream protocol's three topics: the runner's writes, the node's frames, the connections."""

    tx: str
    rx: str
    conn: str


def stream_topics(protocol: str) -> StreamTopics:
    """The topics of ``protocol``'s stream traffic, named after it (``/nsqd/tx``, ...). A
    protocol whose profile does not frame a stream is our own misuse: ValueError."""
    if pick(protocol)[0].framing != "stream":
        raise ValueError(f"--protocol {protocol} is not carried on a stream; it has no stream channels")
    return StreamTopics(f"/{protocol}/tx", f"/{protocol}/rx", f"/{protocol}/conn")


def stream_channels(protocol: str) -> dict[str, tuple[str, dict[str, Any]]]:
    """``protocol``'s stream channels, topic -> (schema name, JSON schema), registered when
    its first frame is recorded."""
    t = stream_topics(protocol)
    return {t.tx: (f"{protocol}.Frame", _STREAM_SCHEMA), t.rx: (f"{protocol}.Frame", _STREAM_SCHEMA),
            t.conn: (f"{protocol}.Connection", _CONN_SCHEMA)}


#: The stream channels of every stream protocol in the profile table.
STREAM_CHANNELS: dict[str, tuple[str, dict[str, Any]]] = {
    topic: value for p in PROFILES.values() if p.framing == "stream" for topic, value in stream_channels(p.name).items()}

#: topic -> (schema name, JSON schema)
CHANNELS: dict[str, tuple[str, dict[str, Any]]] = {
    "/mcp/tx": ("mcp.Datagram", _DATAGRAM_SCHEMA),
    "/mcp/rx": ("mcp.Datagram", _DATAGRAM_SCHEMA),
    "/mcp/burst": ("mcp.Burst", _BURST_SCHEMA),
    "/mavlink": ("mcp.MavlinkFrame", _MAVLINK_SCHEMA),
    "/conformance/case": ("mcp.CaseMark", _CASE_SCHEMA),
    "/impair": ("mcp.Impairment", _IMPAIR_SCHEMA),
    "/vehicle": ("mcp.VehicleEvent", _VEHICLE_SCHEMA),
}


def foxglove_channels() -> dict[str, tuple[str, dict[str, Any]]]:
    """Foxglove's well-known channels (topic -> (schema name, JSON schema from foxglove-sdk)),
    registered when foxglove-sdk is installed (else none: the capture is complete without)."""
    if not fox.available():
        return {}
    return {topic: (f"foxglove.{name}", fox.json_schema(name)) for topic, name in fox.FOXGLOVE_CHANNELS.items()}

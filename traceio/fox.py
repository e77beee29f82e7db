"""Foxglove's well-known messages in our captures (issue 24): what Foxglove draws without a plugin.

The recorder (:mod:`traceio.recorder`) adds three channels Foxglove's panels know by their
schema name:

- ``/vehicle/location`` (``foxglove.LocationFix``, the Map panel): the vehicle's position
  from each GLOBAL_POSITION_INT the autopilot sent (degrees and metres AMSL);
- ``/vehicle/attitude`` (``foxglove.PoseInFrame``): its attitude from each ATTITUDE, as a
  quaternion in the frame ``drone<N>``;
- ``/log`` (``foxglove.Log``, the Log panel): the runner's and the fuzzer's events and
  verdicts (case started; passed; failed with its rules and evidence).

The schemas are not written here: they are the ``foxglove-sdk`` package's own
(``foxglove.messages.<Name>.get_schema()``, a protobuf ``FileDescriptorSet`` read with
protobuf's ``descriptor_pb2``), turned into JSON Schema by :func:`json_schema` so every channel of a capture stays JSON (``mcp-capture``
reads JSON; Foxglove decodes its well-known schemas in JSON as in protobuf). The one
convention of Foxglove's JSON encoding applied: a ``google.protobuf.Timestamp`` is
``{"sec", "nsec"}``. Enums are their integer values.
"""

from __future__ import annotations

import json
import math
import threading
import warnings
from functools import cache
from typing import Any

__all__ = ["ATTITUDE", "FOXGLOVE_CHANNELS", "LOCATION", "LOG", "attitude_body", "available",
           "json_schema", "LAYOUT_FILE", "layout_json", "location_body", "log_body", "log_level", "mavlink_dict"]

LOCATION = "/vehicle/location"
ATTITUDE = "/vehicle/attitude"
LOG = "/log"
#: topic -> the foxglove message its messages are
FOXGLOVE_CHANNELS: dict[str, str] = {LOCATION: "LocationFix", ATTITUDE: "PoseInFrame", LOG: "Log"}
_LEVELS = ("debug", "info", "warning", "error", "fatal")


# ---------------------------------------------------------------- protobuf descriptors
@cache
def _descriptors(name: str) -> tuple[dict[str, list[tuple[str, int, int, str]]], dict[str, list[int]]]:
    """Messages (full name -> [(field, label, type, type name)]) and enums (full name ->
    values) of the SDK's ``foxglove.<name>`` schema, read with protobuf's own
    ``descriptor_pb2.FileDescriptorSet``."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import foxglove.messages as fm
        from google.protobuf import descriptor_pb2
    schema = getattr(fm, name).get_schema()
    if schema.encoding != "protobuf":
        raise ValueError(f"foxglove.{name}: schema encoding {schema.encoding!r}, expected protobuf")
    messages: dict[str, list[tuple[str, int, int, str]]] = {}
    enums: dict[str, list[int]] = {}

    def message(prefix: str, m: Any) -> None:
        mname = f"{prefix}.{m.name}" if prefix else m.name
        messages[mname] = [(f.name, f.label, f.type, f.type_name.lstrip(".")) for f in m.field]
        for sub in m.nested_type:
            message(mname, sub)
        for e in m.enum_type:
            enums[f"{mname}.{e.name}"] = [v.number for v in e.value]

    for file in descriptor_pb2.FileDescriptorSet.FromString(schema.data).file:
        for m in file.message_type:
            message(file.package, m)
        for e in file.enum_type:
            enums[f"{file.package}.{e.name}" if file.package else e.name] = [v.number for v in e.value]
    return messages, enums


_SCALAR = {1: {"type": "number"}, 2: {"type": "number"}, 3: {"type": "integer"}, 4: {"type": "integer"},
           5: {"type": "integer"}, 6: {"type": "integer"}, 7: {"type": "integer"}, 8: {"type": "boolean"},
           9: {"type": "string"}, 12: {"type": "string", "contentEncoding": "base64"},
           13: {"type": "integer"}, 15: {"type": "integer"}, 16: {"type": "integer"},
           17: {"type": "integer"}, 18: {"type": "integer"}}
_TIMESTAMP = {"type": "object", "properties": {"sec": {"type": "integer", "minimum": 0},
                                               "nsec": {"type": "integer", "minimum": 0, "maximum": 999_999_999}},
              "required": ["sec", "nsec"]}


@cache
def json_schema(name: str) -> dict[str, Any]:
    """The JSON Schema of ``foxglove.<name>``, derived from the SDK's protobuf descriptor."""
    messages, enums = _descriptors(name)

    def of(mname: str) -> dict[str, Any]:
        if mname in ("google.protobuf.Timestamp", "google.protobuf.Duration"):
            return dict(_TIMESTAMP)
        props: dict[str, Any] = {}
        for fname, label, ftype, tname in messages[mname]:
            if ftype == 11:
                sub = of(tname)
            elif ftype == 14:
                sub = {"type": "integer", "enum": enums[tname]}
            else:
                sub = dict(_SCALAR[ftype])
            props[fname] = {"type": "array", "items": sub} if label == 3 else sub
        return {"type": "object", "title": mname, "properties": props}

    schema = of(f"foxglove.{name}")
    return {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}


@cache
def available() -> bool:
    """Whether ``foxglove-sdk`` is installed (without it the channels are left out)."""
    try:
        json_schema("Log")
    except ImportError:
        return False
    return True


# ---------------------------------------------------------------- message bodies
def _stamp(t_ns: int) -> dict[str, int]:
    return {"sec": t_ns // 1_000_000_000, "nsec": t_ns % 1_000_000_000}


def _frame(drone: int | None) -> str:
    return "vehicle" if drone is None else f"drone{drone}"


def location_body(t_ns: int, msg: dict[str, Any], drone: int | None) -> dict[str, Any] | None:
    """A ``foxglove.LocationFix`` from a decoded GLOBAL_POSITION_INT (else None)."""
    if msg.get("mavpackettype") != "GLOBAL_POSITION_INT":
        return None
    lat, lon = msg.get("lat"), msg.get("lon")
    if not isinstance(lat, int) or not isinstance(lon, int) or (lat == 0 and lon == 0):
        return None  # no position yet
    return {"timestamp": _stamp(t_ns), "frame_id": _frame(drone), "latitude": lat / 1e7, "longitude": lon / 1e7,
            "altitude": float(msg.get("alt") or 0) / 1000.0, "position_covariance": [0.0] * 9,
            "position_covariance_type": 0}


def attitude_body(t_ns: int, msg: dict[str, Any], drone: int | None) -> dict[str, Any] | None:
    """A ``foxglove.PoseInFrame`` (orientation only) from a decoded ATTITUDE (else None)."""
    if msg.get("mavpackettype") != "ATTITUDE":
        return None
    try:
        r, p, y = (float(msg[k]) / 2 for k in ("roll", "pitch", "yaw"))
    except (KeyError, TypeError, ValueError):
        return None
    if not all(math.isfinite(v) for v in (r, p, y)):
        return None
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    q = {"x": sr * cp * cy - cr * sp * sy, "y": cr * sp * cy + sr * cp * sy,
         "z": cr * cp * sy - sr * sp * cy, "w": cr * cp * cy + sr * sp * sy}
    return {"timestamp": _stamp(t_ns), "frame_id": _frame(drone),
            "pose": {"position": {"x": 0.0, "y": 0.0, "z": 0.0}, "orientation": q}}


@cache
def log_level(level: str) -> int:
    """The value of ``foxglove.LogLevel`` ``level`` (debug, info, warning, error, fatal), the SDK's."""
    if level not in _LEVELS:
        raise ValueError(f"log level must be one of {', '.join(_LEVELS)}, not {level!r}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import foxglove.messages as fm
    return int(getattr(fm.LogLevel, level.capitalize()).value)


def log_body(t_ns: int, level: str, message: str, name: str) -> dict[str, Any]:
    """A ``foxglove.Log`` (``level``: debug, info, warning, error, fatal)."""
    return {"timestamp": _stamp(t_ns), "level": log_level(level), "message": message, "name": name,
            "file": "", "line": 0}


def _jsonable(value: Any) -> Any:
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, (bytes, bytearray)):
        return bytes(value).hex()
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    return value


class _Decoder:
    def __init__(self) -> None:
        from pymavlink.dialects.v20 import ardupilotmega as mavlink2

        from mcp_conform.spec.mavframe import robust_parser

        self.mav = robust_parser()
        self.error = mavlink2.MAVError


_DECODER: _Decoder | None = None
_DECODE_LOCK = threading.Lock()


def mavlink_dict(frame: bytes) -> tuple[dict[str, Any] | None, str | None]:
    """pymavlink's ``to_dict()`` of one frame (JSON-safe: NaN is null, bytes are hex), or
    (None, why) when it does not decode (bad CRC, unknown message, cut)."""
    global _DECODER
    with _DECODE_LOCK:
        if _DECODER is None:
            _DECODER = _Decoder()
        try:
            msg = _DECODER.mav.decode(bytearray(frame))
        except _DECODER.error as exc:
            return None, str(getattr(exc, "message", exc))
        except Exception as exc:  # noqa: BLE001 - a frame pymavlink chokes on is recorded as such
            return None, f"{type(exc).__name__}: {exc}"
    if msg is None or msg.get_type() == "BAD_DATA":
        return None, "not a MAVLink message"
    return _jsonable(msg.to_dict()), None


# ---------------------------------------------------------------- the example layout
LAYOUT_FILE = "examples/foxglove-layout.json"


def layout_json() -> str:
    """The Foxglove layout of ``examples/foxglove-layout.json``, built with the SDK's
    ``foxglove.layouts``: the Map (``/vehicle/location``) above the attitude plot (from
    ``/mavlink``'s decoded ATTITUDE); tabs of tables of the MCP datagrams (``/mcp/rx``,
    ``/mcp/tx``) and the decoded ``/mavlink`` frames; the Log panel (``/log``)."""
    import foxglove.layouts as fl

    attitude = '/mavlink{message.mavpackettype=="ATTITUDE"}.message.'
    left = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=2, content=fl.MapPanel(title="Vehicle", config=fl.MapConfig(
            follow_topic=LOCATION, layer="map", zoom_level=18))),
        fl.SplitItem(proportion=1, content=fl.PlotPanel(title="Attitude (rad)", config=fl.PlotConfig(
            paths=[fl.PlotSeries(value=attitude + axis, label=axis) for axis in ("roll", "pitch", "yaw")],
            show_legend=True))),
    ])
    tables = fl.TabContainer(tabs=[
        fl.TabItem(title="MCP received", content=fl.TablePanel(config=fl.TableConfig(topic_path="/mcp/rx"))),
        fl.TabItem(title="MCP sent", content=fl.TablePanel(config=fl.TableConfig(topic_path="/mcp/tx"))),
        fl.TabItem(title="MAVLink", content=fl.RawMessagesPanel(config=fl.RawMessagesConfig(
            topic_path="/mavlink.message"))),
    ])
    right = fl.SplitContainer(direction="column", items=[
        fl.SplitItem(proportion=1, content=tables),
        fl.SplitItem(proportion=1, content=fl.LogPanel(title="Cases and verdicts", config=fl.LogConfig(
            topic_to_render=LOG, show_level=True, show_name=True, show_time=True))),
    ])
    layout = fl.Layout(content=fl.SplitContainer(direction="row", items=[
        fl.SplitItem(proportion=1, content=left), fl.SplitItem(proportion=1, content=right)]))
    return json.dumps(json.loads(layout.to_json()), indent=2) + "\n"

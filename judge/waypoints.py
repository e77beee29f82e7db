"""MCP-FLOW-5's "every waypoint in a WP_On", one judge for the manager case
(``conformance/cases_manager/test_flow.py``) and the trace monitor (``mcp-conform`` live,
``mcp-capture check``): which of the mission's waypoints no WP_On to a drone carried.

Items are compared on what a QGC WPL 110 line holds (``FILE_FIELDS``; target_system and
target_component are not in the file, so a manager fills them as it likes), floats as the
wire's float32 (a NaN equal to a NaN).
"""

from __future__ import annotations

import math
import struct
from collections.abc import Iterable, Sequence
from typing import Any

__all__ = ["FILE_FIELDS", "f32", "waypoint_key", "waypoints_missed"]

#: Fields a QGC WPL 110 line holds (target_system/component are not in the file).
FILE_FIELDS = ("seq", "current", "frame", "command", "param1", "param2", "param3", "param4",
               "x", "y", "z", "autocontinue")
_F32 = struct.Struct("<f")
_NAN = ("nan",)


def f32(x: float) -> float:
    """``x`` as the wire's float32 carries it."""
    return float(_F32.unpack(_F32.pack(x))[0])


def waypoint_key(item: Any) -> tuple[Any, ...]:
    """A mission item by the fields its file line holds, floats as float32: two items with
    equal keys carry the same waypoint (-0.0 and 0.0 alike, a NaN like a NaN)."""
    out: list[Any] = []
    for name in FILE_FIELDS:
        v = getattr(item, name)
        if isinstance(v, float):
            v = f32(v)
            if math.isnan(v):
                v = _NAN
        out.append(v)
    return tuple(out)


def waypoints_missed(carried: Iterable[Any | None], want: Sequence[Any]) -> list[Any] | None:
    """MCP-FLOW-5: the waypoints of ``want`` (the file's, in order) that no item of ``carried``
    (what the WP_Ons to one drone carried, each decoded) carries. None when not judged: a WP_On
    whose item could not be decoded (None in ``carried``) carried a waypoint no one can read
    (MCP-PAY-5's fault: one fault, one rule)."""
    keys = set()
    for it in carried:
        if it is None:
            return None
        keys.add(waypoint_key(it))
    return [w for w in want if waypoint_key(w) not in keys]

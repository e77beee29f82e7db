"""Mission items, MAVLink MISSION_ITEM messages and QGC WPL 110 waypoint files, via pymavlink.

A mission item is "the MAVLink v1 MISSION_ITEM payload '<fffffffHHBBBBB': param1–4, x (lat),
y (lon), z (alt), seq, command, target_system, target_component, frame, current,
autocontinue" (MCP-PAY-4, errata E-1 and E-2). This module converts
:class:`spec.codec.MissionItem` to and from pymavlink's MISSION_ITEM message, loads and saves
waypoint files through pymavlink's ``mavwp.MAVWPLoader`` (the description's "Waypoint File
format", ``QGC WPL 110``), and checks items for MCP-PAY-7: "Mission items are sane: finite
floats, latitude in [-90, 90], longitude in [-180, 180], a MAV_CMD and a MAV_FRAME that
MAVLink defines."

Nothing here packs bytes by hand: the codec packs items from the spec's struct string, and
pymavlink owns the MAVLink message and the file format.
"""

from __future__ import annotations

import math
import stat
import struct
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from pymavlink import mavwp
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import (
    COUNT_SIZE,
    HEADER_SIZE,
    ITEM,
    ITEM_SIZE,
    MAX_DATAGRAM,
    MissionItem,
)

__all__ = [
    "MAX_FILE_BYTES",
    "MAX_LIST_ITEMS",
    "WAYPOINT_FILE_HEADER",
    "WaypointFileError",
    "from_mavlink",
    "known_command",
    "known_frame",
    "load_waypoints",
    "sane_item",
    "save_waypoints",
    "to_mavlink",
]

#: First line of a waypoint file, from the spec ("QGC WPL 110").
WAYPOINT_FILE_HEADER: str = SPEC.mission_item["waypoint_file"]
_MAVLINK_NAME: str = SPEC.mission_item["mavlink_message"]  # "MISSION_ITEM"
_FIELDS: tuple[str, ...] = tuple(MissionItem._fields)

# A QGC WPL 110 line: <INDEX> <CURRENT WP> <COORD FRAME> <COMMAND> <PARAM1> <PARAM2>
# <PARAM3> <PARAM4> <PARAM5/X> <PARAM6/Y> <PARAM7/Z> <AUTOCONTINUE> (the description's
# "Extracting WayPoint list"; X is the latitude, E-2). Integer columns and their limits.
_LINE_FIELDS = 12
#: The most items one WP_List or Obstacles_List datagram carries: the largest datagram less
#: the header and the count, in items (MCP-PAY-4's layout): 1,769.
MAX_LIST_ITEMS: int = (MAX_DATAGRAM - HEADER_SIZE - COUNT_SIZE) // ITEM_SIZE
#: The largest waypoint file read: room for that many lines of 12 generous columns. A longer
#: file (or /dev/zero) is refused before it is read, not read whole.
MAX_FILE_BYTES: int = 256 * (MAX_LIST_ITEMS + 16)
#: the item's first field, a float as the wire carries it (MCP-PAY-4): what does not fit, no
#: node can get
_FLOAT32 = struct.Struct(ITEM.format[:2])
_INT_COLUMNS = {0: ("index", 0xFFFF), 1: ("current", 0xFF), 2: ("frame", 0xFF),
                3: ("command", 0xFFFF), 11: ("autocontinue", 0xFF)}


def _enum_values(name: str) -> frozenset[int]:
    return frozenset(v for v, e in mavlink2.enums[name].items() if not e.name.endswith("_ENUM_END"))


_MAV_CMDS = _enum_values("MAV_CMD")
_MAV_FRAMES = _enum_values("MAV_FRAME")
#: Frames whose x/y are latitude/longitude (MAV_FRAME_GLOBAL*), where PAY-7's ranges apply.
_GLOBAL_FRAMES = frozenset(v for v, e in mavlink2.enums["MAV_FRAME"].items() if "GLOBAL" in e.name)


class WaypointFileError(ValueError):
    """A waypoint file cannot be read; the one-line message names the file and the line."""

    def __init__(self, path: str | Path, line: int | None, reason: str) -> None:
        where = f"{path}" if line is None else f"{path}:{line}"
        super().__init__(f"{where}: {reason}")
        self.path = str(path)
        self.line = line
        self.reason = reason


# ---------------------------------------------------------------- MAVLink MISSION_ITEM
def to_mavlink(item: Any) -> Any:
    """pymavlink's MISSION_ITEM message (ardupilotmega, v2 module) carrying ``item``."""
    it = MissionItem._make(item)
    return mavlink2.MAVLink_mission_item_message(
        it.target_system, it.target_component, it.seq, it.frame, it.command, it.current,
        it.autocontinue, it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z)


def from_mavlink(msg: Any) -> Any:
    """The :class:`~spec.codec.MissionItem` of a pymavlink MISSION_ITEM message.

    Raises ``ValueError`` for any other message type (MISSION_ITEM_INT scales x/y
    differently and is not a mission item of MCP-PAY-4).
    """
    get_type = getattr(msg, "get_type", None)
    if get_type is None or get_type() != _MAVLINK_NAME:
        kind = get_type() if get_type is not None else type(msg).__name__
        raise ValueError(f"not a {_MAVLINK_NAME} message: {kind}")
    return MissionItem._make(getattr(msg, name) for name in _FIELDS)


# ---------------------------------------------------------------- waypoint files
def _check_lines(path: Path, lines: list[str]) -> list[int]:
    """Check what pymavlink's reader would trip over, so the error can name the line.

    Returns the INDEX column of each waypoint line.
    """
    indexes: list[int] = []
    if not lines or lines[0].strip() != WAYPOINT_FILE_HEADER:
        first = lines[0].strip() if lines else ""
        raise WaypointFileError(path, 1, f"expected {WAYPOINT_FILE_HEADER!r}, found {first[:40]!r}")
    for number, raw in enumerate(lines[1:], start=2):
        line = raw.strip()
        if not line or raw.startswith("#"):
            continue
        cols = line.split()
        if len(cols) != _LINE_FIELDS:
            raise WaypointFileError(
                path, number, f"{len(cols)} fields where a waypoint line has {_LINE_FIELDS}")
        for col, text in enumerate(cols):
            if col in _INT_COLUMNS:
                name, top = _INT_COLUMNS[col]
                try:
                    value = int(text)
                except ValueError:
                    raise WaypointFileError(path, number, f"{name} {text!r} is not an integer") from None
                if not 0 <= value <= top:
                    raise WaypointFileError(path, number, f"{name} {value} is outside 0..{top}")
            else:
                try:
                    _FLOAT32.pack(float(text))
                except ValueError:
                    raise WaypointFileError(path, number, f"field {col + 1} {text!r} is not a number") from None
                except OverflowError:
                    raise WaypointFileError(path, number, f"field {col + 1} {text} does not fit the wire's "
                                                          "32-bit float (MCP-PAY-4)") from None
        indexes.append(int(cols[0]))
    return indexes


def load_waypoints(path: str | Path) -> tuple[Any, ...]:
    """Load a QGC WPL 110 file through pymavlink's ``MAVWPLoader``, as mission items.

    Each item's ``seq`` is the line's INDEX column (pymavlink would renumber by position).

    Raises :class:`WaypointFileError` (a ``ValueError``) naming the file and line.
    """
    src = Path(path)
    try:
        st = src.stat()
        if not stat.S_ISREG(st.st_mode):
            raise WaypointFileError(src, None, "not a regular file")
        if st.st_size > MAX_FILE_BYTES:
            raise WaypointFileError(src, None, f"{st.st_size} bytes: larger than a waypoint list "
                                               f"one datagram carries ({MAX_LIST_ITEMS} items)")
        with open(src, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)  # a file that grew since: still bounded
        if len(data) > MAX_FILE_BYTES:
            raise WaypointFileError(src, None, f"larger than {MAX_FILE_BYTES} bytes")
        lines = data.decode("ascii").splitlines()
    except OSError as exc:
        raise WaypointFileError(src, None, f"cannot read: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise WaypointFileError(src, None, f"not a text file: byte {exc.start} is not ASCII") from None
    indexes = _check_lines(src, lines)
    if len(indexes) > MAX_LIST_ITEMS:
        raise WaypointFileError(src, None, f"{len(indexes)} waypoints: one WP_List or Obstacles_List "
                                           f"datagram carries at most {MAX_LIST_ITEMS}")
    loader = mavwp.MAVWPLoader()
    try:
        loader.load(str(src))
    except (mavwp.MAVWPError, ValueError, OSError) as exc:  # after _check_lines: unexpected
        raise WaypointFileError(src, None, f"pymavlink rejects it: {exc}") from None
    if loader.count() != len(indexes):
        raise WaypointFileError(src, None, f"pymavlink read {loader.count()} waypoints of {len(indexes)}")
    # MAVWPLoader.add() renumbers seq by position; the file's INDEX column is the item's seq.
    return tuple(from_mavlink(loader.wp(i))._replace(seq=indexes[i]) for i in range(loader.count()))


def save_waypoints(path: str | Path, items: Iterable[Any]) -> None:
    """Write ``items`` as a QGC WPL 110 file through pymavlink's ``MAVWPLoader.save``.

    Each item keeps its own ``seq`` as the line's index. Floats are written with six
    decimals (pymavlink's ``%f``), about 0.1 m in latitude/longitude.
    """
    loader = mavwp.MAVWPLoader()
    # Appended directly: MAVWPLoader.add() would renumber seq, and a file should hold
    # exactly the items given.
    loader.wpoints.extend(to_mavlink(item) for item in items)
    try:
        loader.save(str(path))
    except OSError as exc:
        raise WaypointFileError(path, None, f"cannot write: {exc.strerror}") from None


# ---------------------------------------------------------------- MCP-PAY-7
def known_command(command: int) -> bool:
    """True when ``command`` is a MAV_CMD of pymavlink's ardupilotmega dialect."""
    return command in _MAV_CMDS


def known_frame(frame: int) -> bool:
    """True when ``frame`` is a MAV_FRAME of pymavlink's ardupilotmega dialect."""
    return frame in _MAV_FRAMES


def sane_item(item: Any) -> list[str]:
    """The MCP-PAY-7 problems of one mission item (an empty list when it is sane).

    MCP-PAY-7: "Mission items are sane: finite floats, latitude in [-90, 90], longitude
    in [-180, 180], a MAV_CMD and a MAV_FRAME that MAVLink defines." Latitude is x and
    longitude y (E-2); the ranges are checked where the item's frame is a global one
    (MAV_FRAME_GLOBAL*), since in local frames x and y are metres, not degrees.
    """
    it = MissionItem._make(item)
    problems = []
    for name in ("param1", "param2", "param3", "param4", "x", "y", "z"):
        value = getattr(it, name)
        if not isinstance(value, (int, float)) or not math.isfinite(value):
            problems.append(f"{name} is not a finite number: {value!r}")
    if it.frame in _GLOBAL_FRAMES:
        if isinstance(it.x, (int, float)) and math.isfinite(it.x) and not -90.0 <= it.x <= 90.0:
            problems.append(f"latitude x={it.x} is outside [-90, 90]")
        if isinstance(it.y, (int, float)) and math.isfinite(it.y) and not -180.0 <= it.y <= 180.0:
            problems.append(f"longitude y={it.y} is outside [-180, 180]")
    if not known_command(it.command):
        problems.append(f"command {it.command} is not a MAV_CMD")
    if not known_frame(it.frame):
        problems.append(f"frame {it.frame} is not a MAV_FRAME")
    return problems

"""The codec of a stream protocol, derived from its spec (``spec/nsqd.yaml``): frames,
message bodies, and a sans-I/O deframer.

- :func:`encode` builds a frame from a message name and its field values (the prefix counts
  itself when the spec says so: NSQD-FRM-1, E-1).
- :func:`decode_body` reads a body by its message's field list; a body the fields do not fit
  raises :class:`BodyError` naming NSQD-MSG-7 and what was wrong (D-3); text fields are
  checked too (numbers, GPX: D-7). Bytes after the last field are counted, not rejected.
- :class:`Deframer` takes bytes in any split (``feed``) and gives whole frames in order
  (NSQD-FRM-2/3); a length outside the spec's bounds gives a :class:`FramingError` naming
  NSQD-FRM-4 and the deframer stops there, since a stream cannot be resynchronised after it.
"""

from __future__ import annotations

import math
import re
import struct
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from mcp_conform.spec.nsqd import MessageSpec, StreamSpec

__all__ = ["BodyError", "Decoded", "Deframer", "Frame", "FramingError", "decode_body", "encode",
           "encode_body", "frame", "gpx_problem", "number_problem"]

_NUMBER = re.compile(r"[+-]?(\d+(\.\d*)?|\.\d+)([eE][+-]?\d+)?")


class BodyError(ValueError):
    """A body its message's fields do not fit (NSQD-MSG-7, D-3)."""

    rule = "NSQD-MSG-7"


@dataclass(frozen=True)
class Frame:
    """One whole frame as it crossed the wire: its id, its body and its raw bytes."""

    msg_id: int
    body: bytes
    raw: bytes


@dataclass(frozen=True)
class FramingError:
    """A length prefix outside the spec's bounds (NSQD-FRM-4): the stream ends here."""

    length: int
    raw: bytes
    reason: str
    rule: str = "NSQD-FRM-4"


@dataclass(frozen=True)
class Decoded:
    """A decoded body: the message's name and its field values in order (``extra``: bytes
    after the last field)."""

    name: str
    values: tuple[tuple[str, Any], ...]
    extra: int = 0

    def __getitem__(self, key: str) -> Any:
        for k, v in self.values:
            if k == key:
                return v
        raise KeyError(key)

    def as_dict(self) -> dict[str, Any]:
        return dict(self.values)


def number_problem(text: str) -> str | None:
    """Why ``text`` is not a finite decimal number (SET_PID, SET_RPYTFF: D-3), or None."""
    if not _NUMBER.fullmatch(text):
        return f"{text[:40]!r} is not a decimal number"
    if not math.isfinite(float(text)):
        return f"{text[:40]!r} is not finite"
    return None


def gpx_problem(text: str) -> str | None:
    """Why ``text`` is not a flight path (D-7: GPX root, a wpt/rtept/trkpt with lat/lon in range), or None."""
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        return f"not well-formed XML ({exc})"
    if root.tag.rsplit("}", 1)[-1] != "gpx":
        return f"root element {root.tag!r}, not gpx"
    for el in root.iter():
        if el.tag.rsplit("}", 1)[-1] in ("wpt", "rtept", "trkpt"):
            try:
                lat, lon = float(el.attrib["lat"]), float(el.attrib["lon"])
            except (KeyError, ValueError):
                return "a point without numeric lat and lon"
            if not (-90 <= lat <= 90 and -180 <= lon <= 180):
                return f"a point out of range ({lat}, {lon})"
            return None
    return "no wpt, rtept or trkpt"


def _type(spec: StreamSpec, name: str) -> Mapping[str, Any]:
    return spec.types[name]


def encode_body(spec: StreamSpec, msg: MessageSpec, values: Mapping[str, Any]) -> bytes:
    """The body of ``msg`` with ``values`` (strings as str or bytes; a float field takes the
    integer the wire carries, E-2). A missing field raises KeyError (our own misuse)."""
    out = b""
    for f in msg.fields:
        t = _type(spec, f.type)
        v = values[f.name]
        if "length" in t:
            data = v.encode("utf-8") if isinstance(v, str) else bytes(v)
            out += struct.pack(_type(spec, t["length"])["struct"], len(data)) + data
        elif t["struct"].endswith("I"):
            out += struct.pack(t["struct"], int(v) % 2**32)
        else:
            out += struct.pack(t["struct"], v)
    return out


def frame(spec: StreamSpec, msg_id: int, body: bytes, *, length: int | None = None) -> bytes:
    """A frame around ``body``; ``length`` overrides the prefix (for malformed probes)."""
    fr = spec.framing
    head = struct.pack(fr.id_struct, msg_id)
    if length is None:
        length = len(head) + len(body) + (fr.prefix_width if fr.counts_itself else 0)
    return struct.pack(fr.prefix_struct, length) + head + body


def encode(spec: StreamSpec, name: str, **values: Any) -> bytes:
    """The whole frame of message ``name`` with its field values."""
    msg = spec.message(name)
    return frame(spec, msg.id, encode_body(spec, msg, values))


def decode_body(spec: StreamSpec, msg_id: int, body: bytes, *, check_text: bool = True) -> Decoded:
    """The fields of a body; :class:`BodyError` when they do not fit (``KeyError``: unknown id)."""
    msg = spec.message(msg_id)
    pos, values = 0, []
    for f in msg.fields:
        t = _type(spec, f.type)
        if "length" in t:
            lt = _type(spec, t["length"])["struct"]
            n_size = struct.calcsize(lt)
            if pos + n_size > len(body):
                raise BodyError(f"{msg.name}.{f.name}: body ends before the string's length ({len(body)} bytes)")
            (n,) = struct.unpack_from(lt, body, pos)
            pos += n_size
            if n < 0:
                raise BodyError(f"{msg.name}.{f.name}: string length {n} is negative")
            if pos + n > len(body):
                raise BodyError(f"{msg.name}.{f.name}: string length {n} runs {pos + n - len(body)} bytes past the frame")
            raw = body[pos:pos + n]
            pos += n
            text = raw.decode("utf-8", errors="replace")
            if check_text and f.text == "number" and (why := number_problem(text)):
                raise BodyError(f"{msg.name}.{f.name}: {why}")
            if check_text and f.text == "gpx" and (why := gpx_problem(text)):
                raise BodyError(f"{msg.name}.{f.name}: {why}")
            values.append((f.name, text))
        else:
            size = struct.calcsize(t["struct"])
            if pos + size > len(body):
                raise BodyError(f"{msg.name}.{f.name}: body ends at {len(body)} bytes, the field needs {pos + size}")
            (v,) = struct.unpack_from(t["struct"], body, pos)
            pos += size
            if check_text and ((f.min is not None and v < f.min) or (f.max is not None and v > f.max)):
                raise BodyError(f"{msg.name}.{f.name}: {v} outside {f.min}..{f.max}")
            values.append((f.name, v))
    return Decoded(msg.name, tuple(values), extra=len(body) - pos)


class Deframer:
    """Bytes in (any split), whole frames out, in order; sans-I/O.

    ``feed`` returns the frames completed by the bytes given and, once, a
    :class:`FramingError` when a length is out of bounds; after that the deframer is
    ``broken`` and ignores further bytes. ``pending`` is how many bytes of an unfinished
    frame it holds (a connection closed then cut a frame: NSQD-ROB-2/3)."""

    def __init__(self, spec: StreamSpec) -> None:
        self._fr = spec.framing
        self._buf = bytearray()
        self.broken: FramingError | None = None

    @property
    def pending(self) -> int:
        return len(self._buf)

    def feed(self, data: bytes) -> list[Frame | FramingError]:
        if self.broken is not None:
            return []
        self._buf += data
        out: list[Frame | FramingError] = []
        fr = self._fr
        while len(self._buf) >= fr.prefix_width:
            (length,) = struct.unpack_from(fr.prefix_struct, self._buf, 0)
            total = length if fr.counts_itself else length + fr.prefix_width
            if not fr.min_length <= length <= fr.max_length:
                why = "below" if length < fr.min_length else "above"
                self.broken = FramingError(length, bytes(self._buf[:fr.prefix_width]),
                                           f"length {length} {why} the bounds {fr.min_length}..{fr.max_length}")
                self._buf.clear()
                out.append(self.broken)
                break
            if len(self._buf) < total:
                break
            raw = bytes(self._buf[:total])
            del self._buf[:total]
            (msg_id,) = struct.unpack_from(fr.id_struct, raw, fr.prefix_width)
            out.append(Frame(msg_id, raw[fr.header_size:], raw))
        return out

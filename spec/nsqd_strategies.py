"""Hypothesis strategies for a stream protocol, derived from its spec (``spec/nsqd.yaml``).

- :func:`message_values` draws a message name and field values its layout carries (text
  fields as the spec says: decimal numbers, GPX paths; integer ranges of the field type and
  of the field's own bounds), so ``decode_body(encode(...)) == values``.
- :func:`frames` draws their encoded frames; :func:`streams` several frames as one byte
  string with the cut points a TCP stream may split them at (NSQD-FRM-2/3).
"""

from __future__ import annotations

from typing import Any

from hypothesis import strategies as st

from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd import Field, StreamSpec, int_range
from mcp_conform.spec.nsqd_codec import encode

__all__ = ["GPX_FORMS", "frames", "gpx_document", "message_values", "streams"]



#: the forms a flight path's points take (D-7: "at least one wpt, rtept or trkpt"): waypoints, a
#: route, a GPX 1.1 track of segments, a track whose points are its own children (what a backend
#: reading ``trk > trkpt`` takes)
GPX_FORMS = (("", "wpt"), ("rte", "rtept"), ("trk><trkseg", "trkpt"), ("trk", "trkpt"))


def gpx_document(points: list[tuple[float, float]], form: tuple[str, str]) -> str:
    """A GPX 1.1 flight path of ``points`` (lat, lon) in one of :data:`GPX_FORMS`."""
    outer, point = form
    pts = "".join(f'<{point} lat="{lat:.6f}" lon="{lon:.6f}"/>' for lat, lon in points)
    if outer:
        pts = f"<{outer}>{pts}" + "".join(f"</{t}>" for t in reversed(outer.split("><")))
    return f'<?xml version="1.0"?><gpx version="1.1" creator="mcp-fuzz">{pts}</gpx>'


def _gpx() -> st.SearchStrategy[str]:
    point = st.tuples(st.floats(-90, 90, allow_nan=False), st.floats(-180, 180, allow_nan=False))
    return st.builds(gpx_document, st.lists(point, min_size=1, max_size=8), st.sampled_from(GPX_FORMS))


def _field(spec: StreamSpec, f: Field) -> st.SearchStrategy[Any]:
    t = spec.types[f.type]
    if "length" in t:
        if f.text == "number":
            return st.floats(-1e6, 1e6, allow_nan=False).map(lambda x: f"{x:.3f}")
        if f.text == "gpx":
            return _gpx()
        return st.text(st.characters(min_codepoint=32, max_codepoint=126), max_size=40)
    if t["struct"] == ">?":
        return st.booleans()
    lo, hi = int_range(t["struct"])
    lo = max(lo, f.min) if f.min is not None else lo
    hi = min(hi, f.max) if f.max is not None else hi
    return st.integers(lo, hi)


@st.composite
def message_values(draw: Any, spec: StreamSpec = NSQD) -> tuple[str, dict[str, Any]]:
    msg = draw(st.sampled_from(spec.messages))
    return msg.name, {f.name: draw(_field(spec, f)) for f in msg.fields}


def frames(spec: StreamSpec = NSQD) -> st.SearchStrategy[bytes]:
    return message_values(spec).map(lambda nv: encode(spec, nv[0], **nv[1]))


@st.composite
def streams(draw: Any, spec: StreamSpec = NSQD) -> tuple[bytes, list[int]]:
    """Frames back to back, and where a TCP stream cut them."""
    data = b"".join(draw(st.lists(frames(spec), min_size=1, max_size=6)))
    cuts = sorted(draw(st.lists(st.integers(0, len(data)), max_size=10)))
    return data, cuts



"""One MCAP capture from several: the parts pytest-xdist workers record, joined in time order.

Under ``pytest -n N --mcp-capture run.mcap`` each worker records its own node's traffic to a
part (``run.gw0.mcap``, ...); the controller joins them into the one file the user asked
for, as pytest-cov joins coverage data. Channels and schemas are matched by topic and
schema name (every part is written by ``traceio.recorder``, so they agree); each message
keeps its log time. Each part stays a *segment*: its channels and its metadata records carry
its name (``segment``: ``gw0``, ...) and its channels its writer (``library``), so a reader
(``traceio.reader``, ``open_capture(path, segment=...)``) gives each worker's session apart
and the judge judges each on its own, as that worker's run monitor did. A part that is cut
short is read up to its last whole record, like every reader of ours; the parts are removed
only when the merged file is complete.
"""

from __future__ import annotations

import heapq
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

__all__ = ["LIBRARY", "SEGMENT", "merge_captures", "nested", "segment_name"]


SEGMENT = "segment"  # the channel and metadata key naming a part's session
LIBRARY = "library"  # the channel key naming the part's writer (its MCAP header's library)


def segment_name(path: Path) -> str:
    """``run.gw0.mcap`` -> ``gw0`` (the part's worker), else the file's stem."""
    parts = path.name.split(".")
    return parts[-2] if len(parts) >= 3 else path.stem


def nested(part: str, inner: str | None) -> str:
    """The segment of a part's session in the merged file: the part's name, and the session
    the part itself holds, if any (``gw0/main``: a worker's run whose missions are sessions,
    ``traceio.recorder.McapRecorder.begin_segment``)."""
    return part if not inner else f"{part}/{inner}"


def _metadata(path: Path) -> list[tuple[str, dict[str, str]]]:
    """The part's metadata records (none from a part whose summary is unreadable)."""
    with open(path, "rb") as f:
        try:
            return [(md.name, dict(md.metadata)) for md in make_reader(f).iter_metadata()]
        except (McapError, EOFError, ValueError, OSError, AssertionError):
            return []


def _library(path: Path) -> str:
    """The writer the part's header names ("" when unreadable)."""
    with open(path, "rb") as f:
        try:
            return make_reader(f).get_header().library
        except (McapError, EOFError, ValueError, OSError, AssertionError):
            return ""


def _messages(path: Path, part: int) -> Iterator[tuple[int, int, int, Any, Any, Any]]:
    """(log_time, part, sequence, schema, channel, message) of one part, in log-time order."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        n = 0
        try:
            for schema, channel, message in reader.iter_messages(log_time_order=True):
                yield message.log_time, part, n, schema, channel, message
                n += 1
        except (McapError, EOFError, ValueError, OSError, AssertionError):
            return  # a cut part: keep what it holds up to its last whole record


def merge_captures(parts: Sequence[str | Path], out: str | Path, *, remove_parts: bool = True) -> int:
    """Join ``parts`` into ``out`` in log-time order, each part a segment; returns the number
    of messages."""
    paths = [Path(p) for p in parts if Path(p).exists()]
    names = [segment_name(p) for p in paths]
    libraries = [_library(p) for p in paths]  # a reader tells a harness's datagrams by it
    streams = [_messages(p, i) for i, p in enumerate(paths)]
    count = 0
    with open(out, "wb") as f:
        writer = Writer(f, compression=CompressionType.ZSTD)
        writer.start(profile="mcp-conform", library="mcp-conform (merged from pytest-xdist workers)")
        for path, name in zip(paths, names, strict=True):  # first: a reader knows the runs
            for md_name, values in _metadata(path):
                writer.add_metadata(md_name, {**values, SEGMENT: nested(name, values.get(SEGMENT))})
        writer.add_metadata("xdist", {"parts": ", ".join(p.name for p in paths)})
        schemas: dict[tuple[str, str], int] = {}
        channels: dict[tuple[int, int], int] = {}
        for _t, part, _n, schema, channel, message in heapq.merge(*streams, key=lambda r: r[:3]):
            sid = 0
            if schema is not None:
                skey = (schema.name, schema.encoding)
                if skey not in schemas:
                    schemas[skey] = writer.register_schema(schema.name, schema.encoding, schema.data)
                sid = schemas[skey]
            ckey = (part, channel.id)  # a part's sessions have channels of the same topics
            if ckey not in channels:
                channels[ckey] = writer.register_channel(
                    channel.topic, channel.message_encoding, sid,
                    {**dict(channel.metadata), SEGMENT: nested(names[part], channel.metadata.get(SEGMENT)),
                     LIBRARY: libraries[part]})
            writer.add_message(channels[ckey], message.log_time, message.data,
                               message.publish_time, sequence=count)
            count += 1
        writer.finish()
    if remove_parts:
        for p in paths:
            p.unlink(missing_ok=True)
    return count

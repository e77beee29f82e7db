"""What every protocol's trace reader does alike (``traceio.nsqd``, ``traceio.mavlink``: a
capture plug-in's reader, docs/design.md "A protocol is a plug-in"), the protocol a parameter:
which run a capture's metadata says it was (:func:`recorded_protocol`, :func:`said_by`,
:func:`recorded`: its role under test), whether
a capture's first records are a protocol's (:func:`claims`), the records an MCAP holds of it
(:func:`records_of`; a packet protocol's frames numbered, :func:`packet_records`), a capture's packet reader closed however the reading ends
(:func:`closing`), and the one-line error of a file corrupt before its first record
(:func:`corrupt`), a file's head (:func:`head_of`, :func:`is_mcap_head`: ``traceio.reader``'s,
which every capture's reading starts with), a pcap's TCP connections as a stream protocol's records
(:func:`stream_pcap_records`, its frames named by the spec: :func:`frame_names`). A protocol's own module keeps its content: its records, its framing, its
own file format (a tlog).
"""

from __future__ import annotations

import contextlib
import itertools
import json
from collections.abc import Callable, Iterable, Iterator
from pathlib import Path
from typing import Any

from mcp_conform.traceio.reader import (
    Capture,
    CaptureError,
    CaseMark,
    Metadata,
    StreamFrame,
    Truncated,
    head_of,
    is_mcap_head,
    open_capture,
)
from mcp_conform.traceio.tcp import StreamData, StreamGap, tcp_events

__all__ = ["PEEK", "claims", "closing", "corrupt", "frame_names", "head_of", "is_mcap_head", "packet_records", "recorded",
           "recorded_protocol",
           "records_of", "said_by", "stream_pcap_records"]

#: records (or packets) looked at to tell which protocol's a capture is
PEEK = 500


def recorded(path: str | Path, key: str) -> str | None:
    """What the run's metadata record of an MCAP says of ``key`` (``role``: ``mcp-conform
    --role``) among its first :data:`PEEK` records; None: nothing."""
    for rec in itertools.islice(open_capture(path), PEEK):
        if isinstance(rec, Metadata) and rec.data.get(key):
            return str(rec.data[key])
    return None


def recorded_protocol(meta: Metadata) -> str | None:
    """The ``--protocol`` of the run a capture's metadata record describes (its run
    parameters, ``traceio.recorder.run_metadata``), if it says."""
    try:
        value = json.loads(meta.data.get("parameters", "{}")).get("protocol")
    except (ValueError, AttributeError):
        return None
    return value if isinstance(value, str) else None


def said_by(name: str) -> Callable[[Metadata], bool | None]:
    """:func:`claims`'s ``says`` of protocol ``name``: the run's metadata names it, or another
    (None: it names none)."""
    def says(meta: Metadata) -> bool | None:
        protocol = recorded_protocol(meta)
        return None if protocol is None else protocol == name
    return says


def claims(records: Iterable[Any], own: tuple[type, ...], foreign: tuple[type, ...],
           says: Callable[[Metadata], bool | None], *, first: bool) -> bool:
    """Whether a capture's first :data:`PEEK` records are a protocol's: a metadata record
    that ``says`` (True, False; None: says nothing) decides; a ``foreign`` record (another
    protocol's) is a no; an ``own`` one a yes at once (``first``), else when nothing said no."""
    seen = False
    for rec in itertools.islice(records, PEEK):
        if isinstance(rec, Metadata):
            said = says(rec)
            if said is not None:
                return said
        elif isinstance(rec, foreign):
            return False
        elif isinstance(rec, own):
            if first:
                return True
            seen = True
    return seen


def records_of(cap: Capture, kinds: tuple[type, ...]) -> Iterator[Any]:
    """An opened capture's records of these kinds, in order."""
    for rec in cap:
        if type(rec) in kinds:
            yield rec


def packet_records(cap: Capture, kind: type, make: Callable[[int, Any], Any]) -> Iterator[Any]:
    """An opened MCAP's records of a packet protocol: each of its frames (records of ``kind``)
    as ``make(n, rec)`` makes it, ``n`` 0, 1, 2, ... over them; the run's ``CaseMark`` and
    ``Metadata`` records; last, when the file ends early, ``Truncated`` (:func:`corrupt` when
    no frame came before)."""
    n = 0
    for rec in cap:
        if isinstance(rec, kind):
            yield make(n, rec)
            n += 1
        elif isinstance(rec, Truncated):
            if not n and cap.corrupt:
                raise corrupt(cap.path, "MCAP", rec.reason)
            yield rec
        elif isinstance(rec, (CaseMark, Metadata)):
            yield rec


@contextlib.contextmanager
def closing(cap: Capture) -> Iterator[Capture]:
    """``cap`` whose packet reader (a pcap's) is closed however the reading ends."""
    try:
        yield cap
    finally:
        if cap._reader is not None:
            cap._reader.close()


def corrupt(path: str | Path, fmt: str, reason: str) -> CaptureError:
    """The error of a file corrupt before anything of it could be read (never an empty OK)."""
    return CaptureError(f"{path}: {fmt} file corrupt, nothing could be read: {reason}")



def frame_names(spec: Any, deframer: Callable[[], Any]) -> tuple[Callable[[bytes], str | None],
                                                                  Callable[[Any], tuple[str | None, str | None]]]:
    """How a stream protocol's records name what its ``deframer`` gives (an item with a
    ``msg_id`` is a frame, any other bytes it refused, with their ``reason``), by its ``spec``'s
    messages: (the message a client's write is, when it is one whole frame of a known id;
    (name, problem) of an item of the node's bytes: a frame's message name, None for an id the
    spec has not, or None and why the bytes were refused)."""
    def name_of(item: Any) -> str | None:
        return str(spec.message(item.msg_id).name) if spec.has_message(item.msg_id) else None

    def write(raw: bytes) -> str | None:
        head = deframer().feed(raw)
        whole = len(head) == 1 and hasattr(head[0], "msg_id") and len(head[0].raw) == len(raw)
        return name_of(head[0]) if whole else None

    def frame(item: Any) -> tuple[str | None, str | None]:
        return (name_of(item), None) if hasattr(item, "msg_id") else (None, item.reason)
    return write, frame


def stream_pcap_records(cap: Capture, port: int, speaks: Callable[[bytes], bool], deframer: Callable[[], Any],
                        spec: Any) -> Iterator[Any]:
    """A pcap's TCP connections to the node's ``port`` (or whose segments it ``speaks``:
    ``traceio.tcp``) as a stream protocol's records: ``StreamEvent``; ``StreamFrame`` ``tx``
    each write of the client (named: the frame it is, if one, :func:`frame_names`), ``rx``
    each item of the node's bytes through its ``deframer`` (a frame's name, or None and why
    the deframer refused the bytes), unframed after a gap of the node's direction;
    ``StreamGap``; last ``Truncated``. A file corrupt before its first packet is
    :func:`corrupt`."""
    name, frame = frame_names(spec, deframer)
    deframers: dict[int, Any] = {}
    broken: set[int] = set()
    n = events = 0
    for ev in tcp_events(cap, port, speaks):
        events += 1
        kind = type(ev)
        if kind is StreamData:
            if ev.direction == "tx":
                yield StreamFrame(n, ev.t_ns, "tx", ev.conn, name(ev.data), None, ev.data)
                n += 1
                continue
            if ev.conn in broken:
                yield StreamFrame(n, ev.t_ns, "rx", ev.conn, None, "after a gap in the capture: not framed", ev.data)
                n += 1
                continue
            if ev.conn not in deframers:
                deframers[ev.conn] = deframer()
            for item in deframers[ev.conn].feed(ev.data):
                yield StreamFrame(n, ev.t_ns, "rx", ev.conn, *frame(item), item.raw)
                n += 1
        else:
            if kind is StreamGap and ev.direction == "rx":
                broken.add(ev.conn)
            yield ev
    if cap.truncated is not None:
        if cap.corrupt and not events:
            raise corrupt(cap.path, cap.format, cap.truncated)
        yield Truncated(cap.truncated)

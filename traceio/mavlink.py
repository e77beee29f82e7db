"""A MAVLink trace's frames, whatever the file: our MCAP's ``/mavlink`` channel or a ``.tlog``.

:func:`open_trace` yields what ``mcp-capture --protocol mavlink`` and the MAVLink trace
monitor (``judge.mavlink_monitor``) work on: :class:`MavFrame` (one frame, parsed by
pymavlink's dialect, ``spec.MAVLINK.dialect``: ardupilotmega, MAVLink 1 and 2), and from an
MCAP the run's ``CaseMark`` and ``Metadata`` records; last, and only when the file ends early,
``Truncated``.

- Our MCAP (``mcp-conform --protocol mavlink --capture``, and the autopilot link of an MCP
  drone run): each ``/mavlink`` record is one frame, recorded from the autopilot's side
  (``direction`` ``tx``: the vehicle sent it, ``rx``: the vehicle received it), bytes that
  were no good frame as pymavlink's ``BAD_DATA``. The runner records every frame of its one
  link (:attr:`MavTrace.complete`).
- A telemetry log (``.tlog``), the field capture format of MAVLink that MAVProxy, QGroundControl
  and Mission Planner write: records of an 8-byte big-endian microsecond timestamp and one
  MAVLink frame, read by pymavlink's own reader (``mavutil.mavlogfile``), with the dialect's
  parser put in for pymavlink's default one, so that reading a log changes none of
  pymavlink's process-wide settings (its MAVLink 1/2 switch: ``MAVLINK20``). The reader
  never opens a connection, whatever the file is named (``mavutil.mavlink_connection``
  would take ``tcp:HOST:PORT`` as one). A tlog says neither who sent a frame (its source
  IDs do) nor whether it holds every frame of the link (a ground station logs what it
  received and what it chose to log of what it sent).

Unreadable input raises ``CaptureError`` with one line naming the file: an empty file, a file
that is neither our MCAP nor a tlog (its first record is no MAVLink frame), an MCAP without
MAVLink frames. A cut file yields its whole records and then ``Truncated``.
"""

from __future__ import annotations

import contextlib
import io
from collections.abc import Iterator
from pathlib import Path
from typing import Any, NamedTuple

from mcp_conform.spec import MAVLINK
from mcp_conform.spec.mavframe import robust_parser  # the dialect's, which reads MAVLink 1 and 2
from mcp_conform.traceio.reader import (
    CaptureError,
    Datagram,
    MavlinkFrame,
    StreamFrame,
    Truncated,
    open_capture,
)

# ``traceio.traces`` is imported where a file is read, not here: it brings scapy (its TCP
# reassembly, ~0.3 CPU s of imports), which a process that only parses frames -- the runner's
# link, a proxy rewriting a vehicle's frames, the live monitor -- never uses

__all__ = ["MavFrame", "MavTrace", "is_mavlink_capture", "open_trace", "parse_frame", "robust_parser", "version_of"]

DIALECT: Any = MAVLINK.dialect
#: the start markers of a MAVLink 1 and a MAVLink 2 frame (the dialect's)
MARKERS = frozenset({int(DIALECT.PROTOCOL_MARKER_V1), int(DIALECT.PROTOCOL_MARKER_V2)})
#: timestamps a tlog's first record may carry (µs since 1970: 1990 .. 2100): a file whose
#: first 8 bytes are no such time is not a tlog, whatever byte follows them
_PLAUSIBLE_US = (631152000 * 10**6, 4102444800 * 10**6)


class MavFrame(NamedTuple):
    """One MAVLink frame of a trace: ``index`` 0, 1, 2, ... over the trace's frames (the
    evidence of a violation names it), ``t_ns`` (the MCAP's log time, the tlog's timestamp),
    ``direction`` as recorded (``tx`` sent by the vehicle under test, ``rx`` received by it;
    None in a tlog), the frame's bytes and pymavlink's message (``BAD_DATA`` for bytes that
    are no good frame)."""

    index: int  # type: ignore[assignment]  # (shadows tuple.index, as the other records do)
    t_ns: int
    direction: str | None
    raw: bytes
    msg: Any
    segment: str | None = None

    @property
    def name(self) -> str:
        return str(self.msg.get_type())

    @property
    def bad(self) -> bool:
        return self.name == "BAD_DATA"

    @property
    def source(self) -> tuple[int, int]:
        return int(self.msg.get_srcSystem()), int(self.msg.get_srcComponent())

    @property
    def version(self) -> int:
        return version_of(self.raw)


def version_of(raw: bytes) -> int:
    """The MAVLink version of a frame's bytes (its start marker: 2 for MAVLink 2's, else 1)."""
    return 2 if raw[:1] == bytes([DIALECT.PROTOCOL_MARKER_V2]) else 1


def parse_frame(raw: bytes, parser: Any = None) -> Any:
    """pymavlink's message for the bytes of one frame (``BAD_DATA`` when they are none)."""
    parser = parser or robust_parser()
    msgs = parser.parse_buffer(bytes(raw)) or []
    if len(msgs) == 1:
        return msgs[0]
    return DIALECT.MAVLink_bad_data(bytearray(raw), "not one whole frame" if msgs else "no frame")


class MavTrace:
    """An opened MAVLink trace; iterate it once for its records (see the module docstring).
    ``format``: ``mcap`` or ``tlog``; ``complete``: the trace holds every frame of its link
    (our MCAP) rather than what one party logged (a tlog). A cut trace's last record is
    ``Truncated`` (an MCAP's: ``traces.packet_records``')."""

    def __init__(self, path: str | Path) -> None:
        from mcp_conform.traceio.traces import head_of, is_mcap_head

        self.path = Path(path)
        self.size, head = head_of(self.path, 17, "a MAVLink trace (a .tlog or an MCAP of mcp-conform)")
        self.format = "mcap" if is_mcap_head(head) else "tlog" if _tlog_head(head) else ""
        if not self.format:
            raise CaptureError(f"{self.path}: not a MAVLink trace (starts {head[:9].hex(' ')}): a .tlog's "
                               "records are an 8-byte big-endian microsecond time and a MAVLink frame")
        self.complete = self.format == "mcap"

    def __iter__(self) -> Iterator[Any]:
        return self._mcap() if self.format == "mcap" else self._tlog()

    # -- MCAP -----------------------------------------------------------------------------
    def _mcap(self) -> Iterator[Any]:
        parsers: dict[Any, Any] = {}

        def frame(n: int, rec: MavlinkFrame) -> MavFrame:
            p = parsers.get(rec.direction) or parsers.setdefault(rec.direction, robust_parser())
            return MavFrame(n, rec.t_ns, rec.direction, bytes(rec.data), parse_frame(rec.data, p), rec.segment)
        from mcp_conform.traceio.traces import packet_records

        return packet_records(open_capture(self.path), MavlinkFrame, frame)

    # -- tlog -----------------------------------------------------------------------------
    def _tlog(self) -> Iterator[Any]:
        from pymavlink import mavutil

        with contextlib.redirect_stdout(io.StringIO()):  # pymavlink prints nothing we want
            log = mavutil.mavlogfile(str(self.path), robust_parsing=True)
        log.mav = robust_parser()  # the dialect's, which reads MAVLink 1 and 2 (see the module)
        log.first_byte = False  # ... so pymavlink's version switch never runs
        consumed = n = 0
        truncated: str | None = None
        last_us: int | None = None
        try:
            while True:
                try:
                    msg = log.recv_msg()
                except Exception as exc:  # noqa: BLE001 - whatever pymavlink makes of a corrupt tail
                    truncated = f"record {n + 1} unreadable ({type(exc).__name__}: {exc})"
                    break
                if msg is None:
                    break
                raw = bytes(msg.get_msgbuf())
                consumed += 8 + len(raw)
                if n == 0 and msg.get_type() == "BAD_DATA":
                    raise CaptureError(f"{self.path}: not a MAVLink telemetry log: its first record holds "
                                       f"no MAVLink frame ({getattr(msg, 'reason', 'bad data')})")
                t_us = int(round(float(msg._timestamp) * 1e6))
                if not _PLAUSIBLE_US[0] <= t_us <= _PLAUSIBLE_US[1] and last_us is not None:
                    t_us = last_us  # bytes of a damaged record read as its time: no time, not a jump of ages
                last_us = t_us
                yield MavFrame(n, t_us * 1000, None, raw, msg)
                n += 1
        finally:
            log.close()
        if truncated is None and consumed < self.size:
            left = self.size - consumed
            truncated = f"{left} byte(s) after the last whole record (a cut or damaged file)"
        if truncated is not None:
            if not n:
                raise CaptureError(f"{self.path}: not a MAVLink telemetry log: no whole record ({truncated})")
            yield Truncated(truncated)


def _tlog_head(head: bytes) -> bool:
    """A tlog's first record: a plausible microsecond time, then a frame's start marker."""
    if len(head) < 9 or head[8] not in MARKERS:
        return False
    return _PLAUSIBLE_US[0] <= int.from_bytes(head[:8], "big") <= _PLAUSIBLE_US[1]


def open_trace(path: str | Path) -> MavTrace:
    """``path`` opened as a MAVLink trace; CaptureError (one line) when it is none."""
    return MavTrace(path)


def is_mavlink_capture(path: str | Path) -> bool:
    """A MAVLink trace: a tlog whose first record is a good MAVLink frame, or an MCAP whose run
    was ``--protocol mavlink`` (its metadata says so) or whose first records are MAVLink frames
    with no MCP datagram or Nsqd frame among them (an MCP drone run's capture holds its
    autopilot link too, but is MCP's). A file it cannot read as one raises ``CaptureError``
    (or ``OSError``), which ``captures.cli.capture_profile`` takes for "not mine", as of every
    protocol's detector."""
    trace = MavTrace(path)
    if trace.format == "mcap":
        from mcp_conform.traceio.traces import claims, said_by

        return claims(open_capture(path), (MavlinkFrame,), (Datagram, StreamFrame), said_by("mavlink"), first=False)
    return isinstance(next(iter(trace), None), MavFrame)  # the tlog reader refuses a first record that is none

"""The records a capture is read as (``traceio.reader``, ``traceio.nsqd``): one typed tuple
per kind of thing a capture holds, the same whichever file it came from (our MCAP, pcap,
pcapng), and :class:`CaptureError`, a capture that cannot be read (one line, names the file).

They are what the judge is fed: a :class:`Datagram`'s ``index`` is the index the monitor's
evidence names (MCP-* rules), a :class:`StreamFrame`'s the Nsqd judge's (NSQD-*).
"""

from __future__ import annotations

from typing import NamedTuple

__all__ = [
    "CaptureError",
    "CaseMark",
    "Datagram",
    "MavlinkFrame",
    "Metadata",
    "Record",
    "StreamEvent",
    "StreamFrame",
    "Truncated",
    "VehicleMark",
]


class Datagram(NamedTuple):
    index: int  # type: ignore[assignment]  # (shadows tuple.index; the capture's own word)
    t_ns: int
    src_addr: tuple[str, int] | None
    dst_addr: tuple[str, int] | None
    data: bytes
    direction: str | None = None  # "tx" | "rx" | None, seen from the recording host
    recorder: str | None = None
    burst: bool = False  # one of a flood recorded as a count (/mcp/burst)
    segment: str | None = None  # the session it belongs to in a merged capture (gw0, ...)
    run_delay_ns: int | None = None  # its sender's run delay as it came, when recorded (MCP-RTX-3)


class MavlinkFrame(NamedTuple):
    index: int  # type: ignore[assignment]  # 0, 1, 2, ... over the capture's MAVLink frames
    t_ns: int
    direction: str | None  # as recorded: "rx" = received by the vehicle
    msg_type: str | None
    data: bytes
    segment: str | None = None


class CaseMark(NamedTuple):
    t_ns: int
    case: str
    event: str  # "start" | "end"
    outcome: str | None
    rules: tuple[str, ...]
    segment: str | None = None


class VehicleMark(NamedTuple):
    """An autopilot-link event the run observed (``/vehicle``: link, fix, fix_lost)."""

    t_ns: int
    kind: str
    drone: int | None
    detail: str | None
    segment: str | None = None


class StreamFrame(NamedTuple):
    """Bytes on a stream protocol's connection (``/nsqd/tx``: one write of the runner;
    ``/nsqd/rx``: one frame of the backend), as ``traceio.recorder`` wrote them."""

    index: int  # type: ignore[assignment]  # (shadows tuple.index, as Datagram's)
    t_ns: int
    direction: str
    conn: int
    name: str | None
    problem: str | None
    raw: bytes


class StreamEvent(NamedTuple):
    """A stream connection opened (its addresses) or closed (``by`` client or backend, ``how``
    fin or rst): ``/nsqd/conn``, or the TCP handshake and FIN/RST of a pcap."""

    t_ns: int
    event: str  # "open" | "close"
    conn: int
    client: tuple[str, int] | None = None
    backend: tuple[str, int] | None = None
    by: str | None = None
    how: str | None = None


class Metadata(NamedTuple):
    name: str
    data: dict[str, str]


class Truncated(NamedTuple):
    reason: str


Record = Datagram | MavlinkFrame | CaseMark | VehicleMark | StreamFrame | StreamEvent | Metadata | Truncated


class CaptureError(Exception):
    """The file cannot be read as a capture (one line, names the file)."""

"""An Nsqd capture's records, whatever the file: our MCAP or a pcap/pcapng of the TCP traffic.

:func:`stream_records` yields the records ``mcp-capture`` works on for ``--protocol nsqd``:
``StreamEvent`` (a connection opened or closed), ``StreamFrame`` (``tx`` bytes the client
wrote, ``rx`` one frame the backend sent, or the bytes its deframer refused), ``StreamGap``
(bytes of a direction the capture does not hold: what follows on it is not framed),
``CaseMark``, ``Metadata`` and, last, ``Truncated``. From an MCAP they are the recorder's own
(``/nsqd/tx``, ``/nsqd/rx``, ``/nsqd/conn``); from a pcap, ``traceio.tcp`` reassembles each
connection and the backend's bytes go through the spec's deframer as the runner's do.

:func:`is_stream_capture` tells an Nsqd capture from an MCP one by its first records.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import Deframer
from mcp_conform.spec.profiles import PROFILES
from mcp_conform.traceio.reader import (
    Capture,
    CaseMark,
    Datagram,
    Metadata,
    StreamEvent,
    StreamFrame,
    Truncated,
    open_capture,
)
from mcp_conform.traceio.tcp import StreamGap
from mcp_conform.traceio.traces import (
    PEEK,
    claims,
    closing,
    frame_names,
    records_of,
    stream_pcap_records,
)

__all__ = ["BACKEND_PORT", "StreamGap", "is_stream_capture", "stream_records"]

BACKEND_PORT = NSQD.port("backend")
#: the protocols whose captures this module reads (their profile's framing is ``stream``: their
#: frames are on their stream channels), as a run's metadata record names them
_READ_HERE = frozenset(p.name for p in PROFILES.values() if p.framing == "stream")


_name = frame_names(NSQD, lambda: Deframer(NSQD))[0]
_BACKEND_IDS = {NSQD.message("UPDATE").id, NSQD.message("ERROR").id}


def _backend_speaks(payload: bytes) -> bool:
    """A segment that starts with a frame only a backend sends (UPDATE, ERROR)."""
    return len(payload) >= 5 and 5 <= _frame_len(payload) <= 8192 and payload[4] in _BACKEND_IDS


def _frame_len(data: bytes) -> int:
    return int.from_bytes(data[:4], "big") if len(data) >= 5 else 0


def is_stream_capture(path: str | Path) -> bool:
    """An Nsqd capture: an MCAP whose first records are the stream's (or whose metadata says
    ``protocol: nsqd``), a pcap among whose first TCP segments one touches the backend's
    port or starts with a whole Nsqd frame (a backend on another port)."""
    cap = open_capture(path)
    if cap.format == "mcap":
        return claims(cap, (StreamFrame, StreamEvent), (Datagram,),
                      lambda m: True if m.data.get("protocol") in _READ_HERE else None, first=True)
    from mcp_conform.traceio.tcp import tcp_segments

    with closing(cap):
        return any(BACKEND_PORT in (seg.src[1], seg.dst[1]) or _name(seg.payload[:_frame_len(seg.payload)])
                   for seg in tcp_segments(cap, PEEK))


def stream_records(path: str | Path, cap: Capture | None = None) -> Iterator[Any]:
    """The records of an Nsqd capture (see the module docstring); ``cap``: an opened one."""
    cap = cap or open_capture(path)
    if cap.format == "mcap":
        yield from records_of(cap, (StreamFrame, StreamEvent, CaseMark, Metadata, Truncated))
        return
    with closing(cap):
        yield from stream_pcap_records(cap, BACKEND_PORT, _backend_speaks, lambda: Deframer(NSQD), NSQD)

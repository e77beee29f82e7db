"""MAVLink framing for the vehicle, entirely through pymavlink (ardupilotmega).

``Decoder`` turns a byte stream (v1 and v2 frames mixed with any garbage) into decoded
messages plus a count of bytes that were not part of a valid frame, and keeps those bytes
(``take_unparsed``, ``stale``) so that a frame altered on its way can be compared with the
frame sent (MCP-PAY-8); ``Encoder`` packs messages as MAVLink v2 frames (or v1, for a peer
that speaks only MAVLink 1) with its own sequence counter (one per link).
"""

from __future__ import annotations

import threading
import time
from typing import NamedTuple

from pymavlink.dialects.v10 import ardupilotmega as mavlink1
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from pymavlink.dialects.v20.ardupilotmega import MAVLink_message as MAVLinkMessage

from mcp_conform.spec.mavframe import robust_parser

__all__ = ["STALE", "Decoder", "Encoder", "MAVLinkMessage", "UnparsedBytes", "frame_version"]

#: Seconds an incomplete frame waits for its remaining bytes before it is reported as
#: unparsed (it stays in the parser: bytes that complete it later still make a frame).
STALE = 0.2


class UnparsedBytes(NamedTuple):
    """Bytes of the stream that did not parse: ``t`` when the first arrived; ``frame``: an
    unknown message id, which is still handed on as a message (the tap shows it as a frame)."""

    t: float
    raw: bytes
    reason: str
    frame: bool = False


class Decoder:
    """Incremental, never-raising MAVLink v1/v2 stream decoder (one per link).

    Thread-safe. Besides the messages, it keeps the bytes that were no valid frame (MCP-PAY-8,
    "forwards each delivered Mav_Passthrough frame to it exactly once": an altered frame
    arrives as such bytes) until ``take_unparsed()``: each bad-CRC frame, run of bytes
    without a start marker or frame of an unknown message id as one ``UnparsedBytes``, and
    (``stale``) an incomplete frame nothing followed. Each byte is reported once.
    """

    def __init__(self) -> None:
        self._mav = self._new_parser()
        self._lock = threading.Lock()
        #: Total bytes discarded as not belonging to a valid frame.
        self.bad_bytes = 0
        self._fed = 0  # stream offset after the last byte fed
        self._done = 0  # stream offset of the first byte still in the parser
        self._reported = 0  # bytes before this offset were reported as unparsed
        self._arrivals: list[tuple[int, float]] = []  # (stream offset, arrival time) per chunk
        self._found: list[UnparsedBytes] = []

    @staticmethod
    def _new_parser() -> mavlink2.MAVLink:
        return robust_parser()

    def feed(self, data: bytes, now: float | None = None) -> tuple[list[MAVLinkMessage], int, str | None]:
        """Decode ``data`` (arrived at ``now``, ``time.monotonic()`` by default); return
        (messages, bad byte count in this chunk, first reason)."""
        with self._lock:
            return self._feed(bytes(data), time.monotonic() if now is None else now)

    def _feed(self, data: bytes, now: float) -> tuple[list[MAVLinkMessage], int, str | None]:
        self._arrivals.append((self._fed, now))
        held = bytes(self._mav.buf[self._mav.buf_index:])
        self._fed += len(data)
        try:
            if held and self._reported >= self._done + len(held):
                held, parsed = self._after_stale(held, data)
            else:
                parsed = self._mav.parse_buffer(data) or []
        except Exception as exc:  # pymavlink should not raise with robust_parsing; be safe
            self._mav = self._new_parser()
            self.bad_bytes += len(data)
            self._unparsed(held + data, f"parser error: {exc}")
            self._done = self._fed
            return [], len(data), f"parser error: {exc}"
        stream = held + data
        at = 0
        good: list[MAVLinkMessage] = []
        bad = 0
        reason: str | None = None
        for msg in parsed:
            if msg.get_type() == "BAD_DATA":
                chunk = bytes(msg.data) if getattr(msg, "data", None) is not None else stream[at:at + 1]
                bad += len(chunk) or 1
                why = str(getattr(msg, "reason", "bad data"))
                if reason is None:
                    reason = why
                self._unparsed(chunk, why)
            else:
                chunk = bytes(msg.get_msgbuf() or b"")
                if isinstance(msg, mavlink2.MAVLink_unknown):
                    self._unparsed(chunk, f"unknown message id {msg.get_type()[len('UNKNOWN_'):]}",
                                  frame=True)
                good.append(msg)
            self._done += len(chunk)
            at += len(chunk)
        self._done = self._fed - (len(self._mav.buf) - self._mav.buf_index)  # what pymavlink holds
        self._prune()
        self.bad_bytes += bad
        return good, bad, reason

    def _after_stale(self, held: bytes, data: bytes) -> tuple[bytes, list[MAVLinkMessage]]:
        """New bytes after an incomplete frame reported stale: they complete it (a frame, as
        ever), or it fails and is dropped, parsing resuming at the new bytes (so a frame cut
        short does not swallow the next one). Returns (the bytes still held before ``data``,
        the messages). New bytes that begin with a whole valid frame are not its continuation:
        the stale bytes are dropped (garbage that looked like the start of a long frame must not
        swallow the next request)."""
        fresh = self._new_parser()
        alone = fresh.parse_buffer(data) or []
        if alone and alone[0].get_type() != "BAD_DATA" \
                and bytes(alone[0].get_msgbuf() or b"") == data[:len(alone[0].get_msgbuf() or b"")]:
            self._mav = fresh
            self._done += len(held)
            return b"", alone
        trial = self._new_parser()
        parsed = trial.parse_buffer(held + data) or []
        if parsed and parsed[0].get_type() == "BAD_DATA" and len(parsed[0].data) >= len(held):
            self._mav = self._new_parser()
            self._done += len(held)
            return b"", self._mav.parse_buffer(data) or []
        self._mav = trial
        return held, parsed

    def _unparsed(self, chunk: bytes, reason: str, *, frame: bool = False) -> None:
        """``chunk`` (starting at ``self._done``) did not parse: keep what was not reported."""
        start = self._done
        skip = max(0, min(len(chunk), self._reported - start))
        if skip < len(chunk):
            self._found.append(UnparsedBytes(self._arrival(start + skip), chunk[skip:], reason, frame))
        self._reported = max(self._reported, start + len(chunk))

    def _arrival(self, offset: int) -> float:
        t = self._arrivals[0][1] if self._arrivals else time.monotonic()
        for start, when in self._arrivals:
            if start > offset:
                break
            t = when
        return t

    def _prune(self) -> None:
        arrivals = self._arrivals
        while len(arrivals) > 1 and arrivals[1][0] <= self._done:
            arrivals.pop(0)

    def take_unparsed(self) -> list[UnparsedBytes]:
        """The unparsed bytes found since the last call, in stream order."""
        with self._lock:
            out, self._found = self._found, []
            return out

    def stale(self, now: float, after: float = STALE) -> list[UnparsedBytes]:
        """An incomplete frame the parser holds, nothing having arrived for ``after`` seconds:
        reported once as unparsed (a truncated frame would wait forever otherwise); it stays
        in the parser, so the bytes that complete it still make a frame."""
        with self._lock:
            held = bytes(self._mav.buf[self._mav.buf_index:])
            if not held or self._reported >= self._fed or not self._arrivals:
                return []
            if now - self._arrivals[-1][1] < after:
                return []
            start = self._fed - len(held)
            skip = max(0, self._reported - start)
            self._reported = self._fed
            return [UnparsedBytes(self._arrival(start + skip), held[skip:],
                                  f"incomplete frame: {len(held)} bytes, then nothing for {after:g} s")]

    def holding(self) -> int:
        """Bytes of an incomplete frame the parser holds that were not reported yet."""
        with self._lock:
            return max(0, self._fed - max(self._reported, self._fed - (len(self._mav.buf) - self._mav.buf_index)))


class Encoder:
    """Packs messages from ``sysid``/``compid`` (one per link), MAVLink ``version`` 2 or 1.

    In MAVLink 1 a message is packed by its v1.0 definition (extension fields dropped, as
    the C library does); a message with an id above 255 cannot be sent and is skipped.
    """

    def __init__(self, sysid: int, compid: int, version: int = 2) -> None:
        self._mav = mavlink2.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._mav1 = mavlink1.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self.version = version

    def encode(self, msg: MAVLinkMessage) -> bytes:
        """The complete frame for ``msg`` (b"" if v1 cannot carry it); advances the seq."""
        if self.version == 1:
            cls = getattr(mavlink1, type(msg).__name__, None)
            if cls is None:
                return b""
            self._mav1.seq = self._mav.seq
            values = [getattr(msg, name) for name in cls.fieldnames]
            values = [v.encode("latin-1", "replace") if isinstance(v, str) else v for v in values]
            buf = cls(*values).pack(self._mav1)
        else:
            buf = msg.pack(self._mav)
        self._mav.seq = (self._mav.seq + 1) % 256
        return bytes(buf)


def frame_version(raw: bytes) -> int:
    """1 or 2 from a frame's start byte (0 when ``raw`` is not a frame)."""
    if raw[:1] == b"\xfd":
        return 2
    if raw[:1] == b"\xfe":
        return 1
    return 0

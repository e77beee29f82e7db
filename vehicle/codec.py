"""MAVLink framing for the vehicle, entirely through pymavlink (ardupilotmega).

``Decoder`` turns a byte stream (v1 and v2 frames mixed with any garbage) into decoded
messages plus a count of bytes that were not part of a valid frame; ``Encoder`` packs
messages as MAVLink v2 frames (or v1, for a peer that speaks only MAVLink 1) with its own
sequence counter (one per link).
"""

from __future__ import annotations

from pymavlink.dialects.v10 import ardupilotmega as mavlink1
from pymavlink.dialects.v20 import ardupilotmega as mavlink2
from pymavlink.dialects.v20.ardupilotmega import MAVLink_message as MAVLinkMessage

__all__ = ["Decoder", "Encoder", "MAVLinkMessage", "frame_version"]


class Decoder:
    """Incremental, never-raising MAVLink v1/v2 stream decoder (one per link)."""

    def __init__(self) -> None:
        self._mav = self._new_parser()
        #: Total bytes discarded as not belonging to a valid frame.
        self.bad_bytes = 0

    @staticmethod
    def _new_parser() -> mavlink2.MAVLink:
        mav = mavlink2.MAVLink(None)
        mav.robust_parsing = True
        return mav

    def feed(self, data: bytes) -> tuple[list[MAVLinkMessage], int, str | None]:
        """Decode ``data``; return (messages, bad byte count in this chunk, first reason)."""
        try:
            parsed = self._mav.parse_buffer(bytes(data)) or []
        except Exception as exc:  # pymavlink should not raise with robust_parsing; be safe
            self._mav = self._new_parser()
            self.bad_bytes += len(data)
            return [], len(data), f"parser error: {exc}"
        good: list[MAVLinkMessage] = []
        bad = 0
        reason: str | None = None
        for msg in parsed:
            if msg.get_type() == "BAD_DATA":
                bad += len(msg.data) if getattr(msg, "data", None) is not None else 1
                if reason is None:
                    reason = str(getattr(msg, "reason", "bad data"))
            else:
                good.append(msg)
        self.bad_bytes += bad
        return good, bad, reason


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

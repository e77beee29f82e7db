"""A scapy layer for the Nsqd TCP drone protocol, built from ``spec/nsqd.yaml``.

``NSQD`` is the frame header (the signed 32-bit length that counts itself, E-1, and the
message id with the spec's names); one body layer per message is generated from the
messages table (bool, byte, int16, int32, the integer "float" of E-2, int16-counted
strings), bound by id. The layer is bound to TCP on the backend's port (8888) both ways,
and ``NSQD.tcp_reassemble`` lets ``sniff(session=TCPSession)`` / ``sniff(offline=...)``
give whole frames from a stream cut anywhere (NSQD-FRM-2). For humans and pcaps; the
runner's hot path is ``spec.nsqd_codec``.
"""

from __future__ import annotations

import struct
from typing import Any

from scapy.fields import (
    ByteEnumField,
    ByteField,
    Field,
    FieldLenField,
    IntField,
    SignedIntField,
    StrLenField,
)
from scapy.layers.inet import TCP
from scapy.packet import Packet, bind_layers

from mcp_conform.spec import NSQD

__all__ = ["BODY_LAYERS", "MESSAGE_NAMES", "NSQD_Frame", "PORT"]

#: Message id -> name (ERROR, UPDATE, ...), from the spec.
MESSAGE_NAMES: dict[int, str] = {m.id: m.name for m in NSQD.messages}
PORT = NSQD.port("backend")
_PREFIX = NSQD.framing.prefix_width


def _fields(msg: Any) -> list[Any]:
    out: list[Any] = []
    for f in msg.fields:
        t = NSQD.types[f.type]
        if "length" in t:
            fmt = NSQD.types[t["length"]]["struct"]
            out.append(FieldLenField(f"{f.name}_len", None, length_of=f.name, fmt=fmt))
            out.append(StrLenField(f.name, b"", length_from=lambda pkt, n=f.name: max(0, getattr(pkt, f"{n}_len"))))  # type: ignore[misc]  # mypy: a default argument
        elif t["struct"] == ">B":
            out.append(ByteField(f.name, 0))
        elif t["struct"] == ">I":
            out.append(IntField(f.name, 0))
        elif t["struct"] == ">i":
            out.append(SignedIntField(f.name, 0))
        else:
            out.append(Field(f.name, 0, fmt=t["struct"]))
    return out


class NSQD_Frame(Packet):  # noqa: N801 - scapy layer names carry the protocol's spelling
    """One frame: ``length`` (this header included), ``msg_id``; the body is the next layer."""

    name = "NSQD"
    fields_desc = [SignedIntField("length", None), ByteEnumField("msg_id", 0, MESSAGE_NAMES)]  # type: ignore[arg-type]  # None: post_build fills it (scapy's convention, not in its stub)

    def post_build(self, pkt: bytes, pay: bytes) -> bytes:
        if self.length is None:
            pkt = struct.pack(NSQD.framing.prefix_struct, len(pkt) + len(pay)) + pkt[_PREFIX:]
        return pkt + pay

    def extract_padding(self, s: bytes) -> tuple[bytes, bytes]:
        n = max(0, int(self.length or 0) - NSQD.framing.header_size)
        return s[:n], s[n:]

    def mysummary(self) -> str:
        return str(self.sprintf("NSQD %NSQD_Frame.msg_id% len=%NSQD_Frame.length%"))

    @classmethod
    def tcp_reassemble(cls, data: bytes, metadata: dict[str, Any], session: Any = None) -> Packet | None:
        """A whole frame once the stream holds it (scapy's TCPSession calls this)."""
        if len(data) < _PREFIX:
            return None
        (length,) = struct.unpack_from(NSQD.framing.prefix_struct, data)
        if NSQD.framing.min_length <= length <= NSQD.framing.max_length and len(data) < length:
            return None
        return cls(data)


def _body_layer(msg: Any) -> type[Packet]:
    return type(f"NSQD_{msg.name}", (Packet,), {
        "name": f"NSQD {msg.name}", "fields_desc": _fields(msg), "__doc__": msg.doc,
        "extract_padding": lambda self, s: (b"", s)})


#: Message name -> its generated body layer.
BODY_LAYERS: dict[str, type[Packet]] = {}
for _m in NSQD.messages:
    if _m.fields:
        BODY_LAYERS[_m.name] = _body_layer(_m)
        bind_layers(NSQD_Frame, BODY_LAYERS[_m.name], msg_id=_m.id)
bind_layers(TCP, NSQD_Frame, sport=PORT)
bind_layers(TCP, NSQD_Frame, dport=PORT)

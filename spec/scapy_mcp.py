"""A scapy layer for MCP, built from ``spec/mcp.yaml``: for crafting by hand and pcap dissection.

``MCP.fields_desc`` is generated from the spec's header table (``!7s2B4H``, MCP-HDR-2), so the
layer cannot drift from the codec; the payload sub-layers are generated from the payload
layouts (the ACK's acknowledged sequence number and Mission_Ready's ID, big-endian per D-2;
the 37-byte mission item, little-endian per MCP-PAY-4/E-1; the counted lists of MCP-PAY-3).
Mav_Passthrough frames stay ``Raw``. The layer is bound to UDP on the spec's ports (7889 and
7890, MCP-TRN-1) in both directions, so ``rdpcap`` dissects MCP, and ``answers()`` pairs an
ACK with the message it acknowledges: "An ACK's payload is exactly 2 bytes: the acknowledged
message's sequence number" (MCP-ACK-2), "An ACK's dst is the src of the acknowledged message
and its src is the acknowledging node's ID" (MCP-ACK-3).

scapy is for humans and pcaps, never for a hot path (see bench/bench_codec.py).
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from typing import Any

from scapy.config import conf
from scapy.fields import (
    ByteField,
    Field,
    FieldLenField,
    PacketListField,
    ShortEnumField,
    ShortField,
    StrFixedLenField,
)
from scapy.layers.inet import UDP
from scapy.packet import Packet, bind_layers

from mcp_conform.spec import SPEC

__all__ = [
    "ACTION_NAMES",
    "MCP",
    "MCPAck",
    "MCPItemList",
    "MCPMissionItem",
    "MCPReadyId",
    "PORTS",
    "build_fields",
]

#: Action code -> wire name (Mission_Ready, ..., Mav_Passthrough, Any), from the spec.
ACTION_NAMES: dict[int, str] = {a.code: a.wire_name for a in SPEC.actions}
#: The UDP ports MCP is bound to (manager and drone, MCP-TRN-1).
PORTS: tuple[int, ...] = tuple(sorted(set(SPEC.protocol["ports"].values())))
_HEADER_SIZE = struct.calcsize(SPEC.header["struct"])
_ACK_CODE = next(a.code for a in SPEC.actions if a.payload_kind == "seq")


def _codes(kind: str) -> list[int]:
    return [a.code for a in SPEC.actions if a.on_wire and a.payload_kind == kind]


def _const_value(value: Any) -> Any:
    return value.encode("ascii") if isinstance(value, str) else value


def _field(name: str, code: str, order: str, default: Any,
           enum: Mapping[int, str] | None = None) -> Field[Any, Any]:
    """One scapy field for one struct code of the spec."""
    if code.endswith("s"):
        return StrFixedLenField(name, default if default is not None else b"", int(code[:-1] or 1))
    if order in "!>":
        if code == "B":
            return ByteField(name, default or 0)
        if code == "H":
            if enum is not None:
                return ShortEnumField(name, default or 0, dict(enum))
            return ShortField(name, default or 0)
    # Other codes and byte orders (the little-endian mission item): a plain struct field.
    return Field(name, default if default is not None else 0, fmt=order + code)


def build_fields(layout: Mapping[str, Any], enums: Mapping[str, Mapping[int, str]] | None = None,
                 ) -> list[Any]:
    """scapy fields for a spec layout (``struct`` plus ``fields`` with ``name``/``code``/``const``)."""
    order = layout["struct"][0]
    if order not in "@=<>!":
        order = "@"
    return [_field(f["name"], f["code"], order, _const_value(f["const"]) if "const" in f else None,
                   (enums or {}).get(f["name"]))
            for f in layout["fields"]]


class MCPMissionItem(Packet):
    """One 37-byte mission item: MAVLink v1 MISSION_ITEM payload, little-endian (MCP-PAY-4).

    Field names are the spec's; ``command`` is also a ``Packet`` method, so read that field
    with ``item.getfieldval("command")`` (``item.command`` is the method).
    """

    name = "MCP mission item"
    fields_desc = build_fields(SPEC.mission_item)

    def extract_padding(self, s: bytes) -> tuple[bytes, bytes]:
        return b"", s


class MCPItemList(Packet):
    """WP_List / Obstacles_List payload: u16 big-endian count, then the items (MCP-PAY-3)."""

    name = "MCP item list"
    fields_desc = [
        FieldLenField("count", None, count_of="items",
                      fmt=SPEC.payloads["item_list"]["count_struct"]),
        PacketListField("items", [], MCPMissionItem, count_from=lambda pkt: pkt.count),
    ]


class MCPAck(Packet):
    """ACK payload: the acknowledged message's sequence number, u16 big-endian (MCP-ACK-2)."""

    name = "MCP ACK"
    fields_desc = [_field("ack_seq", SPEC.payloads["ack"]["struct"][1:], SPEC.payloads["ack"]["struct"][0], 0)]


class MCPReadyId(Packet):
    """Mission_Ready's optional payload: the drone's ID, u16 big-endian (D-3)."""

    name = "MCP Mission_Ready ID"
    fields_desc = [_field("drone_id", SPEC.payloads["mission_ready"]["struct"][1:],
                          SPEC.payloads["mission_ready"]["struct"][0], 0)]


class MCP(Packet):
    """The MCP header (MCP-HDR-1/2), fields from the spec's header table."""

    name = "MCP"
    fields_desc = build_fields(SPEC.header, enums={"action": ACTION_NAMES})

    @classmethod
    def dispatch_hook(cls, _pkt: bytes | None = None, *args: Any, **kargs: Any) -> type[Packet]:
        """A datagram shorter than the header (MCP-ROB-1) dissects as ``Raw``, not as an error."""
        if _pkt is not None and len(_pkt) < _HEADER_SIZE:
            return conf.raw_layer  # type: ignore[no-any-return]
        return cls

    def mysummary(self) -> str:
        return str(self.sprintf("MCP %MCP.action% %MCP.src% > %MCP.dst% seq=%MCP.seq%"))

    def _acked_seq(self) -> int | None:
        """The sequence number an ACK acknowledges, or None when this is no ACK."""
        if self.action != _ACK_CODE:
            return None
        ack = self.getlayer(MCPAck)
        return None if ack is None else int(ack.ack_seq)

    def hashret(self) -> bytes:
        """Equal for a message and its ACK: (acknowledged seq, the two IDs unordered)."""
        acked = self._acked_seq()
        seq = self.seq if acked is None else acked
        low, high = sorted((self.dst, self.src))
        return struct.pack("!3H", seq, low, high)

    def answers(self, other: Packet) -> int:
        """True when ``self`` is the ACK of ``other`` (MCP-ACK-2, MCP-ACK-3; never ACK of an ACK, MCP-ACK-6)."""
        if not isinstance(other, MCP):
            return 0
        acked = self._acked_seq()
        if acked is None or other.action == _ACK_CODE:
            return 0
        return int(acked == other.seq and self.dst == other.src and self.src == other.dst)


_SUBLAYERS: dict[str, type[Packet]] = {
    "seq": MCPAck,
    "optional_id": MCPReadyId,
    "counted_items": MCPItemList,
    "single_item": MCPMissionItem,
}
for _kind, _layer in _SUBLAYERS.items():
    for _code in _codes(_kind):
        bind_layers(MCP, _layer, action=_code)
for _port in PORTS:
    bind_layers(UDP, MCP, sport=_port)
    bind_layers(UDP, MCP, dport=_port)

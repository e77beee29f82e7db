"""The MCP wire codec, derived from ``spec/mcp.yaml`` at import.

``encode(Message) -> bytes`` and ``decode(bytes) -> Message``. The header and mission-item
``struct.Struct`` tables are compiled from the spec's struct strings; each action code's
payload codec is chosen by the payload *kind* the spec gives it, so no message type has
hand-written packing. ``decode`` raises only :class:`DecodeError`, whose ``rule`` is the
violated rule ID (MCP-ROB-1/2/3/4, MCP-PAY-6), and ``try_decode`` returns that rule and
reason instead of raising; ``encode`` raises
:class:`LocalProtocolError` when our own caller builds a message the spec does not allow.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from enum import IntEnum
from functools import partial
from typing import Any, NamedTuple

from mcp_conform.spec import SPEC
from mcp_conform.spec.mavframe import FrameError, parse_frame

__all__ = [
    "Action",
    "BROADCAST_ID",
    "DecodeError",
    "Decoded",
    "HEADER",
    "HEADER_SIZE",
    "ITEM",
    "COUNT_SIZE",
    "ITEM_SIZE",
    "LocalProtocolError",
    "MANAGER_ID",
    "MAX_DATAGRAM",
    "Message",
    "MissionItem",
    "PREAMBLE",
    "Payload",
    "build_datagram",
    "decode",
    "encode",
    "encode_payload",
    "peek_header",
    "try_decode",
]

# ---------------------------------------------------------------- derived constants
HEADER = struct.Struct(SPEC.header["struct"])
HEADER_SIZE: int = HEADER.size
PREAMBLE: bytes = SPEC.preamble
_PREAMBLE_CONSTS = tuple(
    (f["const"].encode("ascii") if isinstance(f["const"], str) else f["const"])
    for f in SPEC.header["fields"] if "const" in f
)
_HEADER_FIELDS = tuple(f["name"] for f in SPEC.header["fields"] if "const" not in f)
ITEM = struct.Struct(SPEC.mission_item["struct"])
ITEM_SIZE: int = ITEM.size
MANAGER_ID: int = SPEC.protocol["manager_id"]
BROADCAST_ID: int = SPEC.protocol["broadcast_id"]
MAX_DATAGRAM: int = SPEC.protocol["max_datagram"]

class Action(IntEnum):
    """MCP action codes (MISSION_READY = 0 ... MAV_PASSTHROUGH = 8, and ANY = 9, an API
    filter that never goes on the wire, MCP-HDR-3). Declared for type checkers and checked
    against the spec's action table at import: the spec stays the source of truth."""

    MISSION_READY = 0
    START_MISSION = 1
    END_MISSION = 2
    WP_LIST = 3
    WP_ON = 4
    WP_OFF = 5
    OBSTACLES_LIST = 6
    ACK = 7
    MAV_PASSTHROUGH = 8
    ANY = 9


if [(a.name, int(a)) for a in Action] != [(a.name, a.code) for a in SPEC.actions]:
    raise ImportError(f"spec action table {[(a.name, a.code) for a in SPEC.actions]} does not match Action")


class MissionItem(NamedTuple):
    """A mission item: the MAVLink v1 MISSION_ITEM payload, 37 bytes (MCP-PAY-4, E-1, E-2).

    Fields follow spec/mcp.yaml's mission_item table (checked at import)."""

    param1: float
    param2: float
    param3: float
    param4: float
    x: float  # latitude (E-2)
    y: float  # longitude (E-2)
    z: float  # altitude
    seq: int
    command: int  # MAV_CMD
    target_system: int
    target_component: int
    frame: int  # MAV_FRAME
    current: int
    autocontinue: int


if MissionItem._fields != tuple(f["name"] for f in SPEC.mission_item["fields"]):
    raise ImportError(f"spec mission_item fields do not match MissionItem {MissionItem._fields}")

Payload = Any  # None | int | MissionItem | tuple[MissionItem, ...] | bytes


class Message(NamedTuple):
    """One MCP message. ``payload`` is typed by ``action``:

    - Mission_Ready: ``None`` or the drone's ID (int, D-3)
    - Start_Mission, End_Mission, WP_Off: ``None``
    - WP_List, Obstacles_List: ``tuple[MissionItem, ...]``
    - WP_On: one ``MissionItem``
    - ACK: the acknowledged sequence number (int)
    - Mav_Passthrough: the raw MAVLink frame (bytes)
    """

    dst: int
    src: int
    seq: int
    action: Action
    payload: Payload = None


if Message._fields[:-1] != _HEADER_FIELDS:  # the record follows the spec's header table
    raise ImportError(f"spec header fields {_HEADER_FIELDS} do not match Message {Message._fields}")


class DecodeError(ValueError):
    """A datagram is not a well-formed MCP message; ``rule`` names the violated rule."""

    def __init__(self, rule: str, reason: str) -> None:
        super().__init__(f"{rule}: {reason}")
        self.rule = rule
        self.reason = reason


class LocalProtocolError(ValueError):
    """Our own caller asked to encode something the spec does not allow."""


# ---------------------------------------------------------------- payload codecs by kind
_U16 = struct.Struct("!H")
#: WP_List / Obstacles_List: the count before the items, as the spec lays it out (D-2)
_COUNT = struct.Struct(SPEC.payloads["item_list"]["count_struct"])
COUNT_SIZE: int = _COUNT.size
_ACTIONS: tuple[Action, ...] = tuple(sorted((a for a in Action if SPEC.actions[a].on_wire), key=int))
_make_item = MissionItem._make
_iter_items = ITEM.iter_unpack


class _Reject(tuple[str, str]):
    """``(rule, reason)``: a payload decoder's verdict on a malformed payload, returned (not
    raised: a flood of malformed datagrams costs no exception per datagram). No payload a
    decoder returns is of this type, so ``type(p) is _Reject`` tells them apart."""

    __slots__ = ()


def _dec_empty(data: bytes, n: int, src: int) -> _Reject | None:
    if n != HEADER_SIZE:
        return _Reject(("MCP-ROB-4", f"payload of {n - HEADER_SIZE} bytes where this action has none"))
    return None


def _dec_optional_id(data: bytes, n: int, src: int) -> int | _Reject | None:
    if n == HEADER_SIZE:
        return None
    if n != HEADER_SIZE + 2:
        return _Reject(("MCP-ROB-4", f"Mission_Ready payload of {n - HEADER_SIZE} bytes (0 or 2 allowed, D-3)"))
    (ident,) = _U16.unpack_from(data, HEADER_SIZE)
    if ident != src:
        return _Reject(("MCP-ROB-4", f"Mission_Ready carries ID {ident} but src is {src} (D-3)"))
    return ident


def _dec_seq(data: bytes, n: int, src: int) -> int | _Reject:
    if n != HEADER_SIZE + 2:
        return _Reject(("MCP-ROB-4", f"ACK payload of {n - HEADER_SIZE} bytes (exactly 2 required)"))
    return _U16.unpack_from(data, HEADER_SIZE)[0]


def _dec_items(data: bytes, n: int, src: int) -> tuple[Any, ...]:
    if n < HEADER_SIZE + COUNT_SIZE:
        return _Reject(("MCP-ROB-4", f"list payload of {n - HEADER_SIZE} bytes has no {COUNT_SIZE}-byte count"))
    (count,) = _COUNT.unpack_from(data, HEADER_SIZE)
    want = HEADER_SIZE + COUNT_SIZE + ITEM_SIZE * count
    if n != want:
        return _Reject(("MCP-ROB-4", f"count {count} needs {want} bytes, datagram has {n}"))
    return tuple(map(_make_item, _iter_items(memoryview(data)[HEADER_SIZE + COUNT_SIZE:])))


def _dec_item(data: bytes, n: int, src: int) -> Any:
    if n != HEADER_SIZE + ITEM_SIZE:
        return _Reject(("MCP-ROB-4", f"WP_On payload of {n - HEADER_SIZE} bytes (exactly {ITEM_SIZE} required)"))
    return _make_item(ITEM.unpack_from(data, HEADER_SIZE))


def _dec_frame(data: bytes, n: int, src: int) -> bytes | _Reject:
    frame = bytes(data[HEADER_SIZE:])
    try:
        parse_frame(frame)
    except FrameError as exc:
        return _Reject(("MCP-PAY-6", str(exc)))
    return frame


def _enc_empty(payload: Any) -> bytes:
    if payload is not None and payload != b"":
        raise LocalProtocolError(f"this action carries no payload, got {payload!r}")
    return b""


def _enc_optional_id(payload: Any) -> bytes:
    return b"" if payload is None else _enc_seq(payload)


def _enc_seq(payload: Any) -> bytes:
    if not isinstance(payload, int) or not 0 <= payload <= 0xFFFF:
        raise LocalProtocolError(f"expected a u16, got {payload!r}")
    return _U16.pack(payload)


def _pack_item(item: Any) -> bytes:
    try:
        return ITEM.pack(*item)
    except (struct.error, TypeError) as exc:
        raise LocalProtocolError(f"bad mission item {item!r}: {exc}") from None


def _enc_items(payload: Any) -> bytes:
    items = tuple(payload)
    if len(items) > 0xFFFF:
        raise LocalProtocolError(f"{len(items)} items do not fit a u16 count")
    return _COUNT.pack(len(items)) + b"".join(map(_pack_item, items))


def _enc_item(payload: Any) -> bytes:
    return _pack_item(payload)


def _enc_frame(payload: Any) -> bytes:
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        raise LocalProtocolError(f"Mav_Passthrough payload must be frame bytes, got {type(payload).__name__}")
    return bytes(payload)


_KINDS: dict[str, tuple[Callable[..., Any], Callable[[Any], bytes]]] = {
    "empty": (_dec_empty, _enc_empty),
    "optional_id": (_dec_optional_id, _enc_optional_id),
    "seq": (_dec_seq, _enc_seq),
    "counted_items": (_dec_items, _enc_items),
    "single_item": (_dec_item, _enc_item),
    "mavlink_frame": (_dec_frame, _enc_frame),
}
_DECODERS = tuple(_KINDS[SPEC.actions[a].payload_kind][0] for a in _ACTIONS)
_ENCODERS = tuple(_KINDS[SPEC.actions[a].payload_kind][1] for a in _ACTIONS)
_N_ACTIONS = len(_ACTIONS)
_unpack_header = HEADER.unpack_from
#: ``Message`` from a 5-tuple without the Python-level ``__new__`` a NamedTuple call runs
_new_message = partial(tuple.__new__, Message)
_pack_header = HEADER.pack
_P0, _P1, _P2 = _PREAMBLE_CONSTS
_PRE_LEN = len(PREAMBLE)


# ---------------------------------------------------------------- public API
#: ``(message, None)`` or ``(None, (rule, reason))``: what :func:`try_decode` returns.
Decoded = tuple[Message | None, tuple[str, str] | None]
#: malformed datagrams already decoded, ``bytes -> (None, (rule, reason))``: decode is a
#: function of the bytes, so one seen again is answered from here (the MCP-ROB-7 flood's
#: 10,000 cycle through a few dozen). At most ``_MEMO_MAX`` of at most ``_MEMO_BYTES``, all
#: forgotten when full.
_memo: dict[bytes, Decoded] = {}
_MEMO_MAX = 64
_MEMO_BYTES = 1024
#: the last well-formed ``bytes`` object decoded and its answer: the same object read again is
#: answered from here (``is``, never an equal one: well-formed datagrams rarely repeat), e.g. by
#: the simulator's mutant drone and then its endpoint. Its first key is one no caller holds.
_last: tuple[Any, Decoded] = (object(), (None, None))
_PREAMBLE_HEX = PREAMBLE.hex(" ")


def decode(data: bytes) -> Message:
    """Decode one datagram. Raises only :class:`DecodeError` (with ``.rule``)."""
    msg, bad = try_decode(data)
    if bad is not None:
        raise DecodeError(*bad)
    return msg  # type: ignore[return-value]  # (message, None)


def try_decode(data: bytes) -> Decoded:
    """Decode one datagram without raising: ``(message, None)``, or ``(None, (rule, reason))``
    where :func:`decode` would raise ``DecodeError(rule, reason)`` (the node's hot path: a
    malformed datagram, MCP-ROB-1..4 and PAY-6, costs no exception). Answers are immutable."""
    global _last
    last = _last
    if data is last[0]:
        return last[1]
    if type(data) is not bytes:  # a bytearray may change: not remembered
        return _decode(data)
    small = len(data) <= _MEMO_BYTES
    if small and (out := _memo.get(data)) is not None:
        return out
    out = _decode(data)
    if out[1] is None:
        _last = (data, out)
    elif small:
        if len(_memo) >= _MEMO_MAX:
            _memo.clear()  # (one call: other threads may decode meanwhile)
        _memo[data] = out
    return out


def _decode(data: bytes) -> Decoded:
    try:
        n = len(data)
    except TypeError:
        return None, ("MCP-ROB-1", f"not a datagram: {type(data).__name__}")
    if n < HEADER_SIZE:
        return None, ("MCP-ROB-1", f"datagram of {n} bytes is shorter than the {HEADER_SIZE}-byte header")
    if data[:_PRE_LEN] != PREAMBLE:
        return None, ("MCP-ROB-2", f"preamble {bytes(data[:_PRE_LEN]).hex(' ')} is not {_PREAMBLE_HEX}")
    _, _, _, dst, src, seq, action = _unpack_header(data)
    if action >= _N_ACTIONS:
        return None, ("MCP-ROB-3", f"action code {action} is not 0-{_N_ACTIONS - 1}")
    payload = _DECODERS[action](data, n, src)
    if type(payload) is _Reject:
        return None, payload
    return _new_message((dst, src, seq, _ACTIONS[action], payload)), None


def encode_payload(action: int, payload: Any) -> bytes:
    """The payload bytes of ``payload`` for ``action`` (validated like :func:`encode`)."""
    if not 0 <= action < _N_ACTIONS:
        raise LocalProtocolError(f"action {action!r} cannot go on the wire (MCP-HDR-3)")
    return _ENCODERS[action](payload)


def encode(msg: Message) -> bytes:
    """Encode one message. Raises :class:`LocalProtocolError` on a message the spec forbids."""
    dst, src, seq, action, payload = msg
    if not 0 <= action < _N_ACTIONS:
        raise LocalProtocolError(f"action {action!r} cannot go on the wire (MCP-HDR-3)")
    try:
        head = _pack_header(_P0, _P1, _P2, dst, src, seq, action)
    except struct.error as exc:
        raise LocalProtocolError(f"header field out of range in {msg!r}: {exc}") from None
    return head + _ENCODERS[action](payload)


def build_datagram(dst: int, src: int, seq: int, action: int, payload: bytes = b"",
                   preamble: bytes = PREAMBLE) -> bytes:
    """Raw datagram with no validation of the payload: for crafting malformed input."""
    return preamble + struct.pack("!4H", dst & 0xFFFF, src & 0xFFFF, seq & 0xFFFF, action & 0xFFFF) + payload


def peek_header(data: bytes, *, require_preamble: bool = True) -> tuple[int, int, int, int] | None:
    """(dst, src, seq, action) of anything with a whole header (and, unless
    ``require_preamble=False``, the right preamble), else None.

    For observers that must attribute a reply even when its payload is malformed; a runner
    passes ``require_preamble=False`` to recognise a node's Mission_Ready or ACK whose framing
    is wrong, so that MCP-HDR-1 fails and not every case after it.
    """
    if len(data) < HEADER_SIZE or (require_preamble and data[:_PRE_LEN] != PREAMBLE):
        return None
    return tuple(_unpack_header(data)[3:])  # type: ignore[return-value]

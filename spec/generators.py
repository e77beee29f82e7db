"""Generators derived from ``spec/mcp.yaml`` that need no hypothesis: valid messages and
malformed datagrams per kind built from a seeded ``random.Random`` (``random_message``,
``random_malformed``, ``random_mavlink_frame``), and the fixed malformed corpus the
conformance runner sends (``malformed_corpus``: same seed, same bytes, in any process).

The builders take a small chooser interface; ``spec.strategies`` runs the very same builders
with hypothesis's draws, so the corpus is drawn from exactly the strategies' space. The
runner imports this module only, so it never pays for importing hypothesis.
"""

from __future__ import annotations

import random
import string
import struct
from collections.abc import Callable, Sequence
from typing import Any, Protocol, TypeVar

from pymavlink.dialects.v10 import ardupilotmega as mavlink1
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import (
    HEADER_SIZE,
    ITEM_SIZE,
    PREAMBLE,
    Action,
    Message,
    MissionItem,
    build_datagram,
    encode,
    encode_payload,
)
from mcp_conform.spec.mavframe import pack_message

__all__ = [
    "MALFORMED_KINDS",
    "WIRE_ACTIONS",
    "malformed_corpus",
    "random_malformed",
    "random_mavlink_frame",
    "random_message",
]

T = TypeVar("T")

#: Malformed kind -> the rule ``decode`` cites when it rejects it.
MALFORMED_KINDS: dict[str, str] = {
    "short": "MCP-ROB-1",
    "bad_preamble": "MCP-ROB-2",
    "unknown_action": "MCP-ROB-3",
    "wrong_payload_length": "MCP-ROB-4",
    "count_mismatch": "MCP-ROB-4",
    "bad_mavlink_crc": "MCP-PAY-6",
}
#: The action codes that go on the wire (0-8; 9 "Any" never does, MCP-HDR-3).
WIRE_ACTIONS: tuple[Action, ...] = tuple(Action(a.code) for a in SPEC.actions if a.on_wire)
_KIND_OF: dict[Action, str] = {Action(a.code): a.payload_kind for a in SPEC.actions if a.on_wire}
_ACK = next(a for a in WIRE_ACTIONS if _KIND_OF[a] == "seq")
_N_ACTIONS = len(WIRE_ACTIONS)
_MAX_ITEMS = 4  # items per drawn list: enough to exercise counts, small enough to be fast
_F32_MAX = struct.unpack("<f", b"\xff\xff\x7f\x7f")[0]
_F32_EDGES = (0.0, -0.0, 1.0, -1.0, float("inf"), float("-inf"), _F32_MAX, -_F32_MAX, 1e-45)
_PRINTABLE = string.ascii_letters + string.digits + " .,:-_"


# ---------------------------------------------------------------- choosers
class _Chooser(Protocol):
    def integer(self, lo: int, hi: int) -> int: ...
    def choice(self, options: Sequence[T]) -> T: ...
    def float32(self) -> float: ...
    def blob(self, lo: int, hi: int) -> bytes: ...


class _RandomChooser:
    """Choices from a seeded ``random.Random``: the same seed gives the same bytes."""

    def __init__(self, rng: random.Random) -> None:
        self._rng = rng

    def integer(self, lo: int, hi: int) -> int:
        return self._rng.randint(lo, hi)

    def choice(self, options: Sequence[T]) -> T:
        return options[self._rng.randrange(len(options))]

    def float32(self) -> float:
        if self._rng.random() < 0.2:
            return self.choice(_F32_EDGES)
        value = self._rng.uniform(-1e6, 1e6)
        return float(struct.unpack("<f", struct.pack("<f", value))[0])

    def blob(self, lo: int, hi: int) -> bytes:
        return self._rng.randbytes(self._rng.randint(lo, hi))


# ---------------------------------------------------------------- valid builders
def _item(c: _Chooser) -> MissionItem:
    """One mission item: float32 for each ``f`` field, the full range for each integer one."""
    values: list[float | int] = []
    for f in SPEC.mission_item["fields"]:
        code = f["code"]
        if code == "f":
            values.append(c.float32())
        else:
            values.append(c.integer(0, (1 << (8 * struct.calcsize(code))) - 1))
    return MissionItem._make(values)


def _mavlink_frame(c: _Chooser) -> bytes:
    """One MAVLink v1 or v2 frame with a good CRC, packed by pymavlink (MCP-PAY-6)."""
    version = c.choice((1, 2))
    mod: Any = mavlink1 if version == 1 else mavlink2
    kind = c.choice(("HEARTBEAT", "STATUSTEXT", "COMMAND_LONG", "SET_MODE"))
    u8 = lambda: c.integer(0, 0xFF)  # noqa: E731
    if kind == "HEARTBEAT":
        msg = mod.MAVLink_heartbeat_message(u8(), u8(), u8(), c.integer(0, 0xFFFFFFFF), u8(), u8())
    elif kind == "STATUSTEXT":
        text = bytes(ord(_PRINTABLE[b % len(_PRINTABLE)]) for b in c.blob(0, 50))
        msg = mod.MAVLink_statustext_message(c.integer(0, 7), text)
    elif kind == "COMMAND_LONG":
        msg = mod.MAVLink_command_long_message(u8(), u8(), c.integer(0, 0xFFFF), u8(),
                                               *(c.float32() for _ in range(7)))
    else:
        msg = mod.MAVLink_set_mode_message(u8(), u8(), c.integer(0, 0xFFFFFFFF))
    return pack_message(msg, src_system=u8(), src_component=u8(), seq=u8(), version=version)


def _payload(c: _Chooser, action: Action, src: int) -> Any:
    kind = _KIND_OF[action]
    if kind == "empty":
        return None
    if kind == "optional_id":
        return c.choice((None, src))  # D-3: empty, or the ID equal to src
    if kind == "seq":
        return c.integer(0, 0xFFFF)
    if kind == "counted_items":
        return tuple(_item(c) for _ in range(c.integer(0, _MAX_ITEMS)))
    if kind == "single_item":
        return _item(c)
    if kind == "mavlink_frame":
        return _mavlink_frame(c)
    raise AssertionError(f"payload kind {kind!r} has no builder")  # a new kind in the spec


def _message(c: _Chooser, action: Action | None = None, dst: int | None = None,
             src: int | None = None, seq: int | None = None,
             actions: Sequence[Action] = WIRE_ACTIONS) -> Message:
    act = action if action is not None else c.choice(actions)
    d = dst if dst is not None else c.integer(0, 0xFFFF)
    s = src if src is not None else c.integer(0, 0xFFFF)
    q = seq if seq is not None else c.integer(0, 0xFFFF)
    return Message(d, s, q, act, _payload(c, act, s))


# ---------------------------------------------------------------- malformed builders
def _short(c: _Chooser, dst: int, src: int, seq: int, acks: bool) -> bytes:
    """MCP-ROB-1: fewer than 17 bytes (a cut valid datagram, or noise)."""
    if c.choice((True, False)):
        whole = encode(_message(c, dst=dst, src=src, seq=seq, actions=_actions(acks)))
        return whole[:c.integer(0, HEADER_SIZE - 1)]
    return c.blob(0, HEADER_SIZE - 1)


def _bad_preamble(c: _Chooser, dst: int, src: int, seq: int, acks: bool) -> bytes:
    """MCP-ROB-2: a valid datagram whose 9-byte preamble has one or more bytes changed."""
    data = bytearray(encode(_message(c, dst=dst, src=src, seq=seq, actions=_actions(acks))))
    for _ in range(c.integer(1, 3)):
        data[c.integer(0, len(PREAMBLE) - 1)] ^= c.integer(1, 0xFF)
    if bytes(data[:len(PREAMBLE)]) == PREAMBLE:  # two flips cancelled out
        data[0] ^= 0xFF
    return bytes(data)


def _unknown_action(c: _Chooser, dst: int, src: int, seq: int, acks: bool) -> bytes:
    """MCP-ROB-3: an action code above 8 (9, "Any", included: it never goes on the wire)."""
    return build_datagram(dst, src, seq, c.integer(_N_ACTIONS, 0xFFFF), c.blob(0, 64))


def _wrong_length(n_lo: int, n_hi: int, right: Sequence[int], c: _Chooser) -> int:
    """A length in [n_lo, n_hi] that is none of ``right``."""
    wrong = [n for n in range(n_lo, n_hi + 1) if n not in right]
    return c.choice(wrong)


def _wrong_payload_length(c: _Chooser, dst: int, src: int, seq: int, acks: bool) -> bytes:
    """MCP-ROB-4: a payload whose length no valid payload of the action code has."""
    action = c.choice([a for a in _actions(acks) if _KIND_OF[a] != "mavlink_frame"])
    kind = _KIND_OF[action]
    if kind == "empty":
        n = c.integer(1, 64)
    elif kind in ("optional_id", "seq"):
        n = _wrong_length(0, 40, (0, 2) if kind == "optional_id" else (2,), c)
    elif kind == "single_item":
        n = _wrong_length(0, 2 * ITEM_SIZE, (ITEM_SIZE,), c)
    else:  # counted_items: not even room for the 2-byte count
        n = c.integer(0, 1)
    good = encode_payload(action, _payload(c, action, src)) if kind == "single_item" else b""
    body = (good + c.blob(n, n))[:n]
    return build_datagram(dst, src, seq, action, body)


def _count_mismatch(c: _Chooser, dst: int, src: int, seq: int, acks: bool) -> bytes:
    """MCP-ROB-4: a WP_List/Obstacles_List whose count disagrees with the items that follow."""
    action = c.choice([a for a in WIRE_ACTIONS if _KIND_OF[a] == "counted_items"])
    items = b"".join(_packed_item(c) for _ in range(c.integer(0, _MAX_ITEMS)))
    k = len(items) // ITEM_SIZE
    if c.choice((True, False)):
        count = c.choice([n for n in (0, 1, 2, 3, 4, 5, 0xFFFF) if n != k] + [c.integer(0, 0xFFFF)])
        if count == k:
            count = (k + 1) & 0xFFFF
        tail = b""
    else:  # the count is right but a partial item trails
        count = k
        tail = c.blob(1, ITEM_SIZE - 1)
    return build_datagram(dst, src, seq, action, struct.pack("!H", count) + items + tail)


def _packed_item(c: _Chooser) -> bytes:
    single = next(a for a in WIRE_ACTIONS if _KIND_OF[a] == "single_item")
    return encode_payload(single, _item(c))


def _bad_mavlink_crc(c: _Chooser, dst: int, src: int, seq: int, acks: bool) -> bytes:
    """MCP-PAY-6: a Mav_Passthrough whose one MAVLink frame has a corrupted checksum byte."""
    frame = bytearray(_mavlink_frame(c))
    frame[len(frame) - c.integer(1, 2)] ^= c.integer(1, 0xFF)
    action = next(a for a in WIRE_ACTIONS if _KIND_OF[a] == "mavlink_frame")
    return build_datagram(dst, src, seq, action, bytes(frame))


def _actions(acks: bool) -> tuple[Action, ...]:
    return WIRE_ACTIONS if acks else tuple(a for a in WIRE_ACTIONS if a != _ACK)


_BUILDERS: dict[str, Callable[[_Chooser, int, int, int, bool], bytes]] = {
    "short": _short,
    "bad_preamble": _bad_preamble,
    "unknown_action": _unknown_action,
    "wrong_payload_length": _wrong_payload_length,
    "count_mismatch": _count_mismatch,
    "bad_mavlink_crc": _bad_mavlink_crc,
}
assert set(_BUILDERS) == set(MALFORMED_KINDS)


def _edge_cases(kind: str, dst: int, src: int, seq: int) -> list[bytes]:
    """Hand-picked inputs of each kind, at the front of every corpus."""
    start = next(a for a in WIRE_ACTIONS if _KIND_OF[a] == "empty")
    whole = build_datagram(dst, src, seq, start)
    wp_list = next(a for a in WIRE_ACTIONS if _KIND_OF[a] == "counted_items")
    wp_on = next(a for a in WIRE_ACTIONS if _KIND_OF[a] == "single_item")
    passthrough = next(a for a in WIRE_ACTIONS if _KIND_OF[a] == "mavlink_frame")
    item = encode_payload(wp_on, MissionItem(0.0, 0.0, 0.0, 0.0, 35.771332, -78.674421, 3.0,
                                             0, 16, 0, 0, 3, 0, 1))

    def bad_crc(version: int) -> bytes:
        frame = bytearray(pack_message(
            (mavlink1 if version == 1 else mavlink2).MAVLink_heartbeat_message(6, 8, 0, 0, 4, 3),
            version=version))
        frame[-1] ^= 0xFF
        return build_datagram(dst, src, seq, passthrough, bytes(frame))

    return {
        "short": [b"", whole[:len(PREAMBLE)], whole[:HEADER_SIZE - 1]],
        "bad_preamble": [bytes(len(PREAMBLE)) + whole[len(PREAMBLE):],
                         PREAMBLE[:-1] + b"\x02" + whole[len(PREAMBLE):]],
        "unknown_action": [build_datagram(dst, src, seq, _N_ACTIONS),
                           build_datagram(dst, src, seq, 0xFFFF)],
        "wrong_payload_length": [whole + b"\x00", build_datagram(dst, src, seq, wp_on, item[:-1])],
        "count_mismatch": [build_datagram(dst, src, seq, wp_list, b"\x00\x01"),
                           build_datagram(dst, src, seq, wp_list, b"\x00\x00" + item)],
        "bad_mavlink_crc": [bad_crc(1), bad_crc(2)],
    }[kind]


def random_message(rng: random.Random, action: Action | int | None = None, *,
                   dst: int | None = None, src: int | None = None, seq: int | None = None,
                   actions: Sequence[Action] = WIRE_ACTIONS) -> Message:
    """One valid message drawn from :func:`messages`' space by a seeded ``random.Random``
    (the fuzzer's fast path: no hypothesis engine per draw)."""
    act = None if action is None else Action(action)
    return _message(_RandomChooser(rng), act, dst, src, seq, actions)


def random_mavlink_frame(rng: random.Random) -> bytes:
    """One MAVLink v1 or v2 frame with a good CRC, as :func:`messages` draws for Mav_Passthrough."""
    return _mavlink_frame(_RandomChooser(rng))


def random_malformed(rng: random.Random, kind: str, *, dst: int, src: int, seq: int) -> bytes:
    """One datagram of malformed ``kind`` (see :data:`MALFORMED_KINDS`) from a seeded ``rng``."""
    if kind not in MALFORMED_KINDS:
        raise ValueError(f"unknown malformed kind {kind!r}; known: {', '.join(MALFORMED_KINDS)}")
    return _BUILDERS[kind](_RandomChooser(rng), dst, src, seq, False)


def malformed_corpus(seed: int, per_kind: int, *, dst: int = 1, src: int = 0,
                     first_seq: int = 0, kinds: Sequence[str] | None = None,
                     ) -> list[tuple[str, bytes]]:
    """A fixed malformed corpus: ``per_kind`` entries of each kind, deterministic for ``seed``.

    Each kind starts with its hand-picked edge cases, then seeded random draws. Wherever a
    header exists, the entry is a non-ACK message from ``src`` to ``dst`` with its own
    sequence number (``first_seq``, ``first_seq + 1``, ... modulo 65536), so an ACK that
    comes back names the entry it answers.
    """
    chosen = list(kinds) if kinds is not None else list(MALFORMED_KINDS)
    for k in chosen:
        if k not in MALFORMED_KINDS:
            raise ValueError(f"unknown malformed kind {k!r}; known: {', '.join(MALFORMED_KINDS)}")
    rng = random.Random(f"mcp-conform/malformed/{seed}")
    c = _RandomChooser(rng)
    out: list[tuple[str, bytes]] = []
    seq = first_seq
    for k in chosen:
        for i in range(per_kind):
            s = seq & 0xFFFF
            edges = _edge_cases(k, dst, src, s)
            data = edges[i] if i < len(edges) else _BUILDERS[k](c, dst, src, s, False)
            out.append((k, data))
            seq += 1
    return out


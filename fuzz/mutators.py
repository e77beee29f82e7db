"""The stateless engine's inputs: valid messages from the spec's strategies and mutations of
them (issue 11, "Stateless engine").

A :class:`CaseGenerator` draws one case at a time from a seeded ``random.Random`` (the same
seed gives the same bytes in any process): a valid message of any on-wire action code
(:func:`spec.generators.random_message`), a malformed kind of the spec's strategies
(:func:`spec.generators.random_malformed`), a seed datagram from a capture, or one of those
mutated: bit and byte flips, header fields at their boundary values, length lies and
truncation, concatenation, preamble damage, wrong action codes, counts that disagree with the
payload, broken MAVLink frames in Mav_Passthrough, oversized datagrams up to 65,507 bytes
(MCP-ROB-6's limit, ``spec.codec.MAX_DATAGRAM``).

Every case addressed by its header gets a fresh sequence number from the fuzzer's counter
(unless a mutation set the field on purpose), so an ACK names the case it answers.
Passthrough frames are vehicle probes (``vehicle.make_probe``) so the autopilot's record
says which case reached it.
"""

from __future__ import annotations

import random
import struct
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from mcp_conform.spec.codec import (
    HEADER_SIZE,
    ITEM_SIZE,
    MAX_DATAGRAM,
    PREAMBLE,
    Action,
    Message,
    encode,
)
from mcp_conform.spec.generators import (
    MALFORMED_KINDS,
    WIRE_ACTIONS,
    random_malformed,
    random_message,
)
from mcp_conform.vehicle.probe import make_probe

__all__ = ["MUTATORS", "Case", "CaseGenerator"]

_PRE = len(PREAMBLE)
_DST, _SRC, _SEQ, _ACT = _PRE, _PRE + 2, _PRE + 4, _PRE + 6  # header field offsets
_U16 = struct.Struct("!H")
_PASSTHROUGH = Action.MAV_PASSTHROUGH
_COUNTED = (Action.WP_LIST, Action.OBSTACLES_LIST)
_N_ACTIONS = len(WIRE_ACTIONS)
#: Commands that end the node's mission: never sent valid to the node by the stateless
#: engine (a node may stop receiving after End_Mission, D-6; that is the stateful engine's).
_ENDS_MISSION = (Action.END_MISSION,)


@dataclass(frozen=True)
class Case:
    """One input: how it was made, its bytes, the probe token its passthrough carries."""

    mutator: str
    data: bytes
    token: str | None = None


class CaseGenerator:
    """Seeded cases for one node (``node_id``) from one manager (``our_id``)."""

    def __init__(self, seed: int, node_id: int, broadcast_id: int, *, our_id: int = 0,
                 seeds: Sequence[bytes] = (), next_seq: Callable[[int], int] | None = None,
                 worker: int = 0) -> None:
        self.rng = random.Random(f"mcp-fuzz/stateless/{seed}/{worker}")
        self.node_id = node_id
        self.broadcast_id = broadcast_id
        self.our_id = our_id
        self.seeds = list(seeds)
        self._seq: dict[int, int] = {}
        self._next_seq = next_seq or self._own_seq
        self._tokens = 0
        self._prefix = f"f{seed % 1000}w{worker}n"

    # ------------------------------------------------------------------ helpers
    def _own_seq(self, src: int) -> int:
        s = self._seq.get(src, 0)
        self._seq[src] = (s + 1) & 0xFFFF
        return s

    def token(self) -> str:
        self._tokens += 1
        return f"{self._prefix}{self._tokens}"

    def _dst(self) -> int:
        r = self.rng.random()
        if r < 0.75:
            return self.node_id
        if r < 0.85:
            return self.broadcast_id
        return self.rng.choice([x for x in (self.node_id + 1, 0, 0x7FFF, 0xFFFE) if x != self.node_id])

    def _src(self) -> int:
        if self.rng.random() < 0.85:
            return self.our_id
        return self.rng.choice([s for s in (1, 2, 0x7777, 0xFFFE) if s != self.node_id])

    def valid(self, action: Action | None = None) -> Case:
        """A valid message (End_Mission to the node or broadcast replaced by WP_Off)."""
        rng = self.rng
        act = action if action is not None else rng.choice(WIRE_ACTIONS)
        dst = self._dst()
        if act in _ENDS_MISSION and dst in (self.node_id, self.broadcast_id):
            act = Action.WP_OFF
        src = self._src()
        seq = self._next_seq(src)
        token = None
        if act == _PASSTHROUGH:
            token = self.token()
            msg = Message(dst, src, seq, act, make_probe(token, seq=rng.randrange(256),
                                                         version=rng.choice((1, 2))))
        else:
            msg = random_message(rng, act, dst=dst, src=src, seq=seq)
        return Case("valid", encode(msg), token)

    def malformed(self) -> Case:
        kind = self.rng.choice(tuple(MALFORMED_KINDS))
        src = self._src()
        return Case(f"kind:{kind}", random_malformed(self.rng, kind, dst=self._dst(), src=src,
                                                     seq=self._next_seq(src)))

    def base(self) -> Case:
        """A valid case, or a capture seed restamped with a fresh seq."""
        if self.seeds and self.rng.random() < 0.3:
            data = bytearray(self.rng.choice(self.seeds))
            if len(data) >= HEADER_SIZE:
                src = _U16.unpack_from(data, _SRC)[0]
                _U16.pack_into(data, _SEQ, self._next_seq(src))
                if data[_ACT:_ACT + 2] == _U16.pack(Action.END_MISSION):
                    _U16.pack_into(data, _ACT, Action.WP_OFF)
            return Case("seed", bytes(data))
        return self.valid()

    # ------------------------------------------------------------------ the draw
    def next(self) -> Case:
        r = self.rng.random()
        if r < 0.2:
            return self.valid()
        if r < 0.35:
            return self.malformed()
        base = self.base()
        name, mutate = self.rng.choice(MUTATORS)
        out = mutate(self, base.data)
        if len(out) > MAX_DATAGRAM:
            out = out[:MAX_DATAGRAM]
        if len(out) >= HEADER_SIZE and out[_ACT:_ACT + 2] == _U16.pack(Action.END_MISSION) \
                and out[:_PRE] == PREAMBLE:
            out = out[:_ACT] + _U16.pack(Action.WP_OFF) + out[_ACT + 2:]
        return Case(name, out, base.token)


# ---------------------------------------------------------------- mutations
def _bit_flip(g: CaseGenerator, data: bytes) -> bytes:
    if not data:
        return b"\x01"
    b = bytearray(data)
    for _ in range(g.rng.randint(1, 4)):
        i = g.rng.randrange(len(b))
        b[i] ^= 1 << g.rng.randrange(8)
    return bytes(b)


def _byte_flip(g: CaseGenerator, data: bytes) -> bytes:
    if not data:
        return b"\xff"
    b = bytearray(data)
    for _ in range(g.rng.randint(1, 4)):
        b[g.rng.randrange(len(b))] = g.rng.choice((0x00, 0xFF, 0x7F, 0x80, g.rng.randrange(256)))
    return bytes(b)


_BOUNDARIES = (0, 1, 0x7F, 0x80, 0xFF, 0x100, 0x7FFF, 0x8000, 0xFFFE, 0xFFFF)


def _field_boundary(g: CaseGenerator, data: bytes) -> bytes:
    """A header field (dst, src, seq or action) at a boundary value."""
    if len(data) < HEADER_SIZE:
        return data
    b = bytearray(data)
    off = g.rng.choice((_DST, _SRC, _SEQ, _ACT))
    _U16.pack_into(b, off, g.rng.choice(_BOUNDARIES + (g.node_id, g.broadcast_id)))
    return bytes(b)


def _length_lie(g: CaseGenerator, data: bytes) -> bytes:
    """Bytes added or removed at the end of the payload (the header still says the same)."""
    if g.rng.random() < 0.5:
        return data + g.rng.randbytes(g.rng.choice((1, 2, ITEM_SIZE - 1, ITEM_SIZE, ITEM_SIZE + 1)))
    cut = g.rng.randint(1, max(1, len(data) - HEADER_SIZE)) if len(data) > HEADER_SIZE else 1
    return data[:max(HEADER_SIZE, len(data) - cut)]


def _truncate(g: CaseGenerator, data: bytes) -> bytes:
    """Cut anywhere, the header included (MCP-ROB-1 territory below 17 bytes)."""
    return data[:g.rng.randint(0, max(0, len(data) - 1))]


def _concatenate(g: CaseGenerator, data: bytes) -> bytes:
    """Two datagrams in one."""
    return data + g.base().data


def _preamble_damage(g: CaseGenerator, data: bytes) -> bytes:
    if len(data) < _PRE:
        return data
    b = bytearray(data)
    i = g.rng.randrange(_PRE)
    b[i] = (b[i] + g.rng.randint(1, 255)) & 0xFF
    return bytes(b)


def _wrong_action(g: CaseGenerator, data: bytes) -> bytes:
    """Another action code: an unknown one (9 and above, MCP-HDR-3), or a valid one whose
    payload layout differs."""
    if len(data) < HEADER_SIZE:
        return data
    b = bytearray(data)
    code = g.rng.choice((_N_ACTIONS, _N_ACTIONS + 1, 0x00FF, 0x0100, 0xFFFF, g.rng.randrange(_N_ACTIONS)))
    _U16.pack_into(b, _ACT, code)
    return bytes(b)


def _count_mismatch(g: CaseGenerator, data: bytes) -> bytes:
    """A WP_List/Obstacles_List whose count disagrees with the items that follow."""
    msg = random_message(g.rng, g.rng.choice(_COUNTED), dst=g._dst(), src=g.our_id,
                         seq=g._next_seq(g.our_id))
    b = bytearray(encode(msg))
    n = len(msg.payload)
    _U16.pack_into(b, HEADER_SIZE, g.rng.choice([c for c in (n + 1, max(0, n - 1), 0xFFFF, 0x8000, n + 100)
                                                 if c != n] or [n + 1]))
    return bytes(b)


def _broken_mavlink(g: CaseGenerator, data: bytes) -> bytes:
    """A Mav_Passthrough whose frame is broken: bad CRC, bad magic, cut, padded, two frames."""
    case = g.valid(_PASSTHROUGH)
    b = bytearray(case.data)
    how = g.rng.randrange(5)
    if how == 0:
        b[-1] ^= 0xFF
    elif how == 1:
        b[HEADER_SIZE] = g.rng.choice((0x00, 0xFF, 0xFD if b[HEADER_SIZE] == 0xFE else 0xFE))
    elif how == 2:
        del b[g.rng.randint(HEADER_SIZE, len(b) - 1):]
    elif how == 3:
        b += g.rng.randbytes(g.rng.randint(1, 8))
    else:
        b += b[HEADER_SIZE:]
    return bytes(b)


def _oversized(g: CaseGenerator, data: bytes) -> bytes:
    """Padded far beyond any payload, up to the largest UDP datagram (MCP-ROB-6)."""
    size = g.rng.choice((1473, 4096, 8193, 16384, 32768, MAX_DATAGRAM))
    return (data + bytes(size))[:size]


def _unknown_kind(g: CaseGenerator, data: bytes) -> bytes:
    return g.malformed().data


MUTATORS: tuple[tuple[str, Callable[[CaseGenerator, bytes], bytes]], ...] = (
    ("bit_flip", _bit_flip),
    ("byte_flip", _byte_flip),
    ("field_boundary", _field_boundary),
    ("length_lie", _length_lie),
    ("truncate", _truncate),
    ("concatenate", _concatenate),
    ("preamble", _preamble_damage),
    ("wrong_action", _wrong_action),
    ("count_mismatch", _count_mismatch),
    ("broken_mavlink", _broken_mavlink),
    ("oversized", _oversized),
    ("malformed_kind", _unknown_kind),
)

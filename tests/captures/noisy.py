"""Noisy captures: a field recording's worst case, for the capture tools' scaling (issue 19).

``write_noisy(path, n)`` writes an MCAP of ``n`` datagrams from several source addresses:
well-formed commands nobody ACKs (MCP-ACK-1 each), mutated copies of them (bit flips,
truncations: MCP-ROB-*), random bytes long enough to carry a header (random MCP IDs: a node
per datagram, nearly) and runts too short for one (no MCP header: lifelines by address).
Deterministic for a seed. Used by tests/captures/test_scaling.py and
bench/bench_capture_tools.py.
"""

from __future__ import annotations

import random
from pathlib import Path

from mcp_conform.spec.codec import HEADER_SIZE, Action, Message, MissionItem, encode
from mcp_conform.traceio.recorder import McapRecorder

ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 1, 16, 1, 1, 3, 0, 1)
SOURCES = tuple(("127.0.0.1", 41000 + k) for k in range(8))
LOCAL = ("127.0.0.1", 7890)
T0 = 1_800_000_000_000_000_000


def noisy_datagrams(n: int, seed: int = 19) -> list[tuple[str, bytes, tuple[str, int], int]]:
    """(direction, bytes, peer, t_ns) of ``n`` noisy datagrams."""
    rnd = random.Random(seed)
    out = []
    t = T0
    for i in range(n):
        peer = SOURCES[i % len(SOURCES)]
        kind = i % 4
        src = 1 + (i % len(SOURCES))
        if kind == 0:  # a command nobody answers
            data = encode(Message(0, src, i & 0xFFFF, Action.WP_ON, ITEM._replace(seq=i % 1000)))
        elif kind == 1:  # a mutated command
            b = bytearray(encode(Message(0, src, i & 0xFFFF, Action.WP_LIST, (ITEM,))))
            for _ in range(3):
                b[rnd.randrange(len(b))] ^= 1 << rnd.randrange(8)
            data = bytes(b[:rnd.randrange(HEADER_SIZE, len(b) + 1)])
        elif kind == 2:  # random bytes with a (random) header
            data = rnd.randbytes(rnd.randrange(HEADER_SIZE, 64))
        else:  # a runt: no MCP header
            data = rnd.randbytes(rnd.randrange(0, HEADER_SIZE))
        t += 50_000
        out.append(("rx", data, peer, t))
    return out


def write_noisy(path: str | Path, n: int, seed: int = 19) -> Path:
    path = Path(path)
    with McapRecorder(path, local=LOCAL) as rec:
        for direction, data, peer, t in noisy_datagrams(n, seed):
            rec.datagram(direction, data, peer, t)
    return path

"""A synthetic capture of challenge 2 between a manager and two drones, for diff and replay
tests: datagram records as ``traceio.reader`` yields them, with knobs for what may vary
between two recordings of the same scenario (initial seqs, ports, timing)."""

from __future__ import annotations

from typing import NamedTuple

from mcp_conform.spec.codec import Action, Message, MissionItem, encode

WAYPOINTS = tuple(MissionItem(0.0, 0.0, 0.0, 0.0, 35.7711 + i / 1000, -78.6746, 10.0, i, 16, 1, 1, 3, 0, 1)
                  for i in range(3))


class D(NamedTuple):
    index: int
    t_ns: int
    src_addr: tuple[str, int] | None
    dst_addr: tuple[str, int] | None
    data: bytes
    direction: str | None = None
    recorder: str | None = None


def challenge2(seq0: tuple[int, int, int] = (100, 5000, 7), port: int = 7889, step_ns: int = 1_000_000,
               t0: int = 10**18) -> list[D]:
    """Ready, Start, WP_On/WP_Off per waypoint, End: every unicast ACKed once."""
    seq = {0: seq0[0], 1: seq0[1], 2: seq0[2]}
    addr = {0: ("127.0.0.1", port), 1: ("127.0.0.1", port + 1), 2: ("127.0.0.1", port + 2)}
    out: list[D] = []

    def send(src: int, dst: int, action: Action, payload=None) -> int:
        s = seq[src]
        seq[src] = (s + 1) & 0xFFFF
        out.append(D(len(out), t0 + len(out) * step_ns, addr[src], addr[dst],
                     encode(Message(dst, src, s, action, payload))))
        return s

    def unicast(src: int, dst: int, action: Action, payload=None) -> None:
        s = send(src, dst, action, payload)
        send(dst, src, Action.ACK, s)

    for d in (1, 2):
        unicast(d, 0, Action.MISSION_READY)
    for d in (1, 2):
        unicast(0, d, Action.START_MISSION)
    for wp in WAYPOINTS:
        for d in (1, 2):
            unicast(0, d, Action.WP_ON, wp)
        for d in (1, 2):
            unicast(0, d, Action.WP_OFF)
    for d in (1, 2):
        unicast(0, d, Action.END_MISSION)
    return out


def reindex(datagrams: list[D]) -> list[D]:
    return [d._replace(index=i) for i, d in enumerate(datagrams)]

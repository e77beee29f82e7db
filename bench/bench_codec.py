"""Codec benchmark: encode+decode of the 93-byte WP_List with two waypoints, spec codec vs scapy;
and beside it the Nsqd codec (spec.nsqd_codec): a 37-byte UPDATE and a 30-byte SET_RPYTFF
encoded, deframed and decoded, against the Nsqd scapy layer.

    python bench/bench_codec.py [--rounds N] [--quick]

Prints messages/s (best of N rounds after a warm-up) for the spec-derived ``struct`` codec
(``spec.codec.encode`` + ``decode``) and for the scapy layer (build + ``bytes()``, then
dissect), side by side from one run. The target for the spec codec is >= 300k msg/s
(docs/design.md, "Performance targets"). Figures only: nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from collections.abc import Callable
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a source checkout

from mcp_conform.spec.codec import Action, Message, MissionItem, decode, encode  # noqa: E402

TARGET = 300_000
ITEMS = (
    MissionItem(0.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 1, 16, 1, 0, 3, 0, 1),
    MissionItem(5.0, 0.0, 0.0, 0.0, 35.771057, -78.674421, 3.0, 2, 19, 1, 0, 3, 0, 1),
)
# float32 values, as on the wire, so decode(encode(m)) == m
MESSAGE = decode(encode(Message(1, 0, 0x1234, Action.WP_LIST, ITEMS)))


def best_rate(step: Callable[[int], None], batch: int, rounds: int, warmup: int) -> float:
    """Best per-second rate of ``step(batch)`` over ``rounds`` timed rounds."""
    step(warmup)
    best = 0.0
    for _ in range(rounds):
        t0 = time.perf_counter()
        step(batch)
        elapsed = time.perf_counter() - t0
        best = max(best, batch / elapsed)
    return best


def codec_round_trip(n: int) -> None:
    msg, enc, dec = MESSAGE, encode, decode
    for _ in range(n):
        dec(enc(msg))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=5, help="timed rounds per codec (best is kept)")
    ap.add_argument("--quick", action="store_true", help="smaller batches (a smoke run)")
    args = ap.parse_args(argv)
    rounds = max(1, min(args.rounds, 50))
    data = encode(MESSAGE)
    assert len(data) == 93 and decode(data) == MESSAGE

    from mcp_conform.spec.scapy_mcp import MCP, MCPItemList, MCPMissionItem

    item_fields = [it._asdict() for it in ITEMS]

    def scapy_build(n: int) -> None:
        for _ in range(n):
            bytes(MCP(dst=1, src=0, seq=0x1234, action=int(Action.WP_LIST))
                  / MCPItemList(items=[MCPMissionItem(**f) for f in item_fields]))

    def scapy_dissect(n: int) -> None:
        for _ in range(n):
            MCP(data)

    def scapy_round_trip(n: int) -> None:
        scapy_build(n)
        scapy_dissect(n)

    assert bytes(MCP(data)) == data
    big, small = (20_000, 300) if not args.quick else (2_000, 30)
    results = [
        ("spec.codec encode+decode", best_rate(codec_round_trip, big, rounds, big // 10)),
        ("spec.codec encode", best_rate(lambda n: [encode(MESSAGE) for _ in range(n)], big, rounds, big // 10)),
        ("spec.codec decode", best_rate(lambda n: [decode(data) for _ in range(n)], big, rounds, big // 10)),
        ("scapy build+bytes+dissect", best_rate(scapy_round_trip, small, rounds, small // 10)),
        ("scapy build+bytes", best_rate(scapy_build, small, rounds, small // 10)),
        ("scapy dissect", best_rate(scapy_dissect, small, rounds, small // 10)),
    ]
    print(f"WP_List with two waypoints, {len(data)} bytes; best of {rounds} rounds; "
          f"Python {platform.python_version()} on {platform.machine()}")
    print(f"{'codec':<28}{'msg/s':>12}")
    for name, rate in results:
        print(f"{name:<28}{rate:>12,.0f}")
    codec, scapy = results[0][1], results[3][1]
    print(f"spec.codec is {codec / scapy:,.0f}x scapy; target {TARGET:,} msg/s: "
          f"{'met' if codec >= TARGET else 'NOT met'}")
    nsqd = nsqd_results(big, small, rounds)
    print()
    print("Nsqd (TCP) beside it: UPDATE 37 bytes and SET_RPYTFF 30 bytes, one of each per message pair")
    print(f"{'codec':<28}{'msg/s':>12}{'MCP msg/s':>12}")
    for (name, rate), mcp in zip(nsqd, (results[0][1], results[1][1], results[2][1], results[5][1]), strict=True):
        print(f"{name:<28}{rate:>12,.0f}{mcp:>12,.0f}")
    return 0


def nsqd_results(big: int, small: int, rounds: int) -> list[tuple[str, float]]:
    """The same measurements for the Nsqd codec and its scapy layer, per message."""
    from mcp_conform.spec import NSQD
    from mcp_conform.spec.nsqd_codec import Deframer, decode_body
    from mcp_conform.spec.nsqd_codec import encode as nsqd_encode
    from mcp_conform.spec.scapy_nsqd import NSQD_Frame

    values = dict(roll=1, pitch=2, yaw=3, thrust=40, lat=55, lon=10, alt=3, state=2)
    rpytff = dict(roll="1.5", pitch="2", yaw="3", thrust="4", flag=1, file_name="a.csv")
    stream = nsqd_encode(NSQD, "UPDATE", **values) + nsqd_encode(NSQD, "SET_RPYTFF", **rpytff)

    def enc(n: int) -> None:
        for _ in range(n // 2):
            nsqd_encode(NSQD, "UPDATE", **values)
            nsqd_encode(NSQD, "SET_RPYTFF", **rpytff)

    def dec(n: int) -> None:
        d = Deframer(NSQD)
        for _ in range(n // 2):
            for fr in d.feed(stream):
                decode_body(NSQD, fr.msg_id, fr.body)  # type: ignore[union-attr]

    def both(n: int) -> None:
        enc(n)
        dec(n)

    def scapy_dissect(n: int) -> None:
        upd, rpy = stream[:37], stream[37:]
        for _ in range(n // 2):
            NSQD_Frame(upd)
            NSQD_Frame(rpy)

    return [("nsqd_codec encode+decode", best_rate(both, big, rounds, big // 10)),
            ("nsqd_codec encode", best_rate(enc, big, rounds, big // 10)),
            ("nsqd_codec deframe+decode", best_rate(dec, big, rounds, big // 10)),
            ("scapy_nsqd dissect", best_rate(scapy_dissect, small, rounds, small // 10))]


if __name__ == "__main__":
    sys.exit(main())

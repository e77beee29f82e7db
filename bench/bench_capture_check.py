"""mcp-capture check end to end from a big pcap: reading alone vs reading and judging.

Writes a pcap of N datagrams (default 1,000,000; Ethernet/IPv4/UDP as ``tcpdump -i lo``
writes them): a challenge-2 mission between a manager and four drones, each WP_On / WP_Off
unicast and ACKed 0.2 ms later, one exchange every 2 ms (a manager's sequence numbers wrap
every ~130 s: several times in the trace, never within the monitor's 100 s horizon at
--rto 5, inside which a repeated (src, dst, seq) is taken for a retransmission). Then prints, side by side:

- read only: ``traceio.reader`` (dpkt's pcap and pcapng readers + struct link/IP/UDP parsing);
- read + monitor: ``judge.judging.judge`` (what ``mcp-capture check`` does, no printing);
- monitor alone: the same datagrams already in memory, fed to ``judge.monitor``;
- the command: ``mcp-capture check FILE --json OUT`` in-process, terminal output discarded.

    python bench/bench_capture_check.py [--datagrams N] [--keep FILE]

The pcap is written with struct (it is only the benchmark's input; scapy would take minutes).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import struct
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from mcp_conform.judge.judging import Params, judge  # noqa: E402
from mcp_conform.spec.codec import Action, Message, MissionItem, encode  # noqa: E402
from mcp_conform.traceio.reader import open_capture  # noqa: E402

DRONES = (1, 2, 3, 4)
ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 1, 16, 1, 1, 3, 0, 1)
_PCAP_HEADER = struct.Struct("<IHHiIII")
_RECORD = struct.Struct("<IIII")
_IP = struct.Struct("!BBHHHBBH4s4s")
_UDP = struct.Struct("!HHHH")
_ETH = b"\x00" * 12 + b"\x08\x00"
MANAGER = (bytes([127, 0, 0, 1]), 7889)


def drone_addr(d: int) -> tuple[bytes, int]:
    return bytes([127, 0, 0, 10 + d]), 7890


def frame(src: tuple[bytes, int], dst: tuple[bytes, int], payload: bytes) -> bytes:
    udp = _UDP.pack(src[1], dst[1], 8 + len(payload), 0)
    ip = _IP.pack(0x45, 0, 20 + 8 + len(payload), 0, 0, 64, 17, 0, src[0], dst[0])
    return _ETH + ip + udp + payload


def write_pcap(path: Path, n: int) -> int:
    """A clean challenge-2 mission of about ``n`` datagrams; returns the exact count."""
    seq = {0: 65000, **{d: 1000 * d for d in DRONES}}
    out = [_PCAP_HEADER.pack(0xA1B2C3D4, 2, 4, 0, 0, 65535, 1)]
    t_us = 1_700_000_000 * 1_000_000
    count = 0

    def emit(src_id: int, dst_id: int, action: Action, payload: object = None, gap_us: int = 1800) -> int:
        nonlocal t_us, count
        s = seq[src_id]
        seq[src_id] = (s + 1) & 0xFFFF
        data = encode(Message(dst_id, src_id, s, action, payload))
        src = MANAGER if src_id == 0 else drone_addr(src_id)
        dst = MANAGER if dst_id == 0 else drone_addr(dst_id)
        f = frame(src, dst, data)
        t_us += gap_us
        out.append(_RECORD.pack(t_us // 1_000_000, t_us % 1_000_000, len(f), len(f)))
        out.append(f)
        count += 1
        return s

    def exchange(src_id: int, dst_id: int, action: Action, payload: object = None) -> None:
        s = emit(src_id, dst_id, action, payload)
        emit(dst_id, src_id, Action.ACK, s, gap_us=200)

    for d in DRONES:
        exchange(d, 0, Action.MISSION_READY)
    for d in DRONES:
        exchange(0, d, Action.START_MISSION)
    while count < n - 2 * len(DRONES):
        for d in DRONES:
            exchange(0, d, Action.WP_ON, ITEM)
            exchange(0, d, Action.WP_OFF)
    for d in DRONES:
        exchange(0, d, Action.END_MISSION)
    path.write_bytes(b"".join(out))
    return count


def timed(fn):  # type: ignore[no-untyped-def]
    t = time.perf_counter()
    result = fn()
    return time.perf_counter() - t, result


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datagrams", type=int, default=1_000_000)
    ap.add_argument("--keep", metavar="FILE", help="write the pcap here and keep it")
    args = ap.parse_args()
    tmp = None if args.keep else tempfile.TemporaryDirectory()
    path = Path(args.keep) if args.keep else Path(tmp.name) / "big.pcap"  # type: ignore[union-attr]
    dt, n = timed(lambda: write_pcap(path, args.datagrams))
    print(f"pcap: {n:,} datagrams, {path.stat().st_size / 1e6:.1f} MB, written in {dt:.1f} s "
          f"({os.cpu_count()} CPUs, Python {sys.version.split()[0]})")

    def read_only() -> list:
        return list(open_capture(path).datagrams())

    t_read, datagrams = timed(read_only)
    assert len(datagrams) == n, (len(datagrams), n)

    params = dict(rto=5.0, ack_window=2.0, challenge=2)
    t_judge, j = timed(lambda: judge(path, Params(**params)))  # type: ignore[arg-type]

    from mcp_conform.judge.monitor import Monitor

    def monitor_alone() -> list:
        m = Monitor(**params)  # type: ignore[arg-type]
        out = []
        feed = m.datagram
        for d in datagrams:
            out += feed(d.t_ns, d.src_addr, d.dst_addr, d.data)
        out += m.finish(datagrams[-1].t_ns)
        return out

    t_mon, found = timed(monitor_alone)

    from mcp_conform.captures.cli import main as capture_main

    with tempfile.TemporaryDirectory() as out_dir:
        sink = io.StringIO()
        with contextlib.redirect_stdout(sink):
            t_cli, rc = timed(lambda: capture_main(["check", str(path), "--challenge", "2",
                                                    "--json", str(Path(out_dir) / "check.json")]))

    rows = [("read only (traceio.reader)", t_read),
            ("read + monitor (judge.judging.judge)", t_judge),
            ("monitor alone, datagrams in memory", t_mon),
            (f"mcp-capture check --json (exit {rc})", t_cli)]
    print(f"{'':44} {'seconds':>8} {'datagrams/s':>12}")
    for name, t in rows:
        print(f"{name:44} {t:8.2f} {n / t:12,.0f}")
    from collections import Counter

    print(f"violations: {len(j.violations)} from the file {dict(Counter(v.rule for v in j.violations))}, "
          f"{len(found)} in memory (a clean mission: both should be 0); nodes {sorted(j.nodes)}")
    if tmp is not None:
        tmp.cleanup()


if __name__ == "__main__":
    main()

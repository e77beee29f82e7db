"""The reference drone's memory and ACK rate before and after 10^6 impaired datagrams
(issue 22: flat memory on a bad link; MCP-DUP-1's duplicate memory must stay bounded).

    python bench/bench_soak.py [--datagrams 1000000] [--impair loss=0.3,dup=0.1,reorder=0.2,seed=1]

Starts ``python -m mcp_conform.reference_impl drone`` (a subprocess), answers its Mission_Ready, then
sends it WP_Off commands with ever new seqs (wrapping) through ``harness.impair`` decisions
taken in-process (dropped, duplicated, reordered: a held copy goes out after later ones; the
delays themselves are not waited for), in rounds; after the first round and at the end it
prints the drone's RSS (/proc) and the ACKs per second it returned. Figures only, no asserts.
"""

from __future__ import annotations

import argparse
import socket
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mcp_conform.harness.impair import Impairment, parse_impairment  # noqa: E402
from mcp_conform.spec.codec import Action, Message, decode, encode  # noqa: E402


def rss_kib(pid: int) -> int:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return -1


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--datagrams", type=int, default=1_000_000)
    p.add_argument("--impair", default="loss=0.3,dup=0.1,reorder=0.2,seed=1")
    p.add_argument("--window", type=int, default=64, help="datagrams in flight before reading ACKs")
    ns = p.parse_args()
    imp = Impairment(parse_impairment(ns.impair))
    me = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    me.bind(("127.0.0.1", 0))
    me.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
    probe = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    probe.bind(("127.0.0.1", 0))
    port = probe.getsockname()[1]
    probe.close()
    drone = subprocess.Popen([sys.executable, "-m", "mcp_conform.reference_impl", "drone", "--id", "1", "--bind",
                              f"127.0.0.1:{port}", "--send-to", f"127.0.0.1:{me.getsockname()[1]}",
                              "--rto", "0.5", "-q"], cwd=ROOT, stdin=subprocess.DEVNULL,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    target = ("127.0.0.1", port)
    try:
        me.settimeout(20)
        while True:  # its Mission_Ready, ACKed
            msg = decode(me.recvfrom(65535)[0])
            if msg.action == Action.MISSION_READY:
                me.sendto(encode(Message(1, 0, 1, Action.ACK, msg.seq)), target)
                break
        me.sendto(encode(Message(1, 0, 2, Action.START_MISSION)), target)
        time.sleep(1.0)
        me.setblocking(False)
        seq, sent, acks = 3, 0, 0
        held: list[bytes] = []
        rounds = [min(ns.datagrams, 50_000), ns.datagrams]
        for label, upto in zip(("after the first", "after"), rounds, strict=True):
            t0, acks0, sent0 = time.monotonic(), acks, sent
            while sent < upto:
                data = encode(Message(1, 0, seq & 0xFFFF, Action.WP_OFF))
                seq += 1
                sent += 1
                for d in imp.decide("down", data).deliveries:
                    if "reorder" in d.kinds:
                        held.append(d.data)  # out after the next ones
                    else:
                        me.sendto(d.data, target)
                if len(held) > 4 or (held and sent % 7 == 0):
                    me.sendto(held.pop(0), target)
                if sent % ns.window == 0:
                    deadline = time.monotonic() + 0.05
                    while time.monotonic() < deadline:
                        try:
                            me.recvfrom(65535)
                            acks += 1
                        except BlockingIOError:
                            if acks - acks0 >= (sent - sent0) * 0.5:
                                break
                            time.sleep(0.0005)
            dt = time.monotonic() - t0
            print(f"{label} {upto:>9,} datagrams: drone RSS {rss_kib(drone.pid) / 1024:.1f} MiB, "
                  f"{(acks - acks0) / dt:,.0f} ACKs/s ({sent - sent0:,} commands in {dt:.1f} s; "
                  f"link: {imp.summary()})", flush=True)
        return 0
    finally:
        drone.terminate()
        drone.wait(10)


if __name__ == "__main__":
    sys.exit(main())

"""Captures: recording throughput, what recording costs a node, and diff throughput.

    python bench/bench_capture.py [--records N] [--rounds R] [--count N] [--diff-messages N]

1. Recording throughput: ``McapRecorder.datagram`` (decode, JSON, MCAP with LZ4) in-process,
   and ``BackgroundRecorder`` (what ``mcp-node --capture`` uses): the hot-path call rate and
   the end-to-end rate until the writer process has finished the file.
2. The cost of recording on the reference node's ACK rate, side by side in one run: the node
   (``reference_impl.Mcp``, as in bench_node.py) without a capture and with one (its
   ``tap`` feeding a ``BackgroundRecorder``), measured in alternating rounds of ping-pong
   round trips (WP_Off -> ACK); the median rate of each, the median of the paired differences
   (target <= 10 %) and the node's CPU time per round trip, its writer process included.
3. Diff throughput: two MCAP captures of ``--diff-messages`` messages each (a long challenge 2
   between a manager and four drones; the candidate with other initial seqs and ports, one
   ACK dropped and one waypoint changed), read and compared by ``captures.diff``; it must
   find exactly those two divergences. The files are cached in $TMPDIR.

Figures only: nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import os
import platform
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a source checkout
sys.path.insert(0, str(ROOT / "bench"))

from bench_node import LOOP, NODE_ID, client_loop  # noqa: E402

from mcp_conform.spec.codec import Action, Message, MissionItem, encode  # noqa: E402

ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 1, 16, 1, 1, 3, 0, 1)


# ---------------------------------------------------------------- 1. recording throughput
def bench_recording(n: int, tmp: Path) -> None:
    from mcp_conform.traceio.background import BackgroundRecorder
    from mcp_conform.traceio.recorder import McapRecorder

    wp_list = encode(Message(1, 0, 7, Action.WP_LIST, (ITEM, ITEM._replace(seq=2))))
    ack = encode(Message(0, 1, 8, Action.ACK, 7))
    peer = ("127.0.0.1", 7890)
    path = tmp / "bench-rec.mcap"
    t = time.perf_counter()
    with McapRecorder(path) as rec:
        for i in range(n):
            rec.datagram("tx" if i & 1 else "rx", wp_list if i & 1 else ack, peer, i)
    inproc = n / (time.perf_counter() - t)
    size = path.stat().st_size
    t = time.perf_counter()
    bg = BackgroundRecorder(path)
    for i in range(n):
        bg.datagram("tx" if i & 1 else "rx", wp_list if i & 1 else ack, peer, i)
    calls = n / (time.perf_counter() - t)
    bg.close(timeout=300)
    end_to_end = n / (time.perf_counter() - t)
    print(f"recording, {n} datagrams (93-byte WP_List and ACK alternating):")
    print(f"  McapRecorder in-process      : {inproc:10.0f} msg/s  ({size / n:.0f} bytes/msg on disk)")
    print(f"  BackgroundRecorder hot path  : {calls:10.0f} calls/s ({1e6 / calls:.2f} us per datagram)")
    print(f"  BackgroundRecorder end to end: {end_to_end:10.0f} msg/s  (until the writer finished the file)")


# ---------------------------------------------------------------- 2. cost on the node's ACK rate
def serve_node(port_file: str, client_port: int, capture: str | None) -> None:
    from mcp_conform.reference_impl import Mcp, MissionMessageHandlerBase

    rec = None
    if capture:
        from mcp_conform.traceio.background import BackgroundRecorder

        rec = BackgroundRecorder(capture)
    node = Mcp(MissionMessageHandlerBase(), 0, client_port, LOOP, NODE_ID, bind_host=LOOP, max_queued=100,
               tap=None if rec is None else rec.datagram)
    if rec is not None:
        rec.local = node.local_address
    Path(port_file).write_text(str(node.local_port))
    try:
        while True:
            node.recv_message(timeout=1.0)
    except KeyboardInterrupt:
        pass
    finally:
        node.close()
        if rec is not None:
            rec.close()


def _start(kind: str, client_port: int, tmp: Path) -> tuple[subprocess.Popen[bytes], int]:
    port_file = tmp / f"bench-capture-port-{kind}-{os.getpid()}"
    port_file.unlink(missing_ok=True)
    args = [sys.executable, __file__, "--serve", kind, "--port-file", str(port_file), "--client-port", str(client_port)]
    if kind == "capture":
        args += ["--capture-file", str(tmp / "bench-node.mcap")]
    proc = subprocess.Popen(args, cwd=ROOT, stderr=subprocess.PIPE)
    if PIN:  # the node (and the writer process it starts) on one CPU, the client on another
        os.sched_setaffinity(proc.pid, {PIN[1]})
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        if port_file.exists() and port_file.read_text():
            return proc, int(port_file.read_text())
        if proc.poll() is not None:
            raise SystemExit(f"bench_capture: {kind} node died: {proc.stderr.read().decode()[-500:]}")
        time.sleep(0.02)
    proc.kill()
    raise SystemExit("bench_capture: node did not start within 15 s")


def _cpu_seconds(pid: int) -> float:
    """User + system CPU time of ``pid`` and its children (the capture's writer process)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    pids = [pid]
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            pids += [int(x) for x in f.read().split()]
    except OSError:
        pass
    for p in pids:
        try:
            with open(f"/proc/{p}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
        except (OSError, IndexError, ValueError):
            pass
    return total


#: CPUs for (the client, the nodes) in part 2: the ping-pong rate of two unpinned processes
#: swings by +-40 % from round to round with where the scheduler puts them
PIN: tuple[int, int] | None = None


def bench_node_cost(count: int, rounds: int, max_seconds: float, tmp: Path) -> None:
    """Rounds alternate plain/capture back to back; each pair gives one relative cost, so a
    shift in the host's load between pairs (a shared machine) cancels out; the figure is the
    median over the pairs. The node's CPU time per round trip (its writer process included)
    is the steadier figure beside it."""
    global PIN
    cpus = sorted(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else []
    PIN = (cpus[0], cpus[1]) if len(cpus) >= 2 else None
    saved = os.sched_getaffinity(0) if PIN else None
    if PIN:
        os.sched_setaffinity(0, {PIN[0]})
    clients, nodes = {}, {}
    try:
        for kind in ("plain", "capture"):
            c = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
            c.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
            c.bind((LOOP, 0))
            clients[kind] = c
            nodes[kind] = _start(kind, c.getsockname()[1], tmp)
        for kind in clients:
            client_loop(clients[kind], (LOOP, nodes[kind][1]), 500, max_seconds, True, 60000)  # warm-up
        rates: dict[str, list[float]] = {"plain": [], "capture": []}
        cpu: dict[str, list[float]] = {"plain": [], "capture": []}
        for r in range(rounds):  # alternating, so both see the same host load
            for kind in (("plain", "capture") if r % 2 == 0 else ("capture", "plain")):
                pid = nodes[kind][0].pid
                cpu0 = _cpu_seconds(pid)
                lat, _lost, elapsed = client_loop(clients[kind], (LOOP, nodes[kind][1]), count, max_seconds, True,
                                                  (r * count) & 0xFFFF)
                rates[kind].append(len(lat) / elapsed if elapsed else 0.0)
                cpu[kind].append((_cpu_seconds(pid) - cpu0) / max(1, len(lat)))
    finally:
        for proc, _port in nodes.values():
            proc.terminate()
            try:
                proc.wait(30)
            except subprocess.TimeoutExpired:
                proc.kill()
        for c in clients.values():
            c.close()
        if saved:
            os.sched_setaffinity(0, saved)
    plain, capt = statistics.median(rates["plain"]), statistics.median(rates["capture"])
    paired = [(p - c) / p * 100 for p, c in zip(rates["plain"], rates["capture"], strict=True) if p]
    cost = statistics.median(paired) if paired else float("nan")
    q1, _, q3 = statistics.quantiles(paired, n=4) if len(paired) >= 2 else (cost, cost, cost)
    cpu_plain, cpu_capt = statistics.median(cpu["plain"]) * 1e6, statistics.median(cpu["capture"]) * 1e6
    where = f"client on CPU {PIN[0]}, nodes on CPU {PIN[1]}" if PIN else "unpinned"
    print(f"reference node ACK rate, {rounds} alternating pairs of rounds of {count} round trips ({where}):")
    print(f"  without a capture : {plain:9.0f} rt/s median   CPU {cpu_plain:6.1f} us per round trip")
    print(f"  with --capture    : {capt:9.0f} rt/s median   CPU {cpu_capt:6.1f} us per round trip "
          f"(the writer process included)")
    verdict = "meets" if cost <= 10 else "MISSES"
    print(f"  cost of recording : {cost:+.1f} % (median of the {len(paired)} pairs; quartiles "
          f"{q1:+.1f} % .. {q3:+.1f} %)  ({verdict} the target of <= 10 %)")
    print(f"  CPU per round trip: {(cpu_capt - cpu_plain) / cpu_plain * 100 if cpu_plain else float('nan'):+.1f} %")
    cap = tmp / "bench-node.mcap"
    if cap.exists():
        from mcp_conform.traceio.reader import Datagram, open_capture

        n = sum(1 for r in open_capture(cap) if type(r) is Datagram)
        print(f"  the capture holds {n} datagrams ({cap.stat().st_size / 1e6:.1f} MB)")


# ---------------------------------------------------------------- 3. diff throughput
def _long_mission(path: Path, messages: int, seq0: int, port: int, drop_ack: int | None,
                  change_wp: int | None) -> None:
    from mcp_conform.traceio.recorder import McapRecorder

    drones = (1, 2, 3, 4)
    seq = {0: seq0, **{d: (seq0 * 7 + d * 1000) & 0xFFFF for d in drones}}
    mgr = ("127.0.0.1", port)
    addr = {d: ("127.0.0.1", port + d) for d in drones}
    t = 1_800_000_000_000_000_000
    n = 0
    cmd = 0
    commands = messages // 2  # each with its ACK: both captures hold the same commands
    with McapRecorder(path, local=mgr) as rec:
        while cmd < commands:
            d = drones[cmd % len(drones)]
            if (cmd // len(drones)) % 2 == 0:
                wp = ITEM._replace(seq=cmd % 1000, x=35.77 + (cmd % 97) / 1e4)
                if cmd == change_wp:
                    wp = wp._replace(z=99.0)
                data = encode(Message(d, 0, seq[0], Action.WP_ON, wp))
            else:
                data = encode(Message(d, 0, seq[0], Action.WP_OFF, None))
            rec.datagram("tx", data, addr[d], t)
            acked = seq[0]
            seq[0] = (seq[0] + 1) & 0xFFFF
            t += 100_000
            n += 1
            if cmd != drop_ack:
                rec.datagram("rx", encode(Message(0, d, seq[d], Action.ACK, acked)), addr[d], t)
                seq[d] = (seq[d] + 1) & 0xFFFF
                t += 100_000
                n += 1
            cmd += 1


def bench_diff(messages: int, tmp: Path) -> None:
    from mcp_conform.captures.diff import diff_sides, load_side

    golden = tmp / f"bench-diff-golden-{messages}.mcap"
    cand = tmp / f"bench-diff-candidate-{messages}.mcap"
    for path, args in ((golden, (100, 40000, None, None)), (cand, (60000, 50000, 1001, 2000))):
        if not path.exists():
            t = time.perf_counter()
            part = path.with_suffix(".part")
            _long_mission(part, messages, *args)
            part.replace(path)
            print(f"  (wrote {path.name} in {time.perf_counter() - t:.1f} s)")
    clock, cpu = time.perf_counter, time.process_time
    t0, c0 = clock(), cpu()
    g = load_side(golden)
    t1, c1 = clock(), cpu()
    c = load_side(cand)
    t2, c2 = clock(), cpu()
    result = diff_sides(g, c)
    t3, c3 = clock(), cpu()
    total = g.datagrams + c.datagrams
    print(f"diff of two captures of {g.datagrams} and {c.datagrams} messages "
          f"({golden.stat().st_size / 1e6:.0f} MB and {cand.stat().st_size / 1e6:.0f} MB MCAP), wall (CPU):")
    for label, n, wall, used in (("read + fold golden", g.datagrams, t1 - t0, c1 - c0),
                                 ("read + fold candidate", c.datagrams, t2 - t1, c2 - c1),
                                 ("align and compare", total, t3 - t2, c3 - c2),
                                 ("end to end", total, t3 - t0, c3 - c0)):
        print(f"  {label:22s}: {wall:7.2f} s ({used:7.2f} s CPU)  {n / wall:9.0f} msg/s ({n / used:9.0f} per CPU s)")
    kinds = sorted(d.kind for d in result.divergences)
    print(f"  found {len(result.divergences)} divergence(s): {', '.join(kinds)} (expected: changed, missing)")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--records", type=int, default=200_000, help="datagrams recorded in part 1 (200000)")
    ap.add_argument("--count", type=int, default=2000, help="round trips per round in part 2 (2000)")
    ap.add_argument("--rounds", type=int, default=20, help="alternating pairs of rounds in part 2 (20)")
    ap.add_argument("--max-seconds", type=float, default=5.0, help="time limit per round (5)")
    ap.add_argument("--diff-messages", type=int, default=1_000_000, help="messages per capture in part 3")
    ap.add_argument("--only", choices=["record", "node", "diff"], help="run one part")
    ap.add_argument("--serve", choices=["plain", "capture"], help=argparse.SUPPRESS)
    ap.add_argument("--port-file", help=argparse.SUPPRESS)
    ap.add_argument("--client-port", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--capture-file", help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.serve:
        serve_node(args.port_file, args.client_port, args.capture_file)
        return 0
    tmp = Path(os.environ.get("TMPDIR", "/tmp"))
    print(f"python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} CPUs")
    if args.only in (None, "record"):
        bench_recording(args.records, tmp)
    if args.only in (None, "node"):
        bench_node_cost(args.count, args.rounds, args.max_seconds, tmp)
    if args.only in (None, "diff"):
        bench_diff(args.diff_messages, tmp)
    return 0


if __name__ == "__main__":
    sys.exit(main())

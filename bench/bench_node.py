"""Reference node ACK round trips on loopback, beside a plain-Python UDP echo server.

    python bench/bench_node.py [--count N] [--max-seconds S] [--rounds R]
    python bench/bench_node.py --endpoint [--count N] [--rounds R]

Two servers run as separate processes on 127.0.0.1, one after the other:

- ``node``: the reference node (``reference_impl.Mcp``, the blocking API with its network
  and handler threads, as ``mcp-node`` runs it) with ID 1, sending to the client's port;
- ``echo``: a plain ``recvfrom``/``sendto`` loop returning each datagram to its source.

The same client loop measures both: it sends a unicast command (WP_Off, ID 0 -> 1) with a
new sequence number, waits for the reply (for the node: the ACK whose payload is that
seq, MCP-ACK-2; for the echo: the datagram itself), and repeats, bounded by ``--count``
round trips and ``--max-seconds`` per round. It prints round trips per second and p50/p99
latency for each, the servers' CPU per round trip (from ``/proc``, where there is one), and
the node's rate as a fraction of the echo's (docs/design.md's target: within 2x, i.e. at
least 0.5).

``--endpoint``: no sockets, no threads; the sans-I/O ``Endpoint`` alone, its CPU per datagram
(best of the rounds) for a unicast it ACKs and delivers, for a malformed datagram (MCP-ROB-7's
flood corpus: bad preamble, unknown action, count mismatch), and for the same malformed
datagram decoded first by its reader (the simulator's mutant drone reads each datagram, then
hands it to the endpoint). Figures only: nothing here asserts a timing.
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

from mcp_conform.spec.codec import HEADER_SIZE, Action, Message, encode  # noqa: E402

LOOP = "127.0.0.1"
NODE_ID = 1
READY = b"ready\n"


# ---------------------------------------------------------------- servers (child processes)
def serve_node(port_file: str, client_port: int) -> None:
    """The reference node: ACKs from its network thread; messages go through its handler."""
    from mcp_conform.reference_impl import Mcp, MissionMessageHandlerBase

    node = Mcp(MissionMessageHandlerBase(), 0, client_port, LOOP, NODE_ID, bind_host=LOOP,
               max_queued=100)
    Path(port_file).write_text(str(node.local_port))
    try:
        while True:  # the application drains its messages like a drone's recv loop
            node.recv_message(timeout=1.0)
    except KeyboardInterrupt:
        pass
    finally:
        node.close()


def serve_echo(port_file: str) -> None:
    """A plain-Python UDP echo: each datagram straight back to its source."""
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind((LOOP, 0))
    Path(port_file).write_text(str(sock.getsockname()[1]))
    recvfrom, sendto = sock.recvfrom, sock.sendto
    try:
        while True:
            data, addr = recvfrom(65535)
            sendto(data, addr)
    except KeyboardInterrupt:
        pass


# ---------------------------------------------------------------- the client
def client_loop(sock: socket.socket, server: tuple[str, int], count: int, max_seconds: float,
                expect_ack: bool, seq0: int = 0) -> tuple[list[float], int, float]:
    """Round trips: (latencies in s, lost, elapsed). Bounded by ``count`` and ``max_seconds``."""
    sock.settimeout(0.5)
    lat: list[float] = []
    lost = 0
    perf = time.perf_counter
    start = perf()
    end = start + max_seconds
    for i in range(count):
        seq = (seq0 + i) & 0xFFFF
        data = encode(Message(NODE_ID, 0, seq, Action.WP_OFF, None))
        want = seq.to_bytes(2, "big")
        t0 = perf()
        sock.sendto(data, server)
        try:
            while True:
                reply = sock.recv(2048)
                if (reply[HEADER_SIZE:] == want) if expect_ack else (reply == data):
                    break
        except TimeoutError:
            lost += 1
        else:
            lat.append(perf() - t0)
        if perf() > end:
            break
    return lat, lost, perf() - start


def _cpu_s(pid: int) -> float | None:
    """User + system CPU seconds of process ``pid`` (all its threads) so far; None without /proc."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    except OSError:
        return None
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def _spawn(args: list[str], tmp: Path) -> tuple[subprocess.Popen[bytes], int]:
    port_file = tmp / f"port-{args[0]}-{os.getpid()}"
    port_file.unlink(missing_ok=True)
    proc = subprocess.Popen([sys.executable, __file__, "--serve", *args, "--port-file", str(port_file)],
                            cwd=ROOT, stderr=subprocess.PIPE)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        if port_file.exists() and port_file.read_text():
            return proc, int(port_file.read_text())
        if proc.poll() is not None:
            raise SystemExit(f"bench_node: {args[0]} server died: {proc.stderr.read().decode()[-500:]}")
        time.sleep(0.02)
    proc.kill()
    raise SystemExit(f"bench_node: {args[0]} server did not start within 10 s")


def measure(kind: str, count: int, max_seconds: float, rounds: int, tmp: Path) -> dict[str, float]:
    client = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    client.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 1 << 20)
    client.bind((LOOP, 0))
    args = ["node", "--client-port", str(client.getsockname()[1])] if kind == "node" else ["echo"]
    proc, port = _spawn(args, tmp)
    try:
        client_loop(client, (LOOP, port), min(500, count), max_seconds, kind == "node", 60000)  # warm-up
        best: dict[str, float] = {}
        for r in range(rounds):
            cpu0 = _cpu_s(proc.pid)
            lat, lost, elapsed = client_loop(client, (LOOP, port), count, max_seconds, kind == "node", r * count)
            cpu1 = _cpu_s(proc.pid)
            if not lat:
                continue
            rate = len(lat) / elapsed
            if rate > best.get("rate", 0.0):
                q = statistics.quantiles(lat, n=100)
                best = {"rate": rate, "p50": q[49], "p99": q[98], "n": len(lat), "lost": lost}
                if cpu0 is not None and cpu1 is not None:
                    best["cpu"] = (cpu1 - cpu0) / (len(lat) + lost)
        return best
    finally:
        proc.terminate()
        try:
            proc.wait(5)
        except subprocess.TimeoutExpired:
            proc.kill()
        client.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--count", type=int, default=5000, help="round trips per round (default 5000)")
    ap.add_argument("--max-seconds", type=float, default=5.0, help="time limit per round (default 5)")
    ap.add_argument("--rounds", type=int, default=3, help="rounds; the best is reported (default 3)")
    ap.add_argument("--endpoint", action="store_true", help="the sans-I/O endpoint alone: CPU per datagram")
    ap.add_argument("--serve", choices=["node", "echo"], help=argparse.SUPPRESS)
    ap.add_argument("--port-file", help=argparse.SUPPRESS)
    ap.add_argument("--client-port", type=int, default=0, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.serve == "node":
        serve_node(args.port_file, args.client_port)
        return 0
    if args.serve == "echo":
        serve_echo(args.port_file)
        return 0
    if args.count < 1 or args.rounds < 1 or args.max_seconds <= 0:
        ap.error("--count, --rounds and --max-seconds must be positive")
    if args.endpoint:
        return endpoint_cpu(args.count, args.rounds)
    tmp = Path(os.environ.get("TMPDIR", "/tmp"))
    print(f"python {platform.python_version()} on {platform.machine()}, {os.cpu_count()} CPUs; "
          f"{args.count} round trips x {args.rounds} rounds (best), loopback")
    results = {kind: measure(kind, args.count, args.max_seconds, args.rounds, tmp) for kind in ("echo", "node")}
    for kind, label in (("echo", "plain-Python UDP echo"), ("node", "reference node ACK")):
        r = results[kind]
        if not r:
            print(f"{label:24s}: no round trip completed")
            continue
        cpu = f"   server CPU {r['cpu'] * 1e6:5.1f} us/rt" if "cpu" in r else ""
        print(f"{label:24s}: {r['rate']:9.0f} rt/s   p50 {r['p50'] * 1e6:7.1f} us   "
              f"p99 {r['p99'] * 1e6:7.1f} us   ({r['n']:.0f} rt, {r['lost']:.0f} lost){cpu}")
    if results["echo"] and results["node"]:
        ratio = results["node"]["rate"] / results["echo"]["rate"]
        verdict = "meets" if ratio >= 0.5 else "MISSES"
        print(f"node / echo rate: {ratio:.2f}  ({verdict} the target of >= 0.50)")
    return 0


# ---------------------------------------------------------------- --endpoint
def endpoint_cpu(count: int, rounds: int) -> int:
    """CPU per datagram of the sans-I/O endpoint alone (module docstring, ``--endpoint``)."""
    from mcp_conform.reference_impl.endpoint import Endpoint
    from mcp_conform.spec.codec import DecodeError, decode
    from mcp_conform.spec.generators import malformed_corpus

    addr = (LOOP, 14550)
    flood = [d for _, d in malformed_corpus(1, 8, dst=NODE_ID, src=0, first_seq=100,
                                            kinds=["bad_preamble", "unknown_action", "count_mismatch"])]
    unicasts = [encode(Message(NODE_ID, 0, i & 0xFFFF, Action.WP_OFF, None)) for i in range(count)]
    malformed = [flood[i % len(flood)] for i in range(count)]

    def endpoint_alone(datagrams: list[bytes]) -> float:
        ep = Endpoint(NODE_ID, initial_seq=0)
        receive, events, out, cpu = ep.receive_datagram, ep.events, ep.datagrams_to_send, time.process_time
        t0 = cpu()
        for data in datagrams:
            receive(data, addr, 0.0)
            events()
            out()
        return (cpu() - t0) / len(datagrams)

    def read_then_endpoint(datagrams: list[bytes]) -> float:
        ep = Endpoint(NODE_ID, initial_seq=0)
        receive, events, out, cpu = ep.receive_datagram, ep.events, ep.datagrams_to_send, time.process_time
        t0 = cpu()
        for data in datagrams:
            try:
                decode(data)
            except DecodeError:
                pass
            receive(data, addr, 0.0)
            events()
            out()
        return (cpu() - t0) / len(datagrams)

    print(f"python {platform.python_version()} on {platform.machine()}; the sans-I/O endpoint alone, "
          f"{count} datagrams x {rounds} rounds (best), CPU per datagram")
    for label, run, data in (("unicast, ACKed and delivered", endpoint_alone, unicasts),
                             ("malformed (MCP-ROB-7 flood)", endpoint_alone, malformed),
                             ("malformed, read, then endpoint", read_then_endpoint, malformed)):
        best = min(run(data) for _ in range(rounds))
        print(f"{label:32s}: {best * 1e6:6.2f} us")
    return 0


if __name__ == "__main__":
    sys.exit(main())

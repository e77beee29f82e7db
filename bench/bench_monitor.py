"""Trace monitor benchmark: datagrams judged per second from an in-memory trace.

    python bench/bench_monitor.py [--datagrams N] [--drones N] [--rounds N]

Builds one long clean conversation (the manager and N drones, challenge 2: WP_On / WP_Off
cycling the mission's waypoints, every command ACKed, 2 % of ACKs lost so retransmissions
happen) with the scripted-mission builder of the tests, then times, in the same run and over
the same datagrams:

- struct decode only: ``spec.codec.decode`` of every datagram (the floor: parsing alone);
- the monitor, lossy: ``Monitor.datagram`` for every datagram, then ``finish``;
- the monitor, complete: the same with ``complete=True`` (absence deadlines armed).

Prints datagrams/s (best of N rounds). The target is >= 150,000 datagrams/s in memory
(docs/design.md, "Performance targets"). Figures only: nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import platform
import random
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a source checkout

from mcp_conform.judge.monitor import Monitor  # noqa: E402
from mcp_conform.spec.codec import DecodeError, decode  # noqa: E402
from tests.judge.monitor_scripts import WAYPOINTS, Script  # noqa: E402

TARGET = 150_000


def build(datagrams: int, drones: int, seed: int) -> Script:
    """Challenge 2 cycling the mission's waypoints: WP_On / WP_Off to each drone, round after
    round, until the trace holds about ``datagrams`` datagrams."""
    rng = random.Random(seed)

    def vary() -> dict[str, object]:
        return {"lost_acks": 1 if rng.random() < 0.02 else 0, "ack_delay": rng.uniform(0.001, 0.01)}
    s = Script(range(1, drones + 1), challenge=2, waypoints=WAYPOINTS, vary=vary, vehicle=False, seed=seed)
    for d in s.drones:
        s.ready(d)
    for d in s.drones:
        s.start(d)
    while len(s.records) < datagrams:
        s.challenge_steps()
    for d in s.drones:
        s.end(d)
    return s


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--datagrams", type=int, default=300_000)
    ap.add_argument("--drones", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=3)
    args = ap.parse_args()

    t0 = time.perf_counter()
    script = build(args.datagrams, args.drones, seed=1)
    trace = [(r.t_ns, r.src_addr, r.dst_addr, r.data) for r in script.datagrams()]
    end = script.end_ns()
    n = len(trace)
    print(f"trace: {n:,} datagrams, manager + {args.drones} drones, challenge 2 "
          f"(built in {time.perf_counter() - t0:.1f} s); python {platform.python_version()}")

    def decode_only() -> None:
        for _, _, _, data in trace:
            try:
                decode(data)
            except DecodeError:
                pass

    def monitor(complete: bool) -> None:
        m = Monitor(rto=script.rto, ack_window=script.ack_window, challenge=2,
                    waypoints=script.items, complete=complete)
        feed = m.datagram
        found = 0
        for t, src, dst, data in trace:
            found += len(feed(t, src, dst, data))
        found += len(m.finish(end))
        if found:
            raise SystemExit(f"the clean trace raised {found} violation(s): a monitor bug")

    rows = [("struct decode only (spec.codec.decode)", decode_only),
            ("monitor, lossy trace", lambda: monitor(False)),
            ("monitor, complete trace", lambda: monitor(True))]
    print(f"  {'':<40} {'wall clock':>14} {'CPU time':>14}   (best of {args.rounds}; CPU time "
          "is this process's, so a loaded host skews it less)")
    for label, fn in rows:
        best = best_cpu = 0.0
        for _ in range(args.rounds):
            t, c = time.perf_counter(), time.process_time()
            fn()
            best = max(best, n / (time.perf_counter() - t))
            best_cpu = max(best_cpu, n / max(1e-9, time.process_time() - c))
        mark = "" if label.startswith("struct") else (
            f"  target >= 150,000/s: wall {'met' if best >= TARGET else 'NOT met'}, "
            f"CPU {'met' if best_cpu >= TARGET else 'NOT met'}")
        print(f"  {label:<40} {best:>12,.0f}/s {best_cpu:>12,.0f}/s{mark}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

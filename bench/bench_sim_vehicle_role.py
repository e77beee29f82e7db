"""The MAVLink vehicle role in the simulator (``mcp_conform.sim.vehicle_role``, issue 38 item 4):
wall and CPU time per whole-suite run, its virtual time and thread switches, and runs a minute,
for the reference vehicle over TCP and UDP and the faults of ``sim.vehicle_faults``; ``--impair``
the runner's link, ``--stalls P,MAX_S`` the runner's threads stalled.

    python bench/bench_sim_vehicle_role.py [--runs 3] [--faults none,double-ack,...] [--impair SPEC] [--stalls P,S]

Each row: the vehicle, the transport, the rules that failed (the SHOULD warnings of our vehicle,
ArduCopter's errata, left out), the run's length on the virtual clock, its wall and CPU time in
this process (the median of ``--runs``), and what that makes a minute. Figures only: nothing
here asserts a timing. Compare with a real run, ``mcp-conform --protocol mavlink`` (the same
suite against ``mcp-vehicle`` on real timers: ~43 s wall). An ``--impair`` that loses or reorders
fails rules over UDP (udpout): the suite reads its link as loopback (no command is resent,
MAV-HB-11 counts sequence numbers), which TCP keeps and UDP does not.

Measured (2-core host, another helper's tests beside it; --runs 3, median): a whole suite
~0.7 CPU s for ~41 virtual s (reference over tcp 0.69 s, udpout 0.74 s; a fault 0.80-0.86 s),
~60-80 runs a wall minute; through loss=0.1,dup=0.05,reorder=0.1,delay=0-50ms with the runner's
threads stalled (0.1, 0.5) over tcp 0.98 s for 72 virtual s.
"""

from __future__ import annotations

import argparse
import statistics
import time

from mcp_conform.sim.vehicle_faults import RULES
from mcp_conform.sim.vehicle_role import run_vehicle_cases


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--faults", default="reference," + ",".join(RULES))
    ap.add_argument("--impair", default=None, help="the runner's link, both ways (harness.impair spec)")
    ap.add_argument("--stalls", default=None, help="P,MAX_S: the runner's threads stalled")
    a = ap.parse_args()
    stalls = tuple(float(x) for x in a.stalls.split(",")) if a.stalls else None
    print(f"{'vehicle':26} {'link':6} {'failed':24} {'virtual':>8} {'switches':>8} {'wall':>7} {'cpu':>7} {'runs/min':>8}")
    for name in a.faults.split(","):
        for transport in (("tcp", "udpout") if name == "reference" else ("tcp",)):
            walls, cpus = [], []
            for seed in range(a.runs):
                w0, c0 = time.perf_counter(), time.process_time()
                run = run_vehicle_cases(None if name == "reference" else name, seed=seed, transport=transport,
                                        link=a.impair, stalls=stalls)  # type: ignore[arg-type]
                walls.append(time.perf_counter() - w0)
                cpus.append(time.process_time() - c0)
            wall, cpu = statistics.median(walls), statistics.median(cpus)
            bad = ",".join(sorted(run.rules_with("failed", "error"))) or "-"
            print(f"{name:26} {transport:6} {bad:24} {run.virtual_s:7.1f}s {run.switches:8d} {wall:6.2f}s "
                  f"{cpu:6.2f}s {60 / wall:8.1f}")


if __name__ == "__main__":
    main()

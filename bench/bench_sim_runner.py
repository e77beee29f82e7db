"""The runner's drone cases in the simulator (``mcp_conform.sim.runner``, issue 38 item 2): wall
and CPU time per run, virtual time, and runs a minute, for the reference drone and the drone
faults of ``sim.faults``, at the short timings and the description's 5 s ones; ``--mavlink``: with
the runner's vehicle on the same clock (``run_cases(..., mavlink=True)``, sim.vehicle), the
models the sample node's mutants of ``sim.mutants`` may name too (``--models arm-early,...``;
``--models vehicle``: the reference and the 12 mutants observed on the vehicle's link).

    python bench/bench_sim_runner.py [--runs 3] [--impair SPEC] [--mavlink] [--models ...]

Each row: the model, the timing, the verdicts that failed or warned (cases and monitor), the
run's length on the virtual clock, its wall and CPU time in this process (the median of
``--runs``), and what that makes a minute. Figures only: nothing here asserts a timing. Compare
with ``bench/bench_suite.py`` (the same suite against a spawned node on real timers).
"""

from __future__ import annotations

import argparse
import statistics
import time

from mcp_conform.sim.faults import FAULTS
from mcp_conform.sim.mutants import MUTANTS, NEEDS_VEHICLE, mutant_factory
from mcp_conform.sim.runner import run_cases

TIMINGS = {"short": {"rto": 0.2, "ack_window": 0.25}, "5s": {"rto": 5.0, "ack_window": 2.0}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--impair", default=None, help="the runner's --impair for every run")
    ap.add_argument("--models", default="reference," + ",".join(n for n, f in FAULTS.items() if f.role == "drone"))
    ap.add_argument("--mavlink", action="store_true", help="with the runner's vehicle")
    a = ap.parse_args()
    extra = ("--impair", a.impair) if a.impair else ()
    if a.models == "vehicle":
        a.models, a.mavlink = "reference," + ",".join(NEEDS_VEHICLE), True
    print(f"{'model':24} {'timing':6} {'verdicts':34} {'virtual':>8} {'wall':>7} {'cpu':>7} {'runs/min':>8}")
    for name in a.models.split(","):
        for label, timing in TIMINGS.items():
            walls, cpus = [], []
            for seed in range(a.runs):
                model = (None if name == "reference" else name if name in FAULTS
                         else mutant_factory(name, rto=timing["rto"], seed=seed) if name in MUTANTS else name)
                w0, c0 = time.perf_counter(), time.process_time()
                run = run_cases(model, seed=seed, extra=extra, mavlink=a.mavlink, **timing)
                walls.append(time.perf_counter() - w0)
                cpus.append(time.process_time() - c0)
            wall, cpu = statistics.median(walls), statistics.median(cpus)
            bad = ",".join(f"{r}:{o[0]}" for r, o in sorted(run.rules_with("failed", "warned").items())) or "-"
            print(f"{name:24} {label:6} {bad:34} {run.virtual_s:7.1f}s {wall:6.2f}s {cpu:6.2f}s {60 / wall:8.1f}")


if __name__ == "__main__":
    main()

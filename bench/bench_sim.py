"""How many schedules a minute the simulator runs (issue 38, Done-when: >= 10,000 a minute) for
the correct models -- the reference drone(s) and manager of ``sim.models`` over the schedules
``sim.search.draw_schedule`` draws (the runner's ``harness.impair`` link with delays up to 3 x
``--rto``, stalls, 1-3 drones, challenges 1-3) -- with the judges off, the trace monitor alone, ``judge.explain``
alone (tests/sim/test_properties' searches run one judge each), and both, printed side by side. The same schedules in each column (one seed)::

    python bench/bench_sim.py [--seconds S] [--seed N]

Figures only: nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import platform
import random
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a source checkout

from mcp_conform.sim.schedule import run_schedule  # noqa: E402
from mcp_conform.sim.search import draw_schedule  # noqa: E402

MODES = (("judges off", False, True, False), ("monitor", True, True, False), ("explain", True, False, True),
         ("monitor + explain", True, True, True))


def rate(seconds: float, seed: int, judge: bool, monitor: bool, explain: bool) -> tuple[float, float, int, int]:
    """Schedules a minute (of wall time, and of this process's CPU time: on a shared machine
    the second is what one core gives), schedules run, datagrams seen by the parties."""
    rng = random.Random(seed)
    n = datagrams = 0
    t0, c0 = time.perf_counter(), time.process_time()
    while time.perf_counter() - t0 < seconds:
        o = run_schedule(draw_schedule(rng), judge=judge, monitor=monitor, explain=explain)
        n += 1
        datagrams += sum(len(v) for v in o.world.views.values())
    dt, cpu = time.perf_counter() - t0, time.process_time() - c0
    return 60.0 * n / dt, 60.0 * n / max(cpu, 1e-9), n, datagrams


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seconds", type=float, default=10.0, help="time per column (default 10)")
    p.add_argument("--seed", type=int, default=1)
    ns = p.parse_args(argv)
    if not 0 < ns.seconds <= 60:
        p.error("--seconds must be within (0, 60]")
    print(f"python {platform.python_version()} on {platform.machine()}; correct models, {ns.seconds:g} s each")
    rows = [(name, *rate(ns.seconds, ns.seed, judge, monitor, explain)) for name, judge, monitor, explain in MODES]
    print(f"{'':20}" + "".join(f"{name:>20}" for name, *_ in rows))
    print(f"{'schedules/minute':20}" + "".join(f"{r:>20,.0f}" for _, r, _, _, _ in rows))
    print(f"{'  per CPU minute':20}" + "".join(f"{c:>20,.0f}" for _, _, c, _, _ in rows))
    print(f"{'schedules run':20}" + "".join(f"{n:>20,}" for _, _, _, n, _ in rows))
    print(f"{'datagrams/schedule':20}" + "".join(f"{d / max(n, 1):>20.1f}" for _, _, _, n, d in rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())

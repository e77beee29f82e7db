"""What one simulated run of the runner's suite costs, and where (issue 38: the quick tests run
several hundred of them). For each kind of run -- the drone cases (``sim.runner.run_cases``:
alone, with the vehicle, a mutant of the sample node), the manager role, the MAVLink vehicle and
gcs roles -- the CPU seconds of one run in a warm process (the median of ``--runs``; the first
run of a process, which imports everything, is left out and shown apart), split by the phases of
its nested pytest session, and the virtual clock's thread switches::

    python bench/bench_sim_run.py [--runs 5] [--kinds drone,mutant,...] [--src CHECKOUT]
    python bench/bench_sim_run.py --flood [--runs 7] [--src CHECKOUT]

``--src``: import ``mcp_conform`` from another checkout (``git archive <commit> | tar -x -C
DIR``): the same bench before and after a change, run alternately so host noise hits both.

``--flood``: the simulator's per-datagram path alone, MCP-ROB-7's flood (issue 38): 10,000 of
the case's malformed datagrams (``flood_count``) from a side socket through the runner's
transport (:mod:`sim.transport`: the clean link, the delay queue) to the ``ack-zero`` mutant and
the reference drone model, CPU us a datagram (the median of ``--runs`` floods); and the lead's
recipe, a whole mutant run (``run_cases(mutant_factory("ack-zero", ...), mavlink=True)``) at
``flood_count`` and at 100, CPU s a run and the flood's share.

Phases (CPU ms a run): ``args`` the runner's command line made; ``start`` pytest's configuration
and plugins, to the session's start; ``collect`` the case modules collected; ``cases`` the run
of the cases (their setup, call and teardown: the protocol, the monitor, the clock's handoffs);
``report`` the session's end (the JSON report written). Figures only: nothing here asserts a
timing.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
if "--src" in sys.argv:  # another checkout's code (before/after): before anything imports it
    ROOT = Path(sys.argv[sys.argv.index("--src") + 1]).resolve()
sys.path.insert(0, str(ROOT))  # run from a source checkout

PHASES = ("args", "start", "collect", "cases", "report")


class _Phases:
    """CPU marks at the nested session's boundaries (one run at a time: the clock runs one
    thread at a time, so the process's CPU between two marks is that phase's)."""

    def __init__(self) -> None:
        self.marks: list[tuple[str, float]] = []

    def mark(self, name: str) -> None:
        self.marks.append((name, time.process_time()))

    @pytest.hookimpl(tryfirst=True)
    def pytest_sessionstart(self, session: Any) -> None:
        self.mark("start")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_collection(self, session: Any) -> Any:
        yield
        self.mark("collect")

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtestloop(self, session: Any) -> Any:
        yield
        self.mark("cases")


def _kinds() -> dict[str, Callable[[int], Any]]:
    from mcp_conform.sim.gcs_role import run_gcs_cases
    from mcp_conform.sim.manager_runner import run_manager_cases
    from mcp_conform.sim.mutants import mutant_factory
    from mcp_conform.sim.runner import run_cases
    from mcp_conform.sim.vehicle_role import run_vehicle_cases

    return {
        "drone": lambda s: run_cases(None, seed=s),
        "drone-mavlink": lambda s: run_cases(None, seed=s, mavlink=True),
        "mutant": lambda s: run_cases(mutant_factory("ack-zero", rto=0.2, seed=s), seed=s, rto=0.2, ack_window=0.25,
                                      mavlink=True),
        "manager": lambda s: run_manager_cases(None, seed=s),
        "vehicle": lambda s: run_vehicle_cases(None, seed=s),
        "gcs": lambda s: run_gcs_cases(None, seed=s),
    }


def _flood_once(make_model: Callable[[float], Any], count: int) -> float:
    """CPU s of ``count`` flood datagrams sent and read by the model, on a fresh clock."""
    from mcp_conform.harness.clock import VirtualClock
    from mcp_conform.sim.transport import SimTransport
    from mcp_conform.spec.generators import malformed_corpus

    clock = VirtualClock()
    t = SimTransport(clock)
    t.bind(("127.0.0.1", 0))
    corpus = [d for _, d in malformed_corpus(1, 20, dst=1, src=0, first_seq=100,
                                              kinds=["bad_preamble", "unknown_action", "count_mismatch"])]
    out: list[float] = []

    def body() -> None:
        t.attach(make_model(clock.now))
        clock.sleep(0.5)  # the model started, its Mission_Ready sent
        sock = t.side_socket("127.0.0.1")
        target = t.model.addr
        c0 = time.process_time()
        many = getattr(sock, "sendto_many", None)
        if many is not None:  # harness.driver.flood on a virtual clock
            many(corpus, count, target)
        else:  # its loop, as the simulated case ran it before sendto_many
            for i in range(count):
                sock.sendto(corpus[i % len(corpus)], target)
        clock.sleep(0.01)  # every copy due and read
        out.append(time.process_time() - c0)
        sock.close()

    clock.run(body)
    return out[0]


def flood(runs: int) -> None:
    import random as _random

    from mcp_conform.sim.models import DroneModel
    from mcp_conform.sim.mutants import mutant_factory
    from mcp_conform.sim.runner import run_cases
    from mcp_conform.spec import SPEC

    count = int(SPEC.params["flood_count"])
    models = {"mutant ack-zero": lambda s: mutant_factory("ack-zero", rto=0.2, seed=s),
              "reference drone": lambda s: (lambda now: DroneModel(1, 0.2, 3, _random.Random(s), ready_at=now + 0.05))}
    print(f"flood of {count} datagrams through the sim transport (CPU us a datagram, median of {runs}) "
          f"[{ROOT}]")
    for name, make in models.items():
        _flood_once(make(0), count)
        per = [_flood_once(make(s), count) / count * 1e6 for s in range(1, runs + 1)]
        print(f"  {name:16} {statistics.median(per):6.2f} us  (min {min(per):.2f})", flush=True)

    def one(s: int) -> Any:
        return run_cases(mutant_factory("ack-zero", rto=0.2, seed=s), seed=s, rto=0.2, mavlink=True,
                         ack_window=0.25)

    one(0)
    res = {}
    for fc in (count, 100):
        SPEC.params["flood_count"] = fc
        cpus = []
        for s in range(1, runs + 1):
            c0 = time.process_time()
            one(s)
            cpus.append(time.process_time() - c0)
        res[fc] = statistics.median(cpus)
    SPEC.params["flood_count"] = count
    print(f"mutant run (ack-zero, mavlink): {res[count]:.3f} CPU s a run; at flood_count 100 {res[100]:.3f} s; "
          f"the flood {(res[count] - res[100]) / (count - 100) * 1e6:.1f} us a datagram in a run")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=5)
    ap.add_argument("--kinds", default="drone,drone-mavlink,mutant,manager,vehicle,gcs")
    ap.add_argument("--src", default="", help="a checkout to import mcp_conform from (before/after)")
    ap.add_argument("--flood", action="store_true", help="the per-datagram path: MCP-ROB-7's flood")
    a = ap.parse_args()
    if a.flood:
        flood(a.runs)
        return
    kinds = _kinds()
    phases = _Phases()
    real_main = pytest.main

    def timed_main(args: Any, plugins: Any = ()) -> Any:
        phases.mark("args")
        return real_main(args, plugins=[*plugins, phases])

    pytest.main = timed_main  # type: ignore[assignment]  # the sim's run_suite calls pytest.main
    print(f"{'kind':14} {'first':>6} {'cpu/run':>8} {'wall/run':>8} "
          + " ".join(f"{p:>7}" for p in PHASES) + f" {'switches':>8}  (CPU ms; first, cpu, wall: s)")
    for name in a.kinds.split(","):
        run = kinds[name]
        c0 = time.process_time()
        run(0)
        first = time.process_time() - c0
        cpus, walls, split = [], [], {p: [] for p in PHASES}  # type: ignore[var-annotated]
        for seed in range(1, a.runs + 1):
            phases.marks.clear()
            w0, c0 = time.perf_counter(), time.process_time()
            r = run(seed)
            c1 = time.process_time()
            walls.append(time.perf_counter() - w0)
            cpus.append(c1 - c0)
            prev = c0
            seen = dict(phases.marks)
            for p in PHASES:
                t = seen.get(p, c1) if p != "report" else c1
                split[p].append(t - prev)
                prev = t
        print(f"{name:14} {first:6.2f} {statistics.median(cpus):8.3f} {statistics.median(walls):8.3f} "
              + " ".join(f"{statistics.median(split[p]) * 1000:7.0f}" for p in PHASES) + f" {r.switches:8d}",
              flush=True)
    pytest.main = real_main  # type: ignore[assignment]


if __name__ == "__main__":
    main()

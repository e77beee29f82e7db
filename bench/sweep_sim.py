"""A long sweep of the simulator over many schedules (issue 38, Done-when: "10^6 schedules over
the correct models give 0 false verdicts; every fault model is found with its rule wherever
observable"), split over worker processes, each drawing its own share from its own seed
(``sim.search.sweep``: the correct models, or every model in turn with ``--faults``), bounded
in count and time, every failure kept at once as a replayable seed file
(``sim.search.save_seed``: ``python -c "from mcp_conform.sim.search import replay; ..."``)::

    python bench/sweep_sim.py --schedules 1000000 --jobs 2 --minutes 120 --out /tmp/sweep

Progress goes to ``OUT/progress.jsonl`` (one line per worker every ``--every`` schedules), the
totals to ``OUT/summary.json`` at the end, whatever ended it (the count, the time, Ctrl-C).
Figures only: nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import signal
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a source checkout

from mcp_conform.sim.faults import FAULTS  # noqa: E402
from mcp_conform.sim.search import save_seed, sweep  # noqa: E402


def _worker(i: int, n: int, seed: int, faults: bool, deadline: float, every: int, out: str) -> dict:
    models: tuple[str | None, ...] = (None, *FAULTS) if faults else (None,)
    base = Path(out)
    totals = {"worker": i, "seed": seed, "schedules": 0, "failures": 0, "per_fault": {}, "observable": {}}
    kept = 0

    def keep(s, problems) -> None:  # noqa: ANN001 - sim types
        nonlocal kept
        kept += 1
        save_seed(base / f"failure-w{i}-{kept}.json", s, problems, reason="found by bench/sweep_sim.py",
                  xfail=False)

    done = 0
    while done < n and time.time() < deadline:
        chunk = min(every, n - done)
        st = sweep(chunk, seed * 1_000_003 + done, models, on_failure=keep, stop=lambda: time.time() >= deadline)
        done += chunk
        totals["schedules"] += st.schedules
        totals["failures"] += len(st.failures)
        for k, v in st.per_fault.items():
            totals["per_fault"][k] = totals["per_fault"].get(k, 0) + v
        for k, v in st.observable.items():
            totals["observable"][k] = totals["observable"].get(k, 0) + v
        with open(base / "progress.jsonl", "a", encoding="utf-8") as f:
            f.write(json.dumps({**totals, "t": time.time()}) + "\n")
    return totals


def _interrupt(*_: object) -> None:
    raise KeyboardInterrupt


def _worker_signals() -> None:
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--schedules", type=int, default=100_000, help="in all, split over the jobs")
    p.add_argument("--jobs", type=int, default=2)
    p.add_argument("--minutes", type=float, default=30.0, help="a bound on the whole sweep")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--faults", action="store_true", help="every fault model in turn, not only the correct models")
    p.add_argument("--every", type=int, default=2000, help="schedules between progress lines")
    p.add_argument("--out", type=Path, required=True)
    ns = p.parse_args(argv)
    if ns.schedules < 1 or ns.jobs < 1 or ns.minutes <= 0 or ns.every < 1:
        p.error("--schedules, --jobs, --every must be at least 1 and --minutes above 0")
    ns.out.mkdir(parents=True, exist_ok=True)
    t0 = time.time()
    deadline = t0 + 60 * ns.minutes
    share = [ns.schedules // ns.jobs + (1 if i < ns.schedules % ns.jobs else 0) for i in range(ns.jobs)]
    results: list[dict] = []
    interrupted = False
    # Ctrl-C or SIGTERM: the parent stops the workers and writes the summary from their last
    # progress lines (set here: a shell starts a background job with SIGINT ignored); the
    # workers leave SIGINT to it (Ctrl-C reaches the whole process group)
    signal.signal(signal.SIGINT, _interrupt)
    signal.signal(signal.SIGTERM, _interrupt)
    with mp.get_context("fork").Pool(ns.jobs, initializer=_worker_signals) as pool:
        pending = [pool.apply_async(_worker, (i, share[i], ns.seed * 101 + i, ns.faults, deadline, ns.every,
                                              str(ns.out))) for i in range(ns.jobs)]
        try:
            results = [r.get() for r in pending]
        except KeyboardInterrupt:
            interrupted = True
            pool.terminate()
    if interrupted:  # what the workers wrote so far
        last: dict[int, dict] = {}
        for line in (ns.out / "progress.jsonl").read_text(encoding="utf-8").splitlines():
            d = json.loads(line)
            last[d["worker"]] = d
        results = list(last.values())
    total = sum(r["schedules"] for r in results)
    per_fault: dict[str, int] = {}
    observable: dict[str, int] = {}
    for r in results:
        for k, v in r["per_fault"].items():
            per_fault[k] = per_fault.get(k, 0) + v
        for k, v in r["observable"].items():
            observable[k] = observable.get(k, 0) + v
    wall = time.time() - t0
    summary = {"schedules": total, "failures": sum(r["failures"] for r in results), "per_fault": per_fault,
               "observable": observable, "wall_s": round(wall, 1), "jobs": ns.jobs, "seed": ns.seed,
               "schedules_per_wall_minute": round(60 * total / max(wall, 1e-9)), "interrupted": interrupted,
               "seeds": sorted(p.name for p in ns.out.glob("failure-*.json"))}
    (ns.out / "summary.json").write_text(json.dumps(summary, indent=1) + "\n", encoding="utf-8")
    print(json.dumps(summary, indent=1))
    return 1 if summary["failures"] else 0


if __name__ == "__main__":
    sys.exit(main())

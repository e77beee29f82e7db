"""``mcp-soak`` one mission after another and side by side (``--jobs``): the wall time of each,
and whether they ran the same missions (issue 38 item 7: 100 missions took ten minutes, about
6.2 s each, half of it starting processes).

    python bench/bench_soak_jobs.py [--missions 6] [--jobs 3] [--impair loss=0.3,dup=0.1,...]

Runs the same campaign (the reference manager and three drones, the same seeds) twice, in
this process: serial, then ``--jobs N``; prints wall time, missions per minute, p50 mission
time and each mission's (seed, challenge, outcome), side by side. Figures only, no asserts.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from mcp_conform.soak.cli import main as soak  # noqa: E402


def run(missions: int, jobs: int, impair: str, seed: int, tmp: Path) -> tuple[float, dict]:
    out = tmp / f"jobs{jobs}.json"
    t0 = time.monotonic()
    with contextlib.redirect_stdout(io.StringIO()):  # the table and bar: not the figures
        soak(["--missions", str(missions), "--jobs", str(jobs), "--impair", impair, "--seed", str(seed),
              "--out", str(tmp / f"out{jobs}"), "--json", str(out)])
    return time.monotonic() - t0, json.loads(out.read_text())


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--missions", type=int, default=6)
    p.add_argument("--jobs", type=int, default=3)
    p.add_argument("--impair", default="loss=0.3,dup=0.1,reorder=0.2,delay=0-50ms")
    p.add_argument("--seed", type=int, default=0)
    ns = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-soak-") as d:
        rows = [(jobs, *run(ns.missions, jobs, ns.impair, ns.seed, Path(d))) for jobs in (1, ns.jobs)]
    print(f"{ns.missions} missions, link {ns.impair}, seeds {ns.seed}..{ns.seed + ns.missions - 1}")
    print(f"{'':>10} {'wall s':>8} {'missions/min':>13} {'p50 mission s':>14} {'complete':>9}")
    for jobs, wall, doc in rows:
        label = "serial" if jobs == 1 else f"--jobs {jobs}"
        p50 = doc["mission_time_p50_s"]
        print(f"{label:>10} {wall:8.1f} {60 * ns.missions / wall:13.1f} "
              f"{'-' if p50 is None else f'{p50:.2f}':>14} {doc['complete']:>5}/{doc['missions']}")
    same = [[(r["seed"], r["challenge"], r["outcome"]) for r in doc["results"]] for _, _, doc in rows]
    print("missions (seed, challenge, outcome):", "the same" if same[0] == same[1] else "DIFFER")
    for a, b in zip(*same, strict=False):
        if a != b:
            print(f"  serial {a}  side by side {b}")
    print(f"speed-up: {rows[0][1] / rows[1][1]:.2f}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())

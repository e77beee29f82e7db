"""The manager-role suite's wall time, serial and side by side (issue 23), with the outcome
sets compared.

    python bench/bench_manager_suite.py [--challenges 1,2,3] [--faults none|all|NAME,...] [--runs N]

For each target, ``--runs`` times, one run after the other: ``mcp-conform --role manager
--serial`` (every scenario after the one before: the silent drone's after the main
mission, as before) and the default (the silent drone's scenario beside the main mission,
on a manager instance of its own: ``harness.manager_side``). Targets:

- ``ref cN``: the embedded reference manager (its short timeouts), challenge N — the
  figure of "the manager role per challenge";
- ``FAULT``: the independent sample manager (tests/conformance/nodes/sample_manager.py)
  with ``--fault FAULT``, at the challenge its test uses, at the short timeouts
  (``--rto 0.2 --ack-window 0.25``).

It prints each target's wall time (the process, start to exit; mean and max over the runs)
both ways, and whether every run gave every case the same outcome and the run's monitor
the same verdicts (the differences, if any). Figures only: nothing here asserts a timing.
"""

from __future__ import annotations

import argparse
import shlex
import statistics
import sys
from pathlib import Path

from bench_suite import run as suite_run  # bench/ is on sys.path when a bench runs

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "tests" / "conformance" / "nodes" / "sample_manager.py"
FAST = ["--rto", "0.2", "--ack-window", "0.25"]


def faults() -> dict[str, int]:
    """Every fault of the sample manager, with the challenge its test runs it at (1 if none)."""
    sys.path.insert(0, str(ROOT))
    from mcp_conform.sim.manager_faults import MANAGER_FAULTS  # the simulator's models, same names
    from tests.conformance.nodes.sample_manager import FAULTS

    return {f: MANAGER_FAULTS[f].challenge if f in MANAGER_FAULTS else 1 for f in FAULTS}


def sample_manager(fault: str) -> str:
    words = [sys.executable, str(SAMPLE), "--challenge", "{challenge}", "--drones", "{drones}", "--waypoints",
             "{waypoints}", "--obstacles", "{obstacles}", "--bind", "{target_host}:{target_port}", "--send-to",
             "{listen_host}:{listen_port}", "--rto", "0.2", "--retries", "12", "--fault", fault]
    return " ".join(shlex.quote(w) if "{" not in w else w for w in words)


def run(args: list[str]) -> tuple[float, dict]:
    """``mcp-conform --role manager ARGS``: its wall time and JSON report (bench_suite's run)."""
    return suite_run(["--role", "manager", *args])


def outcome(doc: dict) -> tuple:
    """What a run decided: each case's outcome and the run monitor's verdicts."""
    cases = tuple(sorted((c["id"], c["outcome"]) for c in doc.get("cases", [])))
    monitor = tuple(sorted((n, r, v) for n, t in (doc.get("monitor") or {}).get("rules", {}).items()
                           for r, v in t.items()))
    return cases, monitor, doc.get("error")


def describe(a: tuple, b: tuple) -> str:
    da, db = dict(a[0]), dict(b[0])
    out = [f"{c} {da.get(c)}->{db.get(c)}" for c in sorted(set(da) | set(db)) if da.get(c) != db.get(c)]
    ma, mb = {x[:2]: x[2] for x in a[1]}, {x[:2]: x[2] for x in b[1]}
    out += [f"monitor {k[1]} {ma.get(k)}->{mb.get(k)}" for k in sorted(set(ma) | set(mb)) if ma.get(k) != mb.get(k)]
    if a[2] != b[2]:
        out.append(f"error {a[2]!r}->{b[2]!r}")
    return "; ".join(out)


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--challenges", default="1,2,3", help="the reference manager's challenges ('' for none)")
    p.add_argument("--faults", default="none", help="none, all, or sample-manager faults, comma-separated")
    p.add_argument("--runs", type=int, default=1, help="runs of each target each way (default 1)")
    ns = p.parse_args()
    targets: list[tuple[str, list[str]]] = [(f"ref c{c}", ["--challenge", c])
                                            for c in ns.challenges.split(",") if c.strip()]
    if ns.faults != "none":
        table = faults()
        names = list(table) if ns.faults == "all" else ns.faults.split(",")
        targets += [(f, ["--spawn", sample_manager(f), "--challenge", str(table.get(f, 1)), *FAST]) for f in names]
    print(f"{'target':<18} {'runs':>4} {'serial s (max)':>15} {'side by side s (max)':>21}  same outcomes")
    different = 0
    for name, args in targets:
        walls: dict[str, list[float]] = {"serial": [], "side": []}
        seen: list[tuple[str, tuple]] = []
        for _ in range(ns.runs):
            for mode, extra in (("serial", ["--serial"]), ("side", [])):
                wall, doc = run([*args, *extra])
                walls[mode].append(wall)
                seen.append((mode, outcome(doc)))
        first = seen[0][1]
        diffs = [f"{mode} run: {describe(first, o)}" for mode, o in seen[1:] if o != first]
        same = "yes" if first[0] and not diffs else ("NO REPORT: " + str(first[2]) if not first[0] else
                                                     f"NO ({len(diffs)} of {len(seen)} runs differ)")
        different += bool(diffs) or not first[0]
        s, q = walls["serial"], walls["side"]
        print(f"{name:<18} {ns.runs:>4} {statistics.mean(s):9.2f} ({max(s):4.1f}) "
              f"{statistics.mean(q):15.2f} ({max(q):4.1f})  {same}")
        for d in diffs[:5]:
            print(f"{'':<18}   {d}")
    return 1 if different else 0


if __name__ == "__main__":
    sys.exit(main())

"""The drone suite's wall time, serial and scheduled (issue 23), with the outcome sets compared.

    python bench/bench_suite.py [--only embedded,rto0.3,rto5] [--node CMD]

In one run, one after the other, each target twice — ``mcp-conform --serial`` (every case
alone, the schedule of before) and the default schedule (``conformance.schedule``: the
windows of the cases that only wait watched together):

- ``embedded``: the reference node with its short timeouts (the embedded default);
- ``rto0.3``: a spawned node of our own (the independent sample node,
  tests/conformance/nodes/sample_node.py) at ``--rto 0.3`` and the default 2 s window;
- ``rto5``: the same at the description's ``--rto 5`` and ``--ack-window 2``.

It prints each run's wall time (the process, start to exit) and the suite's own
``duration_s``, the speed-up, what became of the batch, and whether the two runs gave every
case the same outcome (the cases that differ, if any). Figures only: nothing here asserts a
timing.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "tests" / "conformance" / "nodes" / "sample_node.py"


def sample_node(rto: float) -> str:
    return (f"{shlex.quote(sys.executable)} {shlex.quote(str(SAMPLE))} --id {{id}} --bind {{target_host}}:{{target_port}} "
            f"--send-to {{listen_host}}:{{listen_port}} --mavlink {{mavlink}} --rto {rto:g}")


def targets(node: str | None) -> dict[str, list[str]]:
    spawn = (lambda rto: node.replace("{rto}", f"{rto:g}")) if node else sample_node
    return {
        "embedded": [],
        "rto0.3": ["--spawn", spawn(0.3), "--mavlink", "--rto", "0.3"],
        "rto5": ["--spawn", spawn(5.0), "--mavlink", "--rto", "5", "--ack-window", "2"],
    }


def run(args: list[str]) -> tuple[float, dict]:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "report.json"
        cmd = [sys.executable, "-m", "conformance", *args, "--json", str(path)]
        env = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1")
        t0 = time.monotonic()
        subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, env=env, timeout=900)
        wall = time.monotonic() - t0
        doc = json.loads(path.read_text()) if path.exists() else {}
    return wall, doc


def outcomes(doc: dict) -> dict[str, str]:
    return {c["id"]: c["outcome"] for c in doc.get("cases", [])}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", default="embedded,rto0.3,rto5", help="targets, comma-separated")
    p.add_argument("--node", help="another drone's --spawn command, with {rto} where its timeout goes")
    ns = p.parse_args()
    table = targets(ns.node)
    print(f"{'target':<10} {'serial s':>9} {'scheduled s':>12} {'speed-up':>9}  same outcomes  batch")
    for name in ns.only.split(","):
        args = table[name]
        s_wall, s_doc = run([*args, "--serial"])
        p_wall, p_doc = run(args)
        a, b = outcomes(s_doc), outcomes(p_doc)
        diff = sorted(c for c in set(a) | set(b) if a.get(c) != b.get(c))
        same = "yes" if a and not diff else f"NO: {', '.join(f'{c} {a.get(c)}->{b.get(c)}' for c in diff)}"
        if not a:
            same = f"no report ({s_doc.get('error') or p_doc.get('error')})"
        batch = (p_doc.get("schedule") or {}).get("batch_outcome")
        print(f"{name:<10} {s_wall:9.1f} {p_wall:12.1f} {s_wall / p_wall if p_wall else 0:8.1f}x  {same:<13}  {batch}")
        print(f"{'':<10} (the suites' own durations: {s_doc.get('summary', {}).get('duration_s')} s serial, "
              f"{p_doc.get('summary', {}).get('duration_s')} s scheduled)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

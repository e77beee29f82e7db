"""The drone suite's wall time, serial and scheduled (issue 23), with the outcome sets compared.

    python bench/bench_suite.py [--only embedded,rto0.3,rto5] [--node CMD] [--parallel 2,3,4]

In one run, one after the other, each target twice — ``mcp-conform --serial`` (every case
alone, the schedule of before) and the default schedule (``conformance.schedule``: the
windows of the cases that only wait watched together) — and once more per ``--parallel N``
asked (the scheduled suite shared out across N node instances, ``conformance.parallel``):

- ``embedded``: the reference node with its short timeouts (the embedded default);
- ``rto0.3``: a spawned node of our own (the independent sample node,
  tests/conformance/nodes/sample_node.py) at ``--rto 0.3`` and the default 2 s window;
- ``rto5``: the same at the description's ``--rto 5`` and ``--ack-window 2``.

It prints each run's wall time (the process, start to exit) and the suite's own
``duration_s``, the speed-up, what became of the batch, and whether every run gave every
case the serial run's outcome (the cases that differ, if any). Figures only: nothing here
asserts a timing.
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


def compare(a: dict[str, str], b: dict[str, str], doc: dict) -> str:
    """'yes', or how run ``b``'s outcomes differ from the serial run's ``a``."""
    if not a or not b:
        return f"no report ({doc.get('error')})"
    diff = sorted(c for c in set(a) | set(b) if a.get(c) != b.get(c))
    return "yes" if not diff else f"NO: {', '.join(f'{c} {a.get(c)}->{b.get(c)}' for c in diff)}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--only", default="embedded,rto0.3,rto5", help="targets, comma-separated")
    p.add_argument("--node", help="another drone's --spawn command, with {rto} where its timeout goes")
    p.add_argument("--parallel", default="", help="also run the scheduled suite with --parallel N, for each N "
                   "(comma-separated)")
    ns = p.parse_args()
    table = targets(ns.node)
    ways = [int(n) for n in ns.parallel.split(",") if n.strip()]
    head = "".join(f" {f'p{n} s':>7}" for n in ways)
    print(f"{'target':<10} {'serial s':>9} {'scheduled s':>12}{head} {'speed-up':>9}  same outcomes  batch")
    for name in ns.only.split(","):
        args = table[name]
        s_wall, s_doc = run([*args, "--serial"])
        p_wall, p_doc = run(args)
        par = [(n, *run([*args, "--parallel", str(n)])) for n in ways]
        a = outcomes(s_doc)
        same = [f"scheduled {compare(a, outcomes(p_doc), p_doc)}"]
        same += [f"p{n} {compare(a, outcomes(doc), doc)}" for n, _, doc in par]
        walls = "".join(f" {w:7.1f}" for _, w, _ in par)
        best = min([p_wall, *(w for _, w, _ in par)])
        batch = (p_doc.get("schedule") or {}).get("batch_outcome")
        print(f"{name:<10} {s_wall:9.1f} {p_wall:12.1f}{walls} {s_wall / best if best else 0:8.1f}x  "
              f"{'; '.join(same)}  {batch}")
        print(f"{'':<10} (the suites' own durations: {s_doc.get('summary', {}).get('duration_s')} s serial, "
              f"{p_doc.get('summary', {}).get('duration_s')} s scheduled"
              + "".join(f", {doc.get('summary', {}).get('duration_s')} s p{n}" for n, _, doc in par) + ")")
    return 0


if __name__ == "__main__":
    sys.exit(main())

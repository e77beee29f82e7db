"""The drone suite's wall time, serial and scheduled (issue 23), with the outcome sets compared,
for the reference node and for nodes the schedule was not written with (issue 35).

    python bench/bench_suite.py [--only embedded,independent@0.3,...] [--node CMD] [--parallel 2,3,4]

In one run, one after the other, each target twice — ``mcp-conform --serial`` (every case
alone, the schedule of before) and the default schedule (``conformance.schedule``: the
windows of the cases that only wait watched together) — and once more per ``--parallel N``
asked (the scheduled suite shared out across N node instances, ``conformance.parallel``).
A target is ``embedded`` (the reference node with its short timeouts, the embedded default)
or ``NODE@RTO``: a spawned node at ``--rto RTO`` (the node's and the runner's; at ``--rto 5``,
the description's, with ``--ack-window 2``) and the default 2 s window, NODE one of

- ``reference``: the reference node (``python -m mcp_conform.reference_impl drone``);
- ``sample``: the independent sample node, threads (tests/conformance/nodes/sample_node.py);
  ``rto0.3`` and ``rto5`` are ``sample@0.3`` and ``sample@5``;
- ``independent``: the single-threaded ``select``-loop node that remembers only the last seq
  per src (tests/conformance/nodes/independent_node.py): its batch was thrown away in every
  run until MCP-DUP-1's message and copy went in a row (issue 35);
- ``dronekit``, ``mavsdk``: the example applications (examples/apps/dronekit_drone.py,
  mavsdk_drone.py), when they are there (else the row says why it was skipped);
- ``custom``: ``--node CMD``, with ``{rto}`` where its timeout goes.

It prints each run's wall time (the process, start to exit) and the suite's own
``duration_s``, the speed-up, what became of the batch (``batch_outcome``: "kept", or why its
cases ran again one by one), and whether every run gave every case the serial run's outcome
(the cases that differ, if any). Figures only: nothing here asserts a timing.
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
NODES_DIR = ROOT / "tests" / "conformance" / "nodes"
SAMPLE = NODES_DIR / "sample_node.py"
INDEPENDENT = NODES_DIR / "independent_node.py"
APPS = {"dronekit": ROOT / "examples" / "apps" / "dronekit_drone.py",
        "mavsdk": ROOT / "examples" / "apps" / "mavsdk_drone.py"}
DEFAULT = ("embedded,reference@0.3,sample@0.3,independent@0.3,dronekit@0.3,mavsdk@0.3,"
           "sample@5,independent@5,dronekit@5,mavsdk@5")
ALIASES = {"rto0.3": "sample@0.3", "rto5": "sample@5"}
PY = shlex.quote(sys.executable)


def sample_node(rto: float) -> str:
    return (f"{PY} {shlex.quote(str(SAMPLE))} --id {{id}} --bind {{target_host}}:{{target_port}} "
            f"--send-to {{listen_host}}:{{listen_port}} --mavlink {{mavlink}} --rto {rto:g}")


def node_command(name: str, rto: float, custom: str | None = None) -> tuple[str | None, str]:
    """(the ``--spawn`` command of node ``name`` at ``rto``, or None; why not)."""
    if name == "custom":
        return (custom.replace("{rto}", f"{rto:g}"), "") if custom else (None, "no --node given")
    if name == "sample":
        return sample_node(rto), ""
    if name == "independent":
        return sample_node(rto).replace(shlex.quote(str(SAMPLE)), shlex.quote(str(INDEPENDENT))), ""
    if name == "reference":
        return (f"{PY} -m mcp_conform.reference_impl drone --id {{id}} --bind {{target_host}}:{{target_port}} "
                f"--send-to {{listen_host}}:{{listen_port}} --mavlink {{mavlink}} --rto {rto:g}"), ""
    if name in APPS:
        app = APPS[name]
        if not app.exists():
            return None, f"{app.relative_to(ROOT)} is not in this checkout"
        return (f"{PY} {shlex.quote(str(app))} --id {{id}} --listen {{target_port}} "
                f"--manager {{listen_host}}:{{listen_port}} --autopilot {{mavlink}} --rto {rto:g}"), ""
    return None, f"unknown node {name!r} (reference, sample, independent, dronekit, mavsdk, custom)"


def target(name: str, custom: str | None = None) -> tuple[list[str] | None, str]:
    """The runner's arguments for target ``name`` (or None), and why not."""
    name = ALIASES.get(name, name)
    if name == "embedded":
        return [], ""
    node, sep, rto_text = name.partition("@")
    try:
        rto = float(rto_text) if sep else 0.3
    except ValueError:
        return None, f"not a timeout: {rto_text!r}"
    spawn, why = node_command(node, rto, custom)
    if spawn is None:
        return None, why
    window = ["--ack-window", "2"] if rto >= 5 else []
    return ["--spawn", spawn, "--mavlink", "--rto", f"{rto:g}", *window], ""


def run(args: list[str]) -> tuple[float, dict]:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "report.json"
        cmd = [sys.executable, "-m", "mcp_conform.conformance", *args, "--json", str(path)]
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
    p.add_argument("--only", default=DEFAULT, help=f"targets, comma-separated (default {DEFAULT})")
    p.add_argument("--node", help="another drone's --spawn command, with {rto} where its timeout goes "
                   "(target custom@RTO; alone, it replaces the sample node in rto0.3 and rto5)")
    p.add_argument("--parallel", default="", help="also run the scheduled suite with --parallel N, for each N "
                   "(comma-separated)")
    ns = p.parse_args()
    if ns.node:
        ALIASES.update({"rto0.3": "custom@0.3", "rto5": "custom@5"})
    ways = [int(n) for n in ns.parallel.split(",") if n.strip()]
    head = "".join(f" {f'p{n} s':>7}" for n in ways)
    print(f"{'target':<16} {'serial s':>9} {'scheduled s':>12}{head} {'speed-up':>9}  same outcomes  batch")
    for name in [n.strip() for n in ns.only.split(",") if n.strip()]:
        args, why = target(name, ns.node)
        if args is None:
            print(f"{name:<16} skipped: {why}")
            continue
        s_wall, s_doc = run([*args, "--serial"])
        p_wall, p_doc = run(args)
        par = [(n, *run([*args, "--parallel", str(n)])) for n in ways]
        a = outcomes(s_doc)
        same = [f"scheduled {compare(a, outcomes(p_doc), p_doc)}"]
        same += [f"p{n} {compare(a, outcomes(doc), doc)}" for n, _, doc in par]
        walls = "".join(f" {w:7.1f}" for _, w, _ in par)
        best = min([p_wall, *(w for _, w, _ in par)])
        batch = (p_doc.get("schedule") or {}).get("batch_outcome")
        print(f"{name:<16} {s_wall:9.1f} {p_wall:12.1f}{walls} {s_wall / best if best else 0:8.1f}x  "
              f"{'; '.join(same)}  {batch}", flush=True)
        print(f"{'':<16} (the suites' own durations: {s_doc.get('summary', {}).get('duration_s')} s serial, "
              f"{p_doc.get('summary', {}).get('duration_s')} s scheduled"
              + "".join(f", {doc.get('summary', {}).get('duration_s')} s p{n}" for n, _, doc in par) + ")",
              flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())

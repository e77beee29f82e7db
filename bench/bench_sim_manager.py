"""The manager role's suite in the simulator (``mcp_conform.sim.manager_runner``, issue 38 item
2) against the same suite on real sockets and timers: wall and CPU time per run.

    python bench/bench_sim_manager.py [--runs 3] [--real] [--faults NAME,...]

Rows: the reference manager at challenge 1, serial and side by side, at --rto 0.2 (and in the
simulator at the description's 5 s too, which there costs no wall time), and ``--faults``
(sim.manager_faults; default two). Each row: the verdicts that failed or warned (cases and
monitor), the virtual seconds, the wall and CPU time (the median of ``--runs``). In the
simulator CPU is this process's; with ``--real`` the same targets are run as ``mcp-conform --role
manager`` processes (the embedded reference manager; the sample manager for a fault), wall and
CPU of the runner and its managers (``RUSAGE_CHILDREN``). Figures only: nothing here asserts a
timing. Compare ``bench/bench_manager_suite.py`` (real runs, serial against side by side).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from mcp_conform.sim.manager_faults import MANAGER_FAULTS
from mcp_conform.sim.manager_runner import run_manager_cases

ROOT = Path(__file__).resolve().parents[1]
SHORT = {"rto": 0.2, "ack_window": 0.25}
DESCRIPTION = {"rto": 5.0, "ack_window": 2.0}


def _flagged(report: dict) -> str:
    rules = {r for r, o in report.get("rules", {}).items() if o in ("failed", "warned")}
    rules |= {r for t in report.get("monitor", {}).get("rules", {}).values() for r, o in t.items()
              if o in ("failed", "warned")}
    return ",".join(sorted(rules)) or "-"


def sim_once(fault: str | None, challenge: int, serial: bool, timing: dict) -> tuple[float, float, float, str]:
    w, c = time.perf_counter(), time.process_time()
    run = run_manager_cases(fault, seed=1, challenge=challenge, serial=serial, **timing)
    return time.perf_counter() - w, time.process_time() - c, run.virtual_s, _flagged(run.report)


def real_once(fault: str | None, challenge: int, serial: bool) -> tuple[float, float, float, str]:
    sys.path.insert(0, str(ROOT))
    from tests.conformance.runner_helpers import sample_manager_command

    args = ["--role", "manager", "--challenge", str(challenge), "--rto", "0.2", "--ack-window", "0.25",
            *(["--serial"] if serial else [])]
    if fault is not None:
        args += ["--spawn", sample_manager_command("--fault", fault)]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "report.json"
        before = resource.getrusage(resource.RUSAGE_CHILDREN)
        w = time.perf_counter()
        subprocess.run([sys.executable, "-m", "mcp_conform.conformance", *args, "--json", str(path)], cwd=ROOT,
                       capture_output=True, env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=600)
        wall = time.perf_counter() - w
        after = resource.getrusage(resource.RUSAGE_CHILDREN)
        doc = json.loads(path.read_text()) if path.exists() else {}
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu, doc.get("summary", {}).get("duration_s", 0.0), _flagged(doc)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--runs", type=int, default=3)
    ap.add_argument("--real", action="store_true", help="also run each short-timing target for real")
    ap.add_argument("--faults", default="wrong-seq-ack,after-end")
    a = ap.parse_args()
    targets: list[tuple[str, str | None, int, bool, dict]] = [
        ("reference c1 side", None, 1, False, SHORT), ("reference c1 serial", None, 1, True, SHORT),
        ("reference c2 5s side", None, 2, False, DESCRIPTION)]
    for f in filter(None, a.faults.split(",")):
        targets.append((f"{f} side", f, MANAGER_FAULTS[f].challenge, False, SHORT))
    print(f"{'target':<26} {'where':<5} {'flagged':<12} {'virtual/suite s':>15} {'wall s':>7} {'CPU s':>6}")
    for name, fault, challenge, serial, timing in targets:
        rows = [("sim", [sim_once(fault, challenge, serial, timing) for _ in range(a.runs)])]
        if a.real and timing is SHORT:
            rows.append(("real", [real_once(fault, challenge, serial) for _ in range(a.runs)]))
        for where, got in rows:
            wall, cpu, virt = (statistics.median(x[i] for x in got) for i in range(3))
            print(f"{name:<26} {where:<5} {got[0][3]:<12} {virt:15.1f} {wall:7.2f} {cpu:6.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

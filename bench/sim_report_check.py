"""The simulator's seeded runs, their JSON reports kept and compared (issue 38: a change that
only makes a simulated run cheaper must leave every report as it was). Each entry point runs a
handful of seeds -- the drone cases (``sim.runner.run_cases``: serial, the default schedule, with
the vehicle, a lossy link with stalls, two of the sample node's mutants), the manager role
(``sim.manager_runner``), the MAVLink vehicle and gcs roles (``sim.vehicle_role``,
``sim.gcs_role``) -- and each report, less what measures the host (``duration_s``), is written
to ``--save FILE`` or compared with the one saved there (``--compare FILE``): every case, its
outcome, reason and evidence, the rules, the monitor's verdicts, the exit code, the clock's
switches and virtual length::

    python bench/sim_report_check.py --save /tmp/before.json     # on the old code
    python bench/sim_report_check.py --compare /tmp/before.json  # on the new: exit 1 on a difference

Figures only beside that: each run's CPU seconds.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a source checkout

LOSSY = "loss=0.1,dup=0.05,reorder=0.1"


def _kinds() -> dict[str, Callable[[int], Any]]:
    from mcp_conform.sim.gcs_role import run_gcs_cases
    from mcp_conform.sim.manager_runner import run_manager_cases
    from mcp_conform.sim.mutants import mutant_factory
    from mcp_conform.sim.runner import run_cases
    from mcp_conform.sim.vehicle_role import run_vehicle_cases

    def mutant(name: str) -> Callable[[int], Any]:
        return lambda s: run_cases(mutant_factory(name, rto=0.2, seed=s), seed=s, rto=0.2, ack_window=0.25,
                                   mavlink=True)

    return {
        "drone-serial": lambda s: run_cases(None, seed=s),
        "drone-schedule": lambda s: run_cases(None, seed=s, serial=False),
        "drone-mavlink": lambda s: run_cases(None, seed=s, mavlink=True),
        "drone-lossy-stalls": lambda s: run_cases(None, seed=s, link=LOSSY, stalls=(0.05, 0.3)),
        "drone-fault": lambda s: run_cases("rtx-stop-on-any-ack" if s % 2 else "ack-previous-seq", seed=s),
        "mutant-ack-zero": mutant("ack-zero"),
        "mutant-rtx-none": mutant("rtx-none"),
        # the MCP-ROB-7 flood's datagrams answered (an ACK of each), or taken as a hang
        "mutant-ack-unknown-action": mutant("ack-unknown-action"),
        "mutant-flood-hang": mutant("flood-hang"),
        "mutant-crash-on-short": mutant("crash-on-short"),
        "manager": lambda s: run_manager_cases(None, seed=s),
        "manager-serial-lossy": lambda s: run_manager_cases(None, seed=s, serial=True, link=LOSSY),
        "vehicle-tcp": lambda s: run_vehicle_cases(None, seed=s),
        "vehicle-udpout-lossy": lambda s: run_vehicle_cases(None, seed=s, transport="udpout", link="delay=1-20ms"),
        "gcs-tcp": lambda s: run_gcs_cases(None, seed=s),
        "gcs-udp-stalls": lambda s: run_gcs_cases(None, seed=s, transport="udp", stalls=(0.05, 0.3)),
    }


def _strip(x: Any) -> Any:
    """The report less what measures the host."""
    if isinstance(x, dict):
        return {k: _strip(v) for k, v in x.items() if k != "duration_s"}
    if isinstance(x, list):
        return [_strip(v) for v in x]
    return x


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--only", default="", help="comma-separated kinds (default: all)")
    g = ap.add_mutually_exclusive_group(required=True)
    g.add_argument("--save", type=Path)
    g.add_argument("--compare", type=Path)
    a = ap.parse_args()
    kinds = _kinds()
    if a.only:
        kinds = {k: v for k, v in kinds.items() if k in a.only.split(",")}
    got: dict[str, Any] = {}
    for name, run in kinds.items():
        cpu = []
        for seed in range(a.seeds):
            c0 = time.process_time()
            r = run(seed)
            cpu.append(time.process_time() - c0)
            got[f"{name}/{seed}"] = {"rc": r.rc, "virtual_s": round(r.virtual_s, 9), "switches": r.switches,
                                     "models": r.models, "report": _strip(r.report)}
        print(f"{name:22} cpu/run {' '.join(f'{c:.2f}' for c in cpu)} s", flush=True)
    if a.save:
        a.save.write_text(json.dumps(got, sort_keys=True, indent=1))
        print(f"{len(got)} reports saved to {a.save}")
        return 0
    old = json.loads(a.compare.read_text())
    bad = 0
    for key, new in got.items():
        if key not in old:
            print(f"{key}: not in {a.compare}")
            bad += 1
            continue
        new = json.loads(json.dumps(new, sort_keys=True))
        if new != old[key]:
            bad += 1
            diff = [k for k in sorted(set(new) | set(old[key])) if new.get(k) != old[key].get(k)]
            rdiff = [k for k in sorted(set(new["report"]) | set(old[key]["report"]))
                     if new["report"].get(k) != old[key]["report"].get(k)]
            print(f"{key}: DIFFERS in {diff}; report keys {rdiff}")
    print(f"{len(got) - bad} of {len(got)} reports the same")
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())

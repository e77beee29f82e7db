"""``python bench/bench_fuzz.py --time-to-find``: for each of the project's own faulty nodes
and backends, the median time to the first confirmed finding over several seeds, per engine
(issue 36 item 6).

MCP: tests/conformance/nodes/sample_node.py with one ``--fault``, fuzzed as a user runs
``mcp-fuzz --spawn ... --rto 0.3 --seed N --max-cases 20000 --duration 60`` (the vehicle
where the fault shows only there), each engine in turn (``stateless``, ``stateful``, and
``both``, the default mix). The time is from the campaign's start (the node spawned) to the
first finding of the fault's rule confirmed by triage (replayed N of N): what a user waits.
Nsqd: the C backend of tests/nsqd_backends (ASan) with one ``--fault``, ``mcp-fuzz
--protocol nsqd``'s campaign stopped at its first confirmed finding of the fault's rule.
``both`` shares ``--max-cases`` between its engines as the campaign does: against a fast
backend the stateless engine may spend all 20,000 cases before the stateful one starts. A campaign that ends
without one counts as not found; the median is over the seeds that found it, shown as
``found/seeds``. Figures only, nothing asserted: the host is said to be loaded or not by the
load average printed beside the table.
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # run from a source checkout

from mcp_conform.fuzz.campaign import run_campaign  # noqa: E402
from mcp_conform.fuzz.config import FuzzConfig  # noqa: E402
from mcp_conform.fuzz.findings import Finding, FindingStore  # noqa: E402
from tests.fuzz.test_stateful_finds import RTO, spawn_command  # noqa: E402

MAX_CASES = 20_000
DURATION = 60.0
#: fault -> (with the vehicle, the rule its finding names)
MCP_FAULTS: dict[str, tuple[bool, str]] = {
    "ack-first-copy-only": (False, "MCP-ACK-1"),
    "no-dup-discard": (True, "MCP-DUP-1"),
    "seq-no-wrap": (True, "MCP-SEQ-3"),
    "ack-broadcast": (False, "MCP-ACK-4"),
    "crash-on-short": (False, "MCP-ROB-1"),
}
NSQD_FAULTS = ("second-client-kicks-first", "stale-partial-frame", "crash-on-negative-string")
ENGINES = ("stateless", "stateful", "both")


class _TimedStore(FindingStore):
    """A store that notes when each rule's first finding was kept."""

    def __init__(self, out: Path) -> None:
        super().__init__(out)
        self.first: dict[str, float] = {}

    def add(self, finding: Finding, traffic: list[Any] | None = None) -> Path | None:
        self.first.setdefault(finding.rule, time.monotonic())
        return super().add(finding, traffic)


def mcp_time_to_find(fault: str, engine: str, seed: int) -> float | None:
    mavlink, rule = MCP_FAULTS[fault]
    with tempfile.TemporaryDirectory() as tmp:
        cfg = FuzzConfig(spawn=spawn_command(fault, mavlink), mavlink=mavlink, engine=engine, seed=seed,
                         max_cases=MAX_CASES, duration=DURATION, rto=RTO, extra={"stop_on_rule": rule})
        store = _TimedStore(Path(tmp))
        t0 = time.monotonic()
        run_campaign(cfg, store)
        return store.first[rule] - t0 if rule in store.first else None


def nsqd_time_to_find(fault: str, engine: str, seed: int) -> float | None:
    from mcp_conform.fuzz.nsqd_campaign import StreamCampaign
    from tests.nsqd_backends.build import FAULTS, built_or_skip

    exe = built_or_skip()
    spawn = f"{exe} --host {{target_host}} --port {{target_port}} --update-period 0.1 --fault {fault}"
    c = StreamCampaign(None, spawn, seed, DURATION, MAX_CASES, None, engine=engine)
    c.stop = lambda: any(f.signature.rule == FAULTS[fault] for f in c.findings)  # another rule's: go on
    t0 = time.monotonic()
    c.run()
    return time.monotonic() - t0 if c.stop() else None


def _row(label: str, engine: str, times: list[float | None]) -> str:
    found = [t for t in times if t is not None]
    median = f"{statistics.median(found):7.1f} s" if found else "      - "
    each = " ".join(f"{t:5.1f}" if t is not None else "    -" for t in times)
    return f"{label:28} {engine:9} {median}  {len(found)}/{len(times)}   [{each}]"


def main_ttf(seeds: list[int], faults: list[str] | None, engines: list[str], nsqd: bool) -> int:
    print(f"time to the first confirmed finding, median over seeds {','.join(map(str, seeds))} "
          f"(at most {MAX_CASES:,} cases or {DURATION:.0f} s a campaign)")
    print(f"{'node --fault':28} {'engine':9} {'median':>9}  found  [per seed, s]")
    for fault in faults or list(MCP_FAULTS):
        if fault not in MCP_FAULTS:
            continue
        for engine in engines:
            times = [mcp_time_to_find(fault, engine, s) for s in seeds]
            print(_row(f"sample_node {fault}", engine, times), flush=True)
    if nsqd:
        for fault in faults or list(NSQD_FAULTS):
            if fault not in NSQD_FAULTS:
                continue
            for engine in engines:
                times = [nsqd_time_to_find(fault, engine, s) for s in seeds]
                print(_row(f"nsqd_backend {fault}", engine, times), flush=True)
    print(f"machine: {os.cpu_count()} CPUs, load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}; "
          f"Python {sys.version.split()[0]}")
    return 0

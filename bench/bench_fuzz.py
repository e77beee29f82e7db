"""mcp-fuzz beside boofuzz against the same reference node, in one run: cases per second.

    pip install -e '.[bench]'      # boofuzz
    python bench/bench_fuzz.py [--cases N] [--seconds S]
    python bench/bench_fuzz.py --protocol nsqd [--backend reference|c|both] [--engines E,...]   # Nsqd over TCP
    python bench/bench_fuzz.py --time-to-find [--seeds 1,2,3,4,5] [--faults F,...] [--engines E,...] [--nsqd]

One reference drone (the embedded default, spawned once) is fuzzed four times in a row:

- ``boofuzz default``: a boofuzz 0.4.2 Session as its documentation sets one up (web UI,
  text logger, results database, receiving after each request), over UDP;
- ``boofuzz tuned``: no web UI, no loggers, ``fuzz_db_keep_only_n_pass_cases=1``,
  ``reuse_target_connection=True``, no receive: it sends blind and judges nothing;
- ``mcp-fuzz stateless``: the stateless engine with every oracle on (replies, liveness
  probe, process fate, trace monitor);
- ``mcp-fuzz stateful``: the stateful engine's programs (``fuzz.programs``), pipelined, with
  the same oracles and every copy's ACK counted (MCP-ACK-1), its rare restarts included
  (withheld Mission_Ready, End_Mission).

``--time-to-find`` prints instead the median time to the first confirmed finding for each
of the project's own faulty nodes (and, with ``--nsqd``, backends), per engine
(``bench/bench_fuzz_ttf.py``).

boofuzz's request is the MCP header (preamble, dst, src, seq, action as big-endian words)
and a payload blob, mutated by boofuzz's own primitives. Each runs ``--cases`` cases or
``--seconds`` seconds, whichever comes first; the figures are printed side by side. Figures
only: nothing here asserts a timing (docs/design.md, "Performance targets").
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # run from a source checkout

from bench.boofuzz_session import timed_session, web_port  # noqa: E402
from mcp_conform.fuzz.config import FuzzConfig  # noqa: E402
from mcp_conform.fuzz.engine_stateless import StatelessEngine  # noqa: E402
from mcp_conform.fuzz.findings import FindingStore  # noqa: E402
from mcp_conform.fuzz.targets import start_target  # noqa: E402
from mcp_conform.fuzz.triage import Triage  # noqa: E402
from mcp_conform.spec.codec import PREAMBLE, Action  # noqa: E402


def _request(boofuzz, node_id: int):  # noqa: ANN001, ANN202
    """The MCP header and a payload, in boofuzz's block language."""
    return boofuzz.Request("mcp", children=(
        boofuzz.Static(name="preamble", default_value=PREAMBLE),
        boofuzz.Word(name="dst", default_value=node_id, endian=">"),
        boofuzz.Word(name="src", default_value=0, endian=">"),
        boofuzz.Word(name="seq", default_value=1, endian=">"),
        boofuzz.Word(name="action", default_value=int(Action.WP_OFF), endian=">"),
        boofuzz.Bytes(name="payload", default_value=b"", max_len=64),
    ))


def run_boofuzz(target: tuple[str, int], node_id: int, cases: int, seconds: float, tuned: bool) -> tuple[int, float]:
    import boofuzz

    conn = boofuzz.UDPSocketConnection(target[0], target[1])
    kw: dict = {"target": boofuzz.Target(connection=conn), "index_end": cases, "sleep_time": 0.0}
    if tuned:
        kw.update(web_port=None, fuzz_loggers=[], fuzz_db_keep_only_n_pass_cases=1,
                  reuse_target_connection=True, receive_data_after_each_request=False,
                  receive_data_after_fuzz=False, check_data_received_each_request=False)
    else:
        # the default UI, on a port nobody else holds, not kept open waiting for ENTER at the end
        kw.update(web_port=web_port(), keep_web_open=False)
    return timed_session(boofuzz, kw, [_request(boofuzz, node_id)], seconds)


def run_mcp_fuzz(tgt, cases: int, seconds: float) -> tuple[int, float]:  # noqa: ANN001
    eng = StatelessEngine(tgt, Triage(tgt, FindingStore(None), "stateless", 1), 1)
    st = eng.run(time.monotonic() + seconds, cases)
    return st.cases, st.seconds


def run_stateful(tgt, cases: int, seconds: float) -> tuple[int, float]:  # noqa: ANN001
    from mcp_conform.fuzz.engine_stateful import StatefulEngine

    cfg = FuzzConfig(engine="stateful", seed=1)
    eng = StatefulEngine(tgt, Triage(tgt, FindingStore(None), "stateful", 1), cfg)
    st = eng.run(time.monotonic() + seconds, cases)
    return st.cases, st.seconds



def _nsqd(args: argparse.Namespace) -> int:
    from bench.bench_fuzz_nsqd import main_nsqd

    return main_nsqd(args.cases, args.seconds, args.backend, [e for e in args.engines.split(",") if e],
                     args.probe_every)


#: ``--protocol NAME``: the benches of the protocols other than MCP (this module's own rows)
OTHER_PROTOCOLS: dict[str, Callable[[argparse.Namespace], int]] = {"nsqd": _nsqd}

def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=20_000)
    ap.add_argument("--seconds", type=float, default=20.0)
    ap.add_argument("--protocol", choices=("mcp", *OTHER_PROTOCOLS), default="mcp",
                    help="nsqd: against an Nsqd backend over TCP (bench/bench_fuzz_nsqd.py)")
    ap.add_argument("--backend", choices=("reference", "c", "both"), default="both",
                    help="nsqd: the Python reference backend, the correct C backend, or both")
    ap.add_argument("--engines", default="stateless,stateful,both",
                    help="nsqd and --time-to-find: mcp-fuzz engines to time (comma-separated)")
    ap.add_argument("--probe-every", type=int, default=40, help="nsqd: mcp-fuzz's probe period in cases (its default 40)")
    ap.add_argument("--time-to-find", action="store_true",
                    help="the median time to the first confirmed finding per faulty node and engine")
    ap.add_argument("--seeds", default="1,2,3,4,5", help="time-to-find: the seeds")
    ap.add_argument("--faults", default="", help="time-to-find: these faults only (comma-separated)")
    ap.add_argument("--nsqd", action="store_true", help="time-to-find: the C backend's faults too")
    args = ap.parse_args()
    if args.time_to_find:
        from bench.bench_fuzz_ttf import ENGINES, main_ttf

        engines = [e for e in args.engines.split(",") if e in ENGINES]
        return main_ttf([int(x) for x in args.seeds.split(",") if x], [f for f in args.faults.split(",") if f] or None,
                        engines, args.nsqd)
    other = OTHER_PROTOCOLS.get(args.protocol)  # a protocol with a bench of its own
    if other is not None:
        return other(args)
    try:
        import boofuzz  # noqa: F401
        have_boofuzz = True
    except ImportError:
        print("bench_fuzz: boofuzz is not installed (pip install -e '.[bench]'): its rows skipped", file=sys.stderr)
        have_boofuzz = False
    tgt = start_target(FuzzConfig())  # the reference drone, spawned once for all three
    rows = []
    try:
        addr, node = tgt.driver.target, tgt.node_id
        runs = [("boofuzz default", lambda: run_boofuzz(addr, node, args.cases, args.seconds, False)),
                ("boofuzz tuned (blind)", lambda: run_boofuzz(addr, node, args.cases, args.seconds, True))]
        runs = runs if have_boofuzz else []
        runs += [("mcp-fuzz stateless, every oracle", lambda: run_mcp_fuzz(tgt, args.cases, args.seconds)),
                 ("mcp-fuzz stateful, every oracle", lambda: run_stateful(tgt, args.cases, args.seconds))]
        for label, fn in runs:
            n, s = fn()
            probe = tgt.probe()
            rows.append((label, n, s, probe.acked))
            print(f"{label:34} {n:8d} cases in {s:6.2f} s  {n / s if s else 0:9,.0f} cases/s"
                  f"  node live after: {probe.acked}", flush=True)
    finally:
        tgt.close()
    print(f"machine: {os.cpu_count()} CPUs, load average {' '.join(f'{x:.1f}' for x in os.getloadavg())}; "
          f"Python {sys.version.split()[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""``mcp-soak``: N whole missions between a manager and K drones, each through its own seeded
impairment (issue 22 item 4; MCP-DUP-1, MCP-RTX-1, MCP-FLOW-4/5/6 on a bad link).

    mcp-soak --missions 100 --impair loss=0.3,dup=0.1,reorder=0.2,delay=0-50ms [--seed N]
             [--drones 1,2,3] [--challenges 1,2,3] [--rto 0.2] [--mission-timeout 60]
             [--manager CMD] [--drone CMD] [--out DIR] [--json FILE|-] [--keep] [--live [HOST:]PORT]
             [--jobs N] [--no-strict] [-v|-q]

Mission *k* of a campaign with ``--seed S`` runs challenge ``challenges[k % n]`` with
impairment seed ``S + k``: ``--missions 1 --seed S+k --challenges c`` replays it. Each
mission: the monitor judges every node's view, every drone's delivery log must hold each
command once, in order, and the manager must complete the mission. Exit 0 when every
mission passed; 1 with the first failing seed, its capture and the command that reproduces
it; 2 with one line on a bad option. A mission fails on any monitor violation by default
(``--strict``, the soak's default); ``--no-strict`` (``--lenient``, its old name, still works)
on MUST violations only. The options follow the tools' one grammar (docs/grammar.md).

``--jobs N`` runs N missions side by side (``soak.campaign``): the same missions, merged in
mission order. SIGTERM or SIGINT stops the campaign: no mission starts, the running ones end
their nodes at once (outcome ``interrupted``), and the table, the summary and ``--json`` are
written with what it has (``"interrupted": "SIGTERM"``); exit 128 + the signal's number. Each
mission names how every node ended (``ended``: exited with its code and when, stopped by the
soak, killed after the grace, never started).
"""

from __future__ import annotations

import argparse
import json
import shlex
import shutil
import signal
import statistics
import sys
import textwrap
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, NoReturn

from mcp_conform.harness.impair import ImpairmentError, parse_impairment
from mcp_conform.soak.campaign import Stop, run_missions, stopping_on_signals
from mcp_conform.soak.mission import (
    DEFAULT_DRONE,
    DEFAULT_MANAGER,
    MissionResult,
    MissionSetup,
    placeholders,
    run_mission,
)
from mcp_conform.traceio.grammar import add_verbosity, add_version, deprecated, epilog

__all__ = ["build_parser", "main"]

PROG = "mcp-soak"
DEFAULT_IMPAIR = "loss=0.3,dup=0.1,reorder=0.2,delay=0-50ms"


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{PROG}: error: {message}\n")


def _ids(text: str, what: str, lo: int, hi: int) -> tuple[int, ...]:
    try:
        ids = tuple(int(w) for w in text.split(",") if w.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(f"{what}: expected comma-separated integers: {text!r}") from None
    if not ids or any(not lo <= i <= hi for i in ids) or len(set(ids)) != len(ids):
        raise argparse.ArgumentTypeError(f"{what}: distinct values {lo}..{hi} expected: {text!r}")
    return ids


def _live(text: str) -> tuple[str, int]:
    from mcp_conform.traceio.live import LiveError, parse_live

    try:
        return parse_live(text)
    except LiveError as exc:
        raise argparse.ArgumentTypeError(str(exc).removeprefix("--live: ")) from None


def build_parser() -> argparse.ArgumentParser:
    p = _Parser(prog=PROG, description="Whole MCP missions on a bad link: each through its own seeded "
                "impairment, judged by the monitor and checked exactly-once on what the drones delivered.")
    p.add_argument("--missions", type=int, default=10, metavar="N", help="how many missions (10)")
    p.add_argument("--impair", default=DEFAULT_IMPAIR, metavar="SPEC",
                   help=f"the link, as mcp-impair's --impair ({DEFAULT_IMPAIR}); its seed is the campaign's")
    p.add_argument("--seed", type=int, default=None, metavar="S",
                   help="campaign seed: mission k uses S+k (default: the spec's seed, else 0)")
    p.add_argument("--drones", type=lambda t: _ids(t, "--drones", 1, 0xFFFE), default=(1, 2, 3),
                   metavar="1,2,3", help="the drones' MCP IDs (1,2,3)")
    p.add_argument("--challenges", type=lambda t: _ids(t, "--challenges", 1, 3), default=(1, 2, 3),
                   metavar="1,2,3", help="the challenges the missions cycle through (1,2,3)")
    p.add_argument("--rto", type=float, default=0.2, metavar="S",
                   help="the nodes' retransmission timeout, the {rto} placeholder (0.2)")
    p.add_argument("--mission-timeout", type=float, default=60.0, metavar="S",
                   help="a mission not over after S seconds fails (60)")
    p.add_argument("--manager", default=None, metavar="CMD",
                   help="your Mission Manager's command, with placeholders (default: the reference manager)")
    p.add_argument("--drone", default=None, metavar="CMD",
                   help="your drone's command, with placeholders (default: the reference drone)")
    p.add_argument("--waypoints", type=Path, default=None, metavar="FILE", help="QGC WPL 110 mission")
    p.add_argument("--obstacles", type=Path, default=None, metavar="FILE", help="QGC WPL 110 obstacles")
    p.add_argument("--out", type=Path, default=Path("soak-out"), metavar="DIR",
                   help="where missions write captures, logs and records (soak-out)")
    p.add_argument("--keep", action="store_true", help="keep passing missions' files too")
    p.add_argument("--strict", action=argparse.BooleanOptionalAction, default=True,
                   help="fail a mission on any monitor violation, SHOULD included (the default); "
                        "--no-strict: on MUST violations only")
    deprecated(p, "--lenient", "--no-strict", dest="strict", flag=False)
    p.add_argument("--fail-fast", action="store_true", help="stop after the first failing mission")
    p.add_argument("--json", metavar="FILE", help="write the results as JSON ('-': stdout); "
                   "written on SIGTERM or SIGINT too, with the missions so far")
    p.add_argument("--jobs", type=int, default=1, metavar="N",
                   help="missions side by side (1): the same missions, merged in mission order")
    p.add_argument("--live", type=_live, metavar="[HOST:]PORT",
                   help="serve the missions live over the Foxglove WebSocket protocol: each node's view under "
                        "its name (/manager/..., /drone1/...), each mission's outcome on /log "
                        "(loopback unless HOST is given; port 0: a free one)")
    add_verbosity(p, "also one line per mission as it ends", "no table or summary: errors, the exit code "
                  "and --json only")
    add_version(p, PROG)
    p.formatter_class = argparse.RawDescriptionHelpFormatter
    p.epilog = epilog(textwrap.fill(
        "placeholders in --manager/--drone: " + ", ".join("{" + k + "}" for k in placeholders())
        + "; {target_host}:{target_port} is where the node listens, {listen_host}:{listen_port} "
        "where it sends, {record} the JSON delivery log it must write", 100))
    return p


def setup_from_args(ns: argparse.Namespace) -> tuple[MissionSetup, int]:
    """The campaign's setup and seed; ValueError (one line) on a bad option."""
    try:
        spec = parse_impairment(ns.impair)
    except ImpairmentError as exc:
        raise ValueError(str(exc)) from None
    if ns.missions < 1:
        raise ValueError("--missions: must be >= 1")
    if ns.jobs < 1:
        raise ValueError("--jobs: must be >= 1")
    if ns.jobs > 1 and ns.live is not None:
        raise ValueError("--live serves one mission's views at a time: use it with --jobs 1")
    if not ns.rto > 0 or not ns.mission_timeout > 0:
        raise ValueError("--rto and --mission-timeout must be > 0")
    for name in ("waypoints", "obstacles"):
        path = getattr(ns, name)
        if path is not None and not path.is_file():
            raise ValueError(f"--{name}: no such file: {path}")
    seed = ns.seed if ns.seed is not None else spec.seed
    setup = MissionSetup(impair=spec, drones=ns.drones, rto=ns.rto, timeout=ns.mission_timeout,
                         manager_cmd=ns.manager or DEFAULT_MANAGER, drone_cmd=ns.drone or DEFAULT_DRONE,
                         waypoints=ns.waypoints, obstacles=ns.obstacles, workdir=ns.out,
                         strict=ns.strict)
    from mcp_conform.soak.mission import _command

    dummy = {k: "1" for k in placeholders()}
    _command(setup.manager_cmd, dummy)  # a bad placeholder fails now, in one line
    _command(setup.drone_cmd, dummy)
    return setup, seed


def reproduce(ns: argparse.Namespace, r: MissionResult) -> str:
    """The one-line command that runs mission ``r`` again."""
    words = [PROG, "--missions", "1", "--seed", str(r.seed), "--challenges", str(r.challenge),
             "--impair", r.impair.rsplit(",seed=", 1)[0] if ",seed=" in r.impair else "seed=0",
             "--drones", ",".join(map(str, ns.drones)), "--rto", f"{ns.rto:g}",
             "--mission-timeout", f"{ns.mission_timeout:g}"]
    for opt in ("manager", "drone", "waypoints", "obstacles"):
        if getattr(ns, opt) is not None:
            words += [f"--{opt}", str(getattr(ns, opt))]
    if not ns.strict:
        words.append("--no-strict")
    return shlex.join(words)


def percentile(values: list[float], q: float) -> float | None:
    if not values:
        return None
    v = sorted(values)
    k = max(0, min(len(v) - 1, round(q / 100 * (len(v) - 1))))
    return v[k]


def main(argv: Sequence[str] | None = None) -> int:
    ns = build_parser().parse_args(argv)
    try:
        setup, seed = setup_from_args(ns)
    except ValueError as exc:
        print(f"{PROG}: error: {exc}", file=sys.stderr)
        return 2
    from rich.console import Console

    console = Console(stderr=ns.json == "-", quiet=ns.quiet)
    if ns.live is not None:
        from mcp_conform.traceio.live import LiveError, LiveServer

        try:
            # every view's channels made before a client can connect (traceio.live)
            setup.live = LiveServer(*ns.live, name=PROG, feeds={
                None: ("/log",), "manager": None, **{f"drone{i}": None for i in setup.drones}})
        except LiveError as exc:
            print(f"{PROG}: error: {exc}", file=sys.stderr)
            return 2
    try:
        return _campaign(ns, setup, seed, console)
    finally:
        if setup.live is not None:  # nothing left listening, however the campaign ended
            setup.live.stop()


def _log(setup: MissionSetup, message: str, level: str = "info") -> None:
    """A line of the campaign's /log (--live): a mission started, complete or failed."""
    if setup.live is None:
        return
    from mcp_conform.traceio.fox import log_body

    t = time.time_ns()
    setup.live.feed(None, topics=("/log",)).publish("/log", json.dumps(log_body(t, level, message, PROG)).encode(), t)


def _campaign(ns: argparse.Namespace, setup: MissionSetup, seed: int, console: Any) -> int:
    stop = Stop()
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
    from rich.table import Table

    if not console.is_terminal:
        console.width = 150
    if setup.live is not None:
        console.print(f"{PROG}: live: {setup.live.url} (Foxglove: Open connection, Foxglove WebSocket)",
                      highlight=False, soft_wrap=True)
    console.print(f"{PROG}: {ns.missions} missions, drones {','.join(map(str, ns.drones))}, "
                  f"challenges {','.join(map(str, ns.challenges))}, link {setup.impair.text().rsplit(',seed=', 1)[0]}, "
                  f"seeds {seed}..{seed + ns.missions - 1}, rto {ns.rto:g} s")
    t0 = time.monotonic()
    plan = [(k, seed + k, ns.challenges[k % len(ns.challenges)]) for k in range(ns.missions)]
    with Progress(TextColumn("[bold]missions"), BarColumn(), MofNCompleteColumn(), TextColumn("{task.fields[state]}"),
                  TimeElapsedColumn(), console=console, transient=False) as bar:
        task = bar.add_task("missions", total=ns.missions, state="")
        tally = {"ok": 0, "failed": 0}

        def run(k: int, mseed: int, challenge: int, stop: Stop) -> MissionResult:
            _log(setup, f"mission {k} started: seed {mseed}, challenge {challenge}")
            return run_mission(setup, k, mseed, challenge, stop)

        def done(r: MissionResult) -> None:
            _log(setup, f"mission {r.index} (seed {r.seed}) complete" if r.ok else
                 f"mission {r.index} (seed {r.seed}) {r.outcome}: " + "; ".join(r.reasons[:3]),
                 "info" if r.ok else "error")
            if r.ok and not ns.keep:
                shutil.rmtree(ns.out / f"mission-{r.seed}-c{r.challenge}", ignore_errors=True)
                r.capture = None
            tally["ok" if r.ok else "failed"] += 1
            if ns.verbose:
                bar.console.print(f"mission {r.index} seed {r.seed} challenge {r.challenge}: "
                                  + ("complete" if r.ok else f"{r.outcome}: " + "; ".join(r.reasons[:3])),
                                  highlight=False, markup=False)
            bar.update(task, advance=1, state=f"[green]{tally['ok']} ok[/] [red]{tally['failed']} failed[/]")

        with stopping_on_signals(stop):
            results = run_missions(plan, run, ns.jobs, stop, fail_fast=ns.fail_fast, done=done)
    wall = time.monotonic() - t0

    table = Table(title=f"missions: link {setup.impair.text().rsplit(',seed=', 1)[0]}, seed {seed}+k")
    for col in ("#", "seed", "challenge", "impairment (what the links did)", "outcome", "mission time",
                "retransmissions", "duplicates discarded"):
        table.add_column(col, justify="left" if col[:3] in ("imp", "out") else "right")
    for r in results:
        table.add_row(str(r.index), str(r.seed), str(r.challenge), r.link,
                      "[green]complete[/]" if r.ok else f"[red]{r.outcome}[/]",
                      "-" if r.mission_time is None else f"{r.mission_time:.2f} s", str(r.retransmissions),
                      str(r.duplicates))
    console.print(table)
    times = [r.mission_time for r in results if r.ok and r.mission_time is not None]
    ok = sum(r.ok for r in results)
    cut = sum(r.outcome == "interrupted" for r in results)
    p50, p99 = percentile(times, 50), percentile(times, 99)
    interrupted = stop.why if stop.why in ("SIGTERM", "SIGINT") else None
    if interrupted:
        console.print(f"[red]stopped by {interrupted}[/]: {len(results)} of {ns.missions} missions ran "
                      f"({cut} interrupted, their nodes ended)", highlight=False)
    console.print(f"{ok}/{len(results)} missions complete, every command delivered exactly once"
                  if ok == len(results) else f"{ok}/{len(results)} missions complete, "
                  f"{len(results) - ok - cut} failed" + (f", {cut} interrupted" if cut else ""))
    console.print(f"mission time p50 {p50:.2f} s, p99 {p99:.2f} s; " if p50 is not None and p99 is not None
                  else "", end="")
    console.print(f"{sum(len(r.violations) for r in results)} monitor violations; "
                  f"{sum(r.retransmissions for r in results)} retransmissions, "
                  f"{sum(r.duplicates for r in results)} duplicates discarded; wall time {wall:.1f} s")
    first_bad = next((r for r in results if not r.ok and r.outcome != "interrupted"), None)
    if first_bad is not None:
        console.print(f"[red]FAILED[/] seed {first_bad.seed} (mission {first_bad.index}, challenge "
                      f"{first_bad.challenge}): " + "; ".join(first_bad.reasons[:3]), highlight=False)
        console.print("nodes: " + "; ".join(f"{v} {e.describe()}" for v, e in first_bad.ended.items()),
                      highlight=False)
        console.print(f"capture: {first_bad.capture or '-'}  logs: {ns.out / f'mission-{first_bad.seed}-c{first_bad.challenge}'}",
                      highlight=False)
        console.print(f"reproduce: {reproduce(ns, first_bad)}", highlight=False, soft_wrap=True)
    if ns.json:
        doc: dict[str, Any] = {
            "tool": PROG, "missions": len(results), "planned": ns.missions, "complete": ok,
            "failed": len(results) - ok - cut, "interrupted_missions": cut, "interrupted": interrupted,
            "jobs": ns.jobs,
            "seed": seed, "impair": setup.impair.text(), "drones": list(ns.drones), "rto": ns.rto,
            "wall_time_s": round(wall, 3),
            "mission_time_p50_s": None if p50 is None else round(p50, 3),
            "mission_time_p99_s": None if p99 is None else round(p99, 3),
            "first_failure": None if first_bad is None else {
                "seed": first_bad.seed, "challenge": first_bad.challenge, "capture": first_bad.capture,
                "reasons": first_bad.reasons, "reproduce": reproduce(ns, first_bad)},
            "results": [r.to_json() for r in results],
            "median_retransmissions": statistics.median([r.retransmissions for r in results])
            if results else None,
        }
        text = json.dumps(doc, indent=1)
        if ns.json == "-":
            print(text)
        else:
            try:
                Path(ns.json).write_text(text + "\n")
            except OSError as exc:
                print(f"{PROG}: error: --json {ns.json}: {exc.strerror}", file=sys.stderr)
                return 2
    if interrupted:
        return 128 + int(getattr(signal, interrupted))
    return 0 if first_bad is None else 1


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())

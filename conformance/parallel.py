"""``mcp-conform --parallel N`` (issue 23): the suite shared out across N node instances.

In spawn mode (an embedded or ``--spawn`` node) the front end starts up to N runs of
itself (each a fork of it, with the runner's modules loaded once: :class:`_Forked`; without
``os.fork``, ``python -m mcp_conform.conformance``), each an instance (``--shard K/N``): its
own node spawned on ports of its own, its own startup phase, its share of the plan
(``conformance.schedule.shard_plan``: the startup-bound cases on the first, the batch whole,
the whole run's observations on each).
The first instance starts first and tells its plan; the others are started once it has (so
an instance the plan leaves idle is never started) and must plan alike. Each appends its
plan, its notes and each case's record to a file of its own (``--shard-events``), which the
front end follows to print the run as one: one header, each case's line as it ends, one
summary. At the end it makes ONE JSON report from the instances' (``report.merge_json``; a
case run on every instance keeps its worst verdict, on that instance's traffic), ONE JUnit
file, ONE capture (``traceio.merge``), one HTML report, and returns one exit code, as a run
of one does: the report has the same keys, its ``schedule`` says which instance ran each
case. SIGINT / SIGTERM stop every instance; the reports are written from what they wrote.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, TYPE_CHECKING, Any

from mcp_conform.conformance.baseline import write_baseline
from mcp_conform.conformance.report import (
    RULE_RANK,
    RunRecord,
    case_from_json,
    merge_json,
    run_from_json,
)
from mcp_conform.conformance.schedule import Plan
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.interrupts import INTERRUPTS
from mcp_conform.spec.profiles import pick

if TYPE_CHECKING:  # imported once the first instance is started (its start is the run's longest path)
    from mcp_conform.conformance.terminal import TerminalReport

__all__ = ["child_args", "pick_every", "run_parallel"]

#: options handed on to every instance as given (``--spawn`` and the timings among them)
_VALUES = ("listen", "target_id", "protocol", "role", "spawn", "rto", "ack_window", "broadcast_id", "timeout",
           "startup_timeout", "case_timeout", "seed", "baseline", "impair")
_FLAGS = ("strict", "serial", "verbose")
#: a case's verdict when it ran on every instance: the worst (an error ranks with a failure)
_RANK = {**RULE_RANK, "error": RULE_RANK["failed"]}


def child_args(ns: Any, k: int, n: int, tmp: Path, record: bool) -> list[str]:
    """Instance ``k``'s command line (``python -m mcp_conform.conformance`` ...): the run's options, its
    own report, capture and events files."""
    args: list[str] = []
    for name in _VALUES:
        value = getattr(ns, name, None)
        if value is not None:
            args.append(f"--{name.replace('_', '-')}={value}")
    if ns.mavlink:
        args.append(f"--mavlink={ns.mavlink}")
    for name in _FLAGS:
        if getattr(ns, name, False):
            args.append(f"--{name}")
    args += [f"--select={p}" for p in ns.select] + [f"--exclude={p}" for p in ns.exclude]
    args += [f"--json={tmp / f'{k}.json'}", f"--shard={k}/{n}", f"--shard-events={tmp / f'{k}.events'}"]
    if record:
        args.append(f"--capture={tmp / f'{k}.mcap'}")
    return args


def preload(profile: Any, role: Any) -> None:
    """Import what each instance's run imports before its first case (the runner's pytest
    plugin, the role's session, case context and monitor), once, in the front end: each
    instance is forked from it (:class:`_Forked`) with them loaded. The cases' modules are
    left to pytest in each instance, which imports them with its asserts rewritten."""
    import importlib

    from mcp_conform.conformance.plugin import RUN_PLUGIN
    from mcp_conform.spec.profiles import resolve

    importlib.import_module(RUN_PLUGIN)
    for name in (role.session, role.context, profile.monitor):
        if name is not None:
            resolve(name)


class _Forked:
    """One instance: a child forked from the front end that runs ``mcp-conform`` with the
    instance's arguments (``cli.main``, as ``python -m mcp_conform.conformance`` would, its
    signal handlers kept to the end as ``conformance._entry`` keeps them), its standard input
    /dev/null, its output (and, but under ``-v``, its errors) to its log; waited for as a ``subprocess.Popen`` is (``poll``, ``returncode``: a signal as a
    negative number). Measured: a fresh interpreter per instance spent about 0.3 CPU s of its
    run importing the runner, the judge, the vehicle and pytest, which a fork has loaded
    (``preload``)."""

    def __init__(self, args: list[str], log: IO[bytes], verbose: bool, run_one: Callable[[list[str]], int]) -> None:
        for stream in (sys.stdout, sys.stderr):  # nothing buffered is written twice
            with contextlib.suppress(Exception):
                stream.flush()
        self.returncode: int | None = None
        seen = len(INTERRUPTS.signals)
        self.pid = os.fork()
        if self.pid == 0:  # the instance: it never returns
            code = 2
            try:
                early = INTERRUPTS.signals[seen:]  # taken by the parent's handler, forked (held) with it
                INTERRUPTS.forked()
                if early:  # stopped before it began, as a fresh interpreter's default action would
                    code = 128 + int(getattr(signal, early[0], signal.SIGTERM))
                    return
                INTERRUPTS.install()  # as conformance._entry does first: kept until the process ends
                devnull = os.open(os.devnull, os.O_RDONLY)
                os.dup2(devnull, 0)
                os.close(devnull)
                os.dup2(log.fileno(), 1)
                if not verbose:  # -v: the traffic, live, on the front end's stderr
                    os.dup2(log.fileno(), 2)
                code = run_one(args)
                INTERRUPTS.stop_raising()
            except SystemExit as exc:
                code = exc.code if isinstance(exc.code, int) else 2
            except BaseException:  # noqa: BLE001  # what a fresh interpreter would print
                with contextlib.suppress(Exception):
                    import traceback

                    traceback.print_exc()
            finally:
                for stream in (sys.stdout, sys.stderr):
                    with contextlib.suppress(Exception):
                        stream.flush()
                os._exit(code)

    def poll(self) -> int | None:
        if self.returncode is None:
            try:
                pid, status = os.waitpid(self.pid, os.WNOHANG)
            except ChildProcessError:  # reaped elsewhere: ended, its status unknown (as Popen says)
                self.returncode = 0
            else:
                if pid:
                    self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.poll() is None:
            os.kill(self.pid, sig)


@dataclass
class _Instance:
    k: int
    proc: _Forked | subprocess.Popen[bytes]
    log: IO[bytes]
    events: Path
    offset: int = 0
    plan: dict[str, Any] | None = None
    cases: list[dict[str, Any]] = field(default_factory=list)

    def read(self) -> list[dict[str, Any]]:
        """The events appended since the last read (whole lines only)."""
        try:
            with self.events.open("rb") as f:
                f.seek(self.offset)
                chunk = f.read()
        except FileNotFoundError:
            return []
        end = chunk.rfind(b"\n") + 1
        self.offset += end
        out = []
        for line in chunk[:end].splitlines():
            with contextlib.suppress(ValueError):
                out.append(json.loads(line))
        return out


class _Run:
    """The instances of one run and what the front end printed of them."""

    def __init__(self, ns: Any, n: int, tmp: Path, terminal: TerminalReport,
                 run_one: Callable[[list[str]], int] | None = None) -> None:
        self.ns, self.n, self.tmp, self.terminal = ns, n, tmp, terminal
        self.run_one = run_one  # a forked instance's run (``cli.main``); None: a fresh interpreter each
        self.record = bool(ns.capture or ns.html)
        self.instances: list[_Instance] = []
        self.plan: Plan | None = None
        self.notes: set[str] = set()
        self.every: dict[str, dict[int, dict[str, Any]]] = {}  # case -> instance -> record
        self.problem: str | None = None

    def start(self, k: int, n: int) -> None:
        log = (self.tmp / f"{k}.log").open("wb")
        args = child_args(self.ns, k, n, self.tmp, self.record)
        proc: _Forked | subprocess.Popen[bytes]
        with INTERRUPTS.held():  # a signal meanwhile stops the run once the instance is known (and stopped)
            if self.run_one is not None:
                proc = _Forked(args, log, self.ns.verbose, self.run_one)
            else:
                proc = subprocess.Popen([sys.executable, "-m", "mcp_conform.conformance", *args],
                                        stdin=subprocess.DEVNULL, stdout=log,
                                        stderr=None if self.ns.verbose else log)  # -v: the traffic, live
            self.instances.append(_Instance(k, proc, log, self.tmp / f"{k}.events"))

    def poll(self) -> None:
        """Print what the instances told since the last poll."""
        for inst in self.instances:
            for ev in inst.read():
                if "plan" in ev:
                    inst.plan = ev["plan"]
                    self._planned(inst)
                elif "note" in ev:
                    self._note(ev["note"])
                elif "case" in ev:
                    self._case(inst, ev["case"])

    def _planned(self, inst: _Instance) -> None:
        if self.plan is None:
            self.plan = Plan.from_json(inst.plan or {})
            if self.ns.verbose:
                for line in self.plan.lines():
                    self._note(line)  # once: each instance prints the plan under -v too
            self.terminal.note(f"parallel: {self.plan.shards} node instance(s) of --parallel {self.n}, each on "
                               "its own ports with its own startup phase (-v: which case runs on which)")
        elif (inst.plan != self.plan.to_json() | {"batch_outcome": inst.plan.get("batch_outcome")}  # type: ignore[union-attr]  # set before the call
                and self.problem is None):
            self.problem = f"node instance {inst.k + 1} planned the run otherwise than the first"

    def _note(self, text: str) -> None:
        if text not in self.notes:  # each instance's startup and liveness notes, once
            self.notes.add(text)
            self.terminal.note(text)

    def _case(self, inst: _Instance, case: dict[str, Any]) -> None:
        inst.cases.append(case)
        on_every = self.plan is not None and any(s.case == case["id"] and s.shard is None for s in self.plan.steps)
        if not on_every:
            self.terminal.case(case_from_json(case))
            return
        seen = self.every.setdefault(case["id"], {})
        seen[inst.k] = case
        if len(seen) == len(self.instances) == (self.plan.shards if self.plan else 0):
            self.terminal.case(case_from_json(pick_every(seen)))

    def running(self) -> bool:
        return any(i.proc.poll() is None for i in self.instances)

    def stop(self, sig: int) -> None:
        for inst in self.instances:
            if inst.proc.poll() is None:
                with contextlib.suppress(OSError):
                    inst.proc.send_signal(sig)

    def wait(self) -> None:
        """Until every instance has ended (an interrupt stops them: their reports follow)."""
        hurried = False
        while self.running():
            try:
                self.poll()
                time.sleep(0.1)
            except KeyboardInterrupt:
                self.stop(signal.SIGTERM)
                INTERRUPTS.stop_raising()
            if INTERRUPTS.hurry and not hurried:  # a second signal: the instances hurry too
                hurried = True
                self.stop(signal.SIGTERM)
        self.poll()
        for inst in self.instances:
            inst.log.close()


def pick_every(by_instance: dict[int, dict[str, Any]]) -> dict[str, Any]:
    """The record of a case run on every instance: the worst verdict (the lowest instance on
    a tie), saying which instance's traffic gave it where the others gave another."""
    order = sorted(by_instance)
    worst = max(order, key=lambda k: (_RANK.get(by_instance[k]["outcome"], 0), -k))
    case = dict(by_instance[worst])
    others = sorted({by_instance[k]["outcome"] for k in order if k != worst} - {case["outcome"]})
    if others:
        case["notes"] = [*case.get("notes", []), f"judged on each node instance's traffic: {case['outcome']} on "
                         f"instance {worst + 1}'s, {' or '.join(others)} on another's"]
    return case


def _merge(run: _Run, docs: dict[int, dict[str, Any]], wall: float) -> dict[str, Any]:
    """ONE report from the instances' (each case once, in the plan's order)."""
    plan = run.plan
    every = {s.case for s in plan.steps if s.shard is None} if plan else set()
    kept: dict[str, dict[str, Any]] = {}
    for cid in every:
        by = {k: c for k, d in docs.items() for c in d.get("cases", []) if c["id"] == cid}
        if by:
            kept[cid] = pick_every(by)
    parts = []
    for n, k in enumerate(sorted(docs)):  # each case once: a case of every instance in the first's
        d = dict(docs[k])
        d["cases"] = [c for c in d.get("cases", []) if c["id"] not in every] + (list(kept.values()) if n == 0 else [])
        parts.append(d)
    doc = merge_json(parts)
    if plan is not None:
        place = {s.case: n for n, s in enumerate(plan.steps)}
        doc["cases"].sort(key=lambda c: place.get(c["id"], len(place)))
        outcome = next((d["schedule"].get("batch_outcome") for d in docs.values()
                        if (d.get("schedule") or {}).get("batch_outcome")), None)
        plan.batch_outcome = outcome
        doc["schedule"] = plan.to_json()
    doc["summary"] = {**doc["summary"], "duration_s": round(wall, 3)}
    return doc


def _instance_error(run: _Run, inst: _Instance) -> str:
    """Why an instance left no report: its exit code and the last line it printed."""
    with contextlib.suppress(OSError):
        lines = [ln for ln in (run.tmp / f"{inst.k}.log").read_text(errors="replace").splitlines() if ln.strip()]
        if lines:
            return f"node instance {inst.k + 1} ended without a report (exit code {inst.proc.returncode}): {lines[-1]}"
    return f"node instance {inst.k + 1} ended without a report (exit code {inst.proc.returncode})"


def run_parallel(ns: Any, cfg: RunConfig, n: int, fail: Callable[[str, str | None], int],
                 run_one: Callable[[list[str]], int] | None = None) -> int:
    """Run the suite across up to ``n`` node instances; the contract's exit code (``fail``:
    the front end's one-line error, exit 2, for a run no instance reported on). ``run_one``
    (``cli.main``): each instance is a fork of this process that runs it (where ``os.fork``
    is); None: each is ``python -m mcp_conform.conformance``."""
    t0 = time.monotonic()
    tmp = Path(tempfile.mkdtemp(prefix="mcp-conform-parallel-"))
    run_one = run_one if hasattr(os, "fork") else None
    run = _Run(ns, n, tmp, None, run_one)  # type: ignore[arg-type]  # set once the first instance is started
    try:
        if run_one is not None:
            with INTERRUPTS.held():  # a signal meanwhile stops the run before any instance starts
                preload(*pick(cfg.protocol, cfg.role))
        run.start(0, n)  # first: the front end's own imports (rich, the report writers) come after
        try:  # the first instance's plan says how many more to start
            with INTERRUPTS.held():  # a signal meanwhile stops the instances once the header is out
                from rich.console import Console

                from mcp_conform.conformance.terminal import TerminalReport

                run.terminal = TerminalReport(Console(highlight=False))
                run.terminal.header(RunRecord(role=cfg.role, target=None, parameters={}, seed=cfg.seed,
                                              strict=cfg.strict), cfg.mode)
            while run.plan is None and run.running():
                run.poll()
                time.sleep(0.05)
            run.poll()
            if run.plan is not None and not INTERRUPTS.interrupted:
                for k in range(1, run.plan.shards):
                    run.start(k, n)
        except KeyboardInterrupt:
            run.stop(signal.SIGTERM)
            INTERRUPTS.stop_raising()
        run.wait()
        return _finish(run, ns, time.monotonic() - t0, fail)
    finally:
        run.stop(signal.SIGKILL)
        shutil.rmtree(tmp, ignore_errors=True)


def _finish(run: _Run, ns: Any, wall: float, fail: Callable[[str, str | None], int]) -> int:
    INTERRUPTS.stop_raising()
    from mcp_conform.conformance._run_reports import write_reports, write_run_html
    from mcp_conform.conformance.junit import write_junit

    docs: dict[int, dict[str, Any]] = {}
    errors: list[str] = []
    for inst in run.instances:
        path = run.tmp / f"{inst.k}.json"
        try:
            docs[inst.k] = json.loads(path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            errors.append(_instance_error(run, inst))
    if not docs:
        return fail(errors[0] if errors else "no node instance was started", ns.json)
    doc = _merge(run, docs, wall)
    error = (INTERRUPTS.reason() if INTERRUPTS.interrupted else None) or doc.get("error") \
        or (errors[0] if errors else None) or run.problem
    doc["error"] = error
    record = run_from_json(doc)
    parts = sorted(str(run.tmp / f"{k}.mcap") for k in docs if (run.tmp / f"{k}.mcap").exists())
    capture = ns.capture or (str(run.tmp / "all.mcap") if ns.html and parts else None)
    writers: list[tuple[str | None, Any]] = []
    if capture and parts:
        from mcp_conform.traceio.merge import merge_captures

        writers.append((capture, lambda p: merge_captures(parts, p)))
    writers += [
        (ns.json, lambda p: Path(p).write_text(json.dumps(doc, indent=2) + "\n", encoding="utf-8")),
        (ns.junit, lambda p: write_junit(p, record, ns.junit_family or "xunit2")),
        (None if error else ns.write_baseline, lambda p: write_baseline(p, record.cases, record.target)),
        (ns.html, lambda p: write_run_html(p, doc, capture)),
    ]
    problems = write_reports(writers)
    run.terminal.summary(record)
    if error and record.cases:
        run.terminal.error(error, None)
    for p in problems:
        print(f"error: {p}", file=sys.stderr)
    if INTERRUPTS.interrupted and not problems:  # 128 + the first signal's number, as a run of one
        return 128 + int(getattr(signal, INTERRUPTS.signals[0], signal.SIGINT))
    if problems or error:
        return 2
    return record.exit_code()

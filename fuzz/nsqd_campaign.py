"""``mcp-fuzz --protocol nsqd``: a campaign against a TCP backend until it breaks (issue 21).

Cases come from ``fuzz.nsqd_mutators`` (seeded); each is written on a connection to the
backend (``fuzz.nsqd_backend.Backend``) and judged at once by the oracles of ``fuzz.nsqd_oracles`` (death, sanitizer
report, a close after valid frames, the backend's own frames); every ``probe_every`` cases a
probe command must still take its effect (else the stream lost sync, or the backend hangs),
and every few hundred connections a spawned backend's descriptors are counted (a leak).

A hit is triaged: the case (or, for a failed probe, each case since the last good one) is
replayed in a fresh process until one reproduces alone; it is minimised (delta debugging
over its writes, then over its bytes); it must then reproduce N of N times (``replays``),
each in a fresh process, with the same signature, or it is dropped as unconfirmed; its
signature deduplicates it. Before any replay, the same observation without the input (a
connection sent nothing; the probe with no case before it) decides whether the input made
the difference: if the baseline fails too, the finding is the target's behaviour, under the
rule the baseline broke, with no input blamed (``fuzz.nsqd_blame``, issue 36 item 2). A hit
whose signature is already a finding (or was one's before minimising) is counted, not
triaged again; one that did not reproduce ``UNCONFIRMED_TRIES`` times is counted too; triage
has a budget (``TRIAGE_SHARE`` of the campaign) and ``--duration`` bounds the whole campaign,
triage included, within ``GRACE_S`` (both in the summary). ``finding-N/`` holds ``finding.json``, the input as hex and as a
Python bytes literal, the stderr excerpt and ``replay.txt``; ``mcp-fuzz --protocol nsqd
--replay finding-N`` reproduces it (exit 1) or not (exit 0).
"""

from __future__ import annotations

import random
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, ClassVar

from mcp_conform.fuzz import nsqd_report
from mcp_conform.fuzz.budget import (
    TRIAGE_SHARE,
    UNCONFIRMED_TRIES,
    Late,
    budget_left,
    campaign_end,
    engine_turns,
    over_budget,
)
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.confirm import Confirmation, confirm_n
from mcp_conform.fuzz.ddmin import ddmin
from mcp_conform.fuzz.environment import EnvironmentLog
from mcp_conform.fuzz.findings import Finding, FindingStore
from mcp_conform.fuzz.nsqd_backend import (
    REPLAY_DEATH_S,
    Backend,
    Hit,
    _defaults,
    _replay_kind,
    _reproduces,
    message_names,
)
from mcp_conform.fuzz.nsqd_blame import PROBED, baseline, death_culprit, leak_check
from mcp_conform.fuzz.nsqd_mutators import Case, Write, draw_case
from mcp_conform.fuzz.nsqd_oracles import CLOSE_RULE, Signature, desync_rule, same_finding
from mcp_conform.fuzz.nsqd_replay import replay_stream_finding
from mcp_conform.fuzz.nsqd_repro import TrafficLog, write_finding_files
from mcp_conform.fuzz.progress import Progress
from mcp_conform.fuzz.workers import Reporter, report, run_jobs, sum_tables
from mcp_conform.harness.errors import SetupError
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import encode
from mcp_conform.spec.profiles import NSQD_PROFILE

__all__ = ["StreamCampaign", "nsqd_finding", "replay_stream_finding"]

_same, _CLOSE_RULE = same_finding, CLOSE_RULE  # their old names (moved for fuzz.nsqd_stateful)

def nsqd_finding(sig: Signature, cases: list[Case], detail: str, replays: str, stderr: tuple[str, ...] = (), *,
                 note: str = "", traffic: list[Any] | None = None, program: list[dict[str, Any]] | None = None,
                 no_input: bool = False, probe: bool = False, seed: int = 0, worker: int = 0) -> Finding:
    """An Nsqd finding as every protocol's is (``fuzz.findings.Finding``): its signature,
    minimal cases (or a stateful program's ops), the last confirming replay's traffic (its
    repro.mcap, repro.pcap); ``probe``: its replay ends with the probe command."""
    writes = ([Write(bytes.fromhex(w["hex"]), w.get("end", "")) for op in program for w in op["writes"]]
              if program is not None else [w for c in cases for w in c.writes])
    doc: dict[str, Any] = {
        "oracle": sig.oracle, "kind": sig.kind, "access": sig.access, "frames": list(sig.frames),
        "description": sig.describe(), "detail": detail, "probe": probe or "probe" in note,
        "writes": [{"hex": w.data.hex(), "end": w.end} for w in writes],
        "expect": [list(c.expect) for c in cases if c.check], "or_error": any(c.or_error for c in cases)}
    if len(cases) > 1:  # each as it was sent (its own watch, its connection kept or not): --replay too
        doc["cases"] = [{"kind": c.kind, "valid": c.valid, "probe": c.probe, "note": c.note,
                         "writes": [{"hex": w.data.hex(), "end": w.end} for w in c.writes]} for c in cases]
    # the shape groups as the signature's key does (its access aside): fuzz.findings.FindingStore
    shape = Signature(sig.oracle, sig.kind, sig.frames[:3], sig.rule).describe()
    return Finding(sig.rule, "", detail, [], shape, "stateless" if program is None else "stateful", seed,
                   level="MUST", evidence=list(stderr), worker=worker, program=program, source=sig.oracle,
                   protocol=NSQD_PROFILE.name, note=note, replays=replays, no_input=no_input, doc=doc,
                   signature=sig, cases=list(cases), traffic=list(traffic or []))


@dataclass
class StreamCampaign:
    target: tuple[str, int] | None
    spawn: str | None
    seed: int
    duration: float | None
    max_cases: int | None
    out: Path | None
    replays: int = 3
    probe_every: int = 40
    stop_after: int | None = None  # end the campaign once this many findings are confirmed
    unconfirmed: int = 0
    cases: int = 0
    by_kind: dict[str, int] = field(default_factory=dict)
    restarts: int = 0
    engine: str = "stateless"  # stateless | stateful | both (the duration split between them)
    db: str | None = None  # hypothesis's example database of the stateful engine (--db)
    worker: int = 0  # a --jobs worker's index: its own seed stream
    tick: Callable[[Progress], None] | None = None  # live progress (fuzz.progress)
    tried: dict[str, dict[str, int]] = field(default_factory=dict)  # kind -> message -> cases
    fuzz_s: float = 0.0  # seconds spent fuzzing (triage's replays excluded)
    triage_s: float = 0.0  # triage's own: its baselines and replays, the processes they start included
    restart_s: float = 0.0  # the backend restarted to go on fuzzing (after a death, a hang, a triage)
    started: float = field(default_factory=time.monotonic)
    origin: float | None = None  # a --jobs parent's start: --duration counts from it (fuzz.budget)
    stop: Callable[[], bool] = lambda: False  # a --jobs parent's stop request
    current: Any = None  # the backend now fuzzed (closed at the end, whatever ends the campaign)
    workers: list[dict[str, Any]] | None = None  # --jobs: each worker's figures (:meth:`run_jobs`)
    untriaged: dict[str, int] = field(default_factory=dict)  # signature -> hits counted, not triaged
    tries: dict[Any, int] = field(default_factory=dict)  # (signature key, how) -> triages that did not reproduce
    aliases: dict[Any, Finding] = field(default_factory=dict)  # a hit's key -> the finding it became
    base_seen: dict[bool, Signature | None] = field(default_factory=dict)  # baseline (probe or not) -> what it showed
    environment: EnvironmentLog = field(default_factory=EnvironmentLog)  # seen, then not every replay: why
    #: the cases the engine now running may reach: ``--max-cases`` shared between the engines of
    #: ``both`` as the duration is (the stateless engine spent all 20,000 before the stateful one
    #: began); None: ``max_cases``
    case_cap: int | None = None
    #: how long a replay of the hit now triaged waits for it to show (``Backend.suspects``)
    wait: float = REPLAY_DEATH_S
    triage_from: float | None = None  # when the triage in progress began (``over_budget``)
    jobs: int = 1  # --jobs: :meth:`fuzz` runs this many workers (:meth:`run_jobs`)
    interrupted: bool = False  # SIGINT ended it (its summary says so)
    store: FindingStore = field(init=False)  # the confirmed findings (fuzz.findings), written under ``out``

    def __post_init__(self) -> None:
        how = ["--spawn", self.spawn] if self.spawn else (
            ["--target", f"{self.target[0]}:{self.target[1]}"] if self.target else [])
        self.store = FindingStore(self.out, ["--protocol", NSQD_PROFILE.name, *how], write_finding_files)

    @property
    def findings(self) -> list[Finding]:
        return self.store.order

    def _over(self, deadline: float) -> bool:
        cap = self.case_cap if self.case_cap is not None else self.max_cases
        return (time.monotonic() >= deadline or (cap is not None and self.cases >= cap)
                or (self.stop_after is not None and len(self.findings) >= self.stop_after) or self.stop())

    def note_tried(self, kind: str, data: bytes) -> None:
        """Which message ids x mutation kinds were sent (the progress table, summary.json)."""
        row = self.tried.setdefault(kind, {})
        for name in message_names(data):
            row[name] = row.get(name, 0) + 1

    def _tick(self) -> None:
        if self.tick is not None:
            self.tick(self.progress())

    def progress(self) -> Progress:
        """The live figures (``fuzz.progress``): findings by class (the oracle), the kinds x
        message ids sent."""
        classes: dict[str, int] = {}
        for f in self.findings:
            classes[f.source] = classes.get(f.source, 0) + 1
        return Progress(self.cases, len(self.findings), self.restarts, self.fuzz_s, self.started, self.engine,
                        classes, self.tried)

    def report(self, **more: Any) -> dict[str, Any]:
        """A ``--jobs`` worker's report to its parent (``fuzz.workers.report``)."""
        return report(self.cases, self.fuzz_s, self.restarts, list(self.findings), tried=self.tried,
                      triage_s=self.triage_s, restart_s=self.restart_s, environment=self.environment.values(),
                      unconfirmed=self.unconfirmed, untriaged=self.untriaged, by_kind=self.by_kind, **more)

    def run_jobs(self, jobs: int, tick: Callable[[Progress], None] | None = None) -> dict[str, Any]:
        """``--jobs N``: N workers (``fuzz.workers.run_jobs``), each a campaign of its own
        backend and seed stream, ``--max-cases`` shared out, ``--duration`` from this start;
        their findings in this campaign's store, their figures merged; the summary."""
        t0 = self.started = time.monotonic()
        kw = {**{k: getattr(self, k) for k in _JOB_FIELDS}, "origin": t0}
        if self.max_cases is not None:  # the budget shared: N workers run max_cases in all
            kw["max_cases"] = max(1, self.max_cases // jobs)
        got = run_jobs(_job, lambda i, q, stop: (kw, i, q, stop), jobs, campaign_end(t0, self.duration), self.store,
                       tick, Progress(started=t0, engine=self.engine), self.stop_after)
        bodies = list(got.per.values())
        self.cases, self.restarts = sum(b["cases"] for b in bodies), sum(b["restarts"] for b in bodies)
        self.fuzz_s = max((b["fuzz_s"] for b in bodies), default=0.0)
        self.triage_s, self.restart_s = sum(b["triage_s"] for b in bodies), sum(b["restart_s"] for b in bodies)
        self.unconfirmed = sum(b["unconfirmed"] for b in bodies)
        for e in (e for b in bodies for e in b["environment"]):
            self.environment.add(e)
        self.tried = sum_tables(b["tried"] for b in bodies)
        self.untriaged = sum_tables({"": b["untriaged"]} for b in bodies).get("", {})
        self.by_kind = sum_tables({"": b["by_kind"]} for b in bodies).get("", {})
        self.workers = [{"worker": i, "cases": got.per.get(i, {}).get("cases", 0),
                         "fuzz_s": round(got.per.get(i, {}).get("fuzz_s", 0.0), 2),
                         "findings": len(got.done.get(i, {}).get("found", [])),
                         "error": got.done[i]["error"] if i in got.done else "gave no result"} for i in range(jobs)]
        self.interrupted = got.interrupted
        return self.summary(time.monotonic() - t0)

    def run(self) -> dict[str, Any]:
        self.started = t0 = self.origin if self.origin is not None else time.monotonic()
        backend = self.current = Backend(self.target, self.spawn)
        try:
            if self.worker == 0:
                backend = self.current = leak_check(self, backend)
            for name, deadline, cap in engine_turns(self.engine, t0, self.duration, self.max_cases):
                self.case_cap = cap
                if name == "stateful":
                    from mcp_conform.fuzz.nsqd_stateful import StreamStatefulEngine

                    backend = StreamStatefulEngine(self, backend, self.db, self.worker).run(
                        lambda d=deadline: self._over(d), self._tick)  # type: ignore[misc]  # mypy: a default argument
                else:
                    backend = self._stateless(backend, deadline)
        except KeyboardInterrupt:  # SIGINT: the campaign ends with what it has
            self.interrupted = True
        finally:
            self.current.close()
        return self.summary(time.monotonic() - t0)

    def add_program(self, backend: Backend, hit: Any, ops: list[Any]) -> Backend:
        """A stateful program's failure: triaged like a case's (fuzz.nsqd_stateful)."""
        from mcp_conform.fuzz.nsqd_stateful import triage_program

        t0, r0 = time.monotonic(), self.restart_s
        self.wait, self.triage_from = REPLAY_DEATH_S, t0
        try:
            if self.skip(hit.signature, backend, "program"):
                return self.restart(backend) if hit.signature.oracle in ("crash", "hang", "sanitizer") else backend
            blame, backend = self.blamed(backend, hit, False)
            return triage_program(self, backend, hit, ops) if blame else backend
        except Late:
            self.untriaged[hit.signature.describe()] = self.untriaged.get(hit.signature.describe(), 0) + 1
            return self.current
        finally:
            self.triage_s += time.monotonic() - t0 - (self.restart_s - r0)
            self.triage_from = None

    def add_program_finding(self, sig: Signature, detail: str, replays: str, stderr: tuple[str, ...], note: str,
                            program: list[dict[str, Any]], traffic: list[Any] | None = None) -> None:
        """A stateful program's confirmed finding; ``traffic``: its last confirming replay's
        (repro.mcap, repro.pcap), as a case's finding has it."""
        self._add(nsqd_finding(sig, [], detail, replays, stderr, note=note, program=program, traffic=traffic))

    def _stateless(self, backend: Backend, deadline: float) -> Backend:
        rng = random.Random(self.seed if not self.worker else hash((self.seed, self.worker)))
        window: list[Case] = []
        n, last_tick = 0, 0.0
        t_fuzz = time.monotonic()
        try:
            while not self._over(deadline):
                case = draw_case(rng)
                if case.expect and n % 4 == 0:  # one valid command in four is judged by its effect
                    case = replace(case, check=True)
                n += 1
                self.cases += 1
                self.by_kind[case.kind] = self.by_kind.get(case.kind, 0) + 1
                self.note_tried(case.kind, case.data)
                if time.monotonic() - last_tick >= 0.25:
                    last_tick = time.monotonic()
                    self.fuzz_s += last_tick - t_fuzz
                    t_fuzz = last_tick
                    self._tick()
                window.append(case)
                hit = backend.run(case)
                probe = False
                if hit is None and backend.synced:  # a judged effect proved the stream in sync
                    backend.synced = False
                    window.clear()
                if hit is None and len(window) >= self.probe_every:
                    hit, probe = backend.probe(), True
                    if hit is None:
                        window.clear()
                if hit is not None:
                    # a death may show only at the next case's write: the one before is a suspect too
                    t1, r0 = time.monotonic(), self.restart_s
                    self.triage_from = t1
                    self.fuzz_s += t1 - t_fuzz
                    suspects, self.wait = (list(window), REPLAY_DEATH_S) if probe else backend.suspects(hit, window)
                    backend = self.current = self._triage(backend, hit, suspects, probe)
                    t_fuzz, self.triage_from = time.monotonic(), None
                    self.triage_s += t_fuzz - t1 - (self.restart_s - r0)
                    window.clear()
                    continue
        finally:
            self.fuzz_s += time.monotonic() - t_fuzz
        return backend

    def known(self, sig: Signature) -> Finding | None:
        """The finding a hit of ``sig`` already is: the same signature (a sanitizer's report seen
        before or after the exit alike: ``same_finding``), or a hit's that became it."""
        if sig.oracle == "desync":  # named by what lost the stream its sync: only after its triage
            return None
        return next((f for f in self.findings if f.signature.key == sig.key or (
            f.signature.oracle != "desync" and same_finding(sig, f.signature))), None) or self.aliases.get(sig.key)

    def skip(self, sig: Signature, backend: Backend, how: str) -> bool:
        """Counted, not triaged: a known finding's hit, a signature that did not reproduce
        ``UNCONFIRMED_TRIES`` times when shown ``how`` (after a case, after a probe window,
        by a program), or any once the triage budget is spent."""
        known = self.known(sig)
        if known is not None:
            known.occurrences += 1
            return True
        if self.target is not None and self.spawn is None and sig.oracle in ("crash", "hang") \
                and backend.session.death() is not None:
            raise SetupError(f"the attached backend is gone; findings so far are kept ({sig.describe()})")
        if self.tries.get((sig.key, how), 0) >= UNCONFIRMED_TRIES or not budget_left(self, time.monotonic()):
            self.untriaged[sig.describe()] = self.untriaged.get(sig.describe(), 0) + 1
            return True
        return False

    def _tried(self, sig: Signature, probe: bool) -> None:
        k = (sig.key, "probe" if probe else "case")
        self.tries[k] = self.tries.get(k, 0) + 1

    def rep(self, b: Backend, cases: list[Case], sig: Signature, *, probe: bool,
            log: TrafficLog | None = None, wait: float | None = None) -> tuple[bool, Backend, Hit | None]:
        """One replay (``_reproduces``), none once the deadline passed (``Late``); ``wait``: the
        triaged hit's own (``self.wait``) unless given (a confirming replay waits twice that, at
        least 1 s: a loaded host's slow death is no reason to call it unconfirmed)."""
        if self.duration is not None and time.monotonic() >= self.started + self.duration \
                or over_budget(self, time.monotonic()):
            raise Late
        ok, b, h = _reproduces(b, cases, sig, probe=probe, log=log, wait=self.wait if wait is None else wait)
        self.current = b
        return ok, b, h

    def shows(self, sig: Signature, *, probe: bool) -> Callable[[list[Case]], bool]:
        """Nsqd's replay for delta debugging: whether ``cases``, replayed (:meth:`rep`) on the
        backend now fuzzed (``current``: a fresh process when spawned), still show ``sig``
        (then the probe command, ``probe``); ``current`` follows each replay's backend."""
        def still(cases: list[Case]) -> bool:
            ok, _, _ = self.rep(self.current, cases, sig, probe=probe)
            return ok
        return still

    def blamed(self, backend: Backend, hit: Hit, probe: bool) -> tuple[bool, Backend]:
        """Whether the input makes the difference: the baseline (``fuzz.nsqd_blame``) on a
        fresh backend, run once per campaign (with the probe or without). A failing baseline is
        confirmed ``replays`` times and kept as the target's behaviour, no input blamed; it
        explains the hit when it is of its kind (a death for a death, a bad frame for a bad
        frame; any for what a probe showed): then (False, backend)."""
        key = probe or hit.signature.oracle in ("hang", "desync")
        if key not in self.base_seen:
            self.base_seen[key] = self._baseline(backend, hit, key)
            backend = self.current
        base = self.base_seen[key]
        if base is None:
            return True, backend
        h, b = hit.signature.oracle, base.oracle
        if not (h in ("hang", "desync", "effect") or h == b or {h, b} <= {"crash", "sanitizer"}):
            return True, backend
        found = self.known(base)
        if found is not None:
            found.occurrences += 1
            self.aliases[hit.signature.key] = found
        return False, backend

    def _baseline(self, backend: Backend, hit: Hit, key: bool) -> Signature | None:
        """The baseline, confirmed ``replays`` times: its signature (a finding, no input
        blamed), or None (clean, or not every time: counted unconfirmed)."""
        if self.duration is not None and time.monotonic() >= self.started + self.duration:
            raise Late
        b = self.current = backend.fresh()
        self.restarts += 1
        base = baseline(b, hit.signature, probe=key)
        if base is None:
            return None
        sig = base.signature

        def once() -> Hit | None:
            if self.duration is not None and time.monotonic() >= self.started + self.duration:
                raise Late
            fresh = self.current = self.current.fresh()
            self.restarts += 1
            again = baseline(fresh, sig, probe=key)
            return again if again is not None and same_finding(again.signature, sig) else None

        conf = confirm_n(once, self.replays - 1, until_miss=False)  # the first baseline is one of replays
        confirmed = 1 + len(conf.hits)
        self.restart(self.current)
        if not conf.confirmed:  # at times whatever it is sent: no input is to blame either
            self.unconfirmed += 1
            conf.note(self.environment, sig.rule, f"{sig.describe()}, no input", base.detail,
                      "a baseline sent nothing showed it, then not every confirming baseline did "
                      "(timing or load); no input is to blame either")
            return None
        if self.known(sig) is None:
            self._add(nsqd_finding(sig, [], base.detail, f"{confirmed} of {self.replays}", base.stderr,
                              note="the target's behaviour, whatever it is sent: no input blamed (" + (
                                  "the probe command with no case before it)" if base.detail.endswith(PROBED)
                                  else "a baseline connection sent nothing)"),
                              no_input=True, probe=key))
        return sig

    def _triage(self, backend: Backend, hit: Hit, suspects: list[Case], probe: bool) -> Backend:
        sig = hit.signature
        if self.skip(sig, backend, "probe" if probe else "case"):
            return self.restart(backend) if sig.oracle in ("crash", "hang", "sanitizer") else backend
        try:
            blame, backend = self.blamed(backend, hit, probe)
            if not blame:
                return backend
            return self._triage_input(backend, hit, suspects, probe)
        except Late:
            self.untriaged[sig.describe()] = self.untriaged.get(sig.describe(), 0) + 1
            return self.current

    def _triage_input(self, backend: Backend, hit: Hit, suspects: list[Case], probe: bool) -> Backend:
        sig = hit.signature
        culprit: list[Case] | None = None
        if sig.oracle == "effect" and any(m.name == sig.kind for m in NSQD.messages):
            # a command's own effect: the command alone (plain values), judged by its effect
            msg = NSQD.message(sig.kind)
            culprit = [Case("valid", (Write(encode(NSQD, msg.name, **_defaults(msg))),), True, msg.name,
                            expect=msg.effect.to, or_error=msg.effect.or_error, check=True)]
            suspects, probe = [], False
        if probe and len(suspects) > 2:
            # a failed probe: the cases since the last good one, replayed together, then delta
            # debugged down to the case(s) that break the stream (log n replays, not n)
            ok, backend, _ = self.rep(backend, suspects, sig, probe=True)
            self.restarts += 1
            if ok:
                culprit = ddmin(list(suspects), self.shows(sig, probe=True), budget=20)
                backend = self.current
            suspects = []
        if sig.oracle in ("crash", "sanitizer") and len(suspects) > 2 and not probe:
            culprit, backend = death_culprit(self, backend, sig, suspects)
            suspects = []
        for c in reversed(suspects):  # the newest suspect first
            ok, backend, _ = self.rep(backend, [c], sig, probe=probe)
            self.restarts += 1
            if ok:
                culprit = [c]
                break
        if culprit is None and len(suspects) > 1 and sig.oracle != "effect":
            ok, backend, _ = self.rep(backend, suspects, sig, probe=probe)
            culprit = suspects if ok else None
        if culprit is None:
            self.unconfirmed += 1
            self._tried(sig, probe)
            return self.restart(backend)
        if sig.oracle == "desync":  # named by what lost the stream its sync
            kind = culprit[-1].kind
            sig = Signature("desync", f"stream lost after {kind}", (), desync_rule(kind))
            hit = Hit(sig, hit.detail, hit.stderr)
        known = self.known(sig)
        if known is not None:
            known.occurrences += 1
            self.aliases[hit.signature.key] = known
            return self.restart(backend)
        self.current = backend

        test_cases = self.shows(sig, probe=probe)

        def test(writes: list[Write]) -> bool:
            return test_cases([Case(_replay_kind(sig), tuple(writes))])

        if len(culprit) > 1 and sig.oracle != "desync":
            # several cases, each as it was sent (its own connection or not, its own watch): a
            # close after a valid frame that an earlier case set up (Nsqd's E-6: SET_PID's early
            # return keeps the frame size) is no close once the two are one case of raw writes
            minimal = ddmin(list(culprit), test_cases, budget=16)
            writes = [w for c in minimal for w in c.writes]
        else:
            writes = [w for c in culprit for w in c.writes]
            if sig.oracle != "effect":
                writes = ddmin(writes, test, budget=24)
            c0 = culprit[0]
            minimal = [Case(c0.kind, tuple(writes), c0.valid, c0.note, expect=c0.expect, or_error=c0.or_error,
                            check=c0.check)]

        def confirm(cases: list[Case]) -> Confirmation[tuple[Hit | None, list[Any]]]:
            def once() -> tuple[Hit | None, list[Any]] | None:
                log = TrafficLog()
                ok, _, h = self.rep(self.current, cases, sig, probe=probe, log=log,
                                    wait=min(REPLAY_DEATH_S, max(1.0, 2 * self.wait)))
                return (h, log.records) if ok else None
            return confirm_n(once, self.replays, until_miss=False)

        conf = confirm(minimal)
        last = conf.hits[-1][0] if conf.confirmed else None
        if last is not None and last.stderr:
            hit = Hit(hit.signature, hit.detail, last.stderr)
        if not conf.confirmed:
            self.unconfirmed += 1
            self._tried(hit.signature, probe)
            conf.note(self.environment, sig.rule, sig.describe(), hit.detail,
                      f"the minimal input ({len(writes)} write(s)) showed it in triage, then "
                      f"{len(conf.hits)} of {self.replays} confirming replays did (timing or load)")
            return self.restart(self.current)
        traffic = conf.hits[-1][1]
        if len(minimal) == 1 and len(writes) == 1 and not writes[0].end and sig.oracle in ("crash", "sanitizer") \
                and not over_budget(self, time.monotonic() + 0.5 * TRIAGE_SHARE * (self.duration or 0.0)):
            # a shorter tail, once it is confirmed as the whole input was (after it: an input
            # that does not replay spends no time on cuts), while half of triage's share is left
            data = writes[0].data
            for cut in (len(data) // 2, len(data) * 3 // 4, len(data) - 1):
                if 0 < cut < len(data) and test([Write(data[:cut])]):
                    data = data[:cut]
            if len(data) < len(writes[0].data):
                shorter = [replace(minimal[0], writes=(Write(data),))]
                again = confirm(shorter)
                if again.confirmed:
                    minimal, traffic = shorter, again.hits[-1][1]
        self._add(nsqd_finding(sig, minimal, hit.detail, conf.replays, hit.stderr,
                          note=culprit[0].note + (" (then a probe command)" if probe else ""), traffic=traffic))
        self.aliases[hit.signature.key] = self.store.groups[self.findings[-1].key]
        return self.restart(self.current)

    def restart(self, backend: Backend) -> Backend:
        """The backend restarted to go on fuzzing (``Backend.restart``: a spare started in the
        background), timed on its own (``restart_s``): a restart after a hit counted, not
        triaged, is no triage."""
        t0 = time.monotonic()
        b = self.current = backend.restart()
        self.restarts += 1
        self.restart_s += time.monotonic() - t0
        return b

    def add_found(self, sig: Signature, detail: str, replays: str, note: str) -> None:
        """A finding no input is replayed for (``fuzz.nsqd_blame.leak_check``'s)."""
        self._add(nsqd_finding(sig, [], detail, replays, (), note=note))

    def _add(self, f: Finding) -> None:
        """A confirmed finding into the store (``finding-N/`` under ``out``)."""
        f.seed, f.worker = self.seed, self.worker
        self.store.add(f)

    def summary(self, elapsed: float) -> dict[str, Any]:
        """``summary.json`` (``fuzz.nsqd_report.summary``), written under ``out``."""
        return nsqd_report.summary(self, elapsed)

    # -- mcp-fuzz's campaign of the protocol (fuzz.config.FuzzCampaign) ----------------
    REFUSED: ClassVar[tuple[str, ...]] = ("--mavlink", "--seeds", "--live")

    @classmethod
    def from_config(cls, cfg: FuzzConfig, tick: Callable[[Progress], None] | None) -> StreamCampaign:
        return cls(cfg.target, cfg.spawn, cfg.seed, cfg.duration_limit, cfg.max_cases,
                   Path(cfg.out) if cfg.out else None, engine=cfg.engine, db=cfg.db, tick=tick, jobs=cfg.jobs)

    def fuzz(self) -> dict[str, Any]:
        return self.run_jobs(self.jobs, self.tick) if self.jobs > 1 else self.run()

    def abort(self) -> None:
        if self.out:
            self.summary(0.0)

    def final(self, summary: dict[str, Any], live: Any, strict: bool) -> int:
        return nsqd_report.final(self, summary, live, strict)

    @staticmethod
    def replay(path: str, cfg: FuzzConfig) -> int:
        return replay_stream_finding(path, cfg.target, cfg.spawn)

_JOB_FIELDS = ("target", "spawn", "seed", "duration", "max_cases", "replays", "probe_every", "engine", "db")


def _job(kw: dict[str, Any], worker: int, q: Any, stop: Any) -> None:
    """A ``--jobs`` worker process: its campaign, its reports (``fuzz.workers.Reporter``)."""
    reporter = Reporter(q, worker)
    c = StreamCampaign(**kw, out=None, worker=worker, stop=stop.is_set)
    c.tick = lambda _: reporter.progress(c.report)
    error = None
    try:
        c.run()
    except Exception as exc:  # noqa: BLE001 - reported by the parent in one line
        error = f"worker {worker}: {type(exc).__name__}: {exc}"
    reporter.done(c.report(findings=list(c.findings), error=error))

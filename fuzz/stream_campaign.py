"""``mcp-fuzz --protocol nsqd``: a campaign against a TCP backend until it breaks (issue 21).

Cases come from ``fuzz.stream_mutators`` (seeded); each is written on a connection to the
backend (``fuzz.stream_backend.Backend``) and judged at once by the oracles of ``fuzz.stream_oracles`` (death, sanitizer
report, a close after valid frames, the backend's own frames); every ``probe_every`` cases a
probe command must still take its effect (else the stream lost sync, or the backend hangs),
and every few hundred connections a spawned backend's descriptors are counted (a leak).

A hit is triaged: the case (or, for a failed probe, each case since the last good one) is
replayed in a fresh process until one reproduces alone; it is minimised (delta debugging
over its writes, then over its bytes); it must then reproduce N of N times (``replays``),
each in a fresh process, with the same signature, or it is dropped as unconfirmed; its
signature deduplicates it. ``finding-N/`` holds ``finding.json``, the input as hex and as a
Python bytes literal, the stderr excerpt and ``replay.txt``; ``mcp-fuzz --protocol nsqd
--replay finding-N`` reproduces it (exit 1) or not (exit 0).
"""

from __future__ import annotations

import json
import random
import shlex
import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from fuzz.ddmin import ddmin
from fuzz.stream_backend import Backend, Hit, _defaults, _replay_kind, _reproduces, message_names
from fuzz.stream_findings import TrafficLog, load_stream_finding, write_stream_repro
from fuzz.stream_mutators import Case, Write, draw_case
from fuzz.stream_oracles import CLOSE_RULE, Signature, desync_rule, same_finding
from harness.errors import SetupError
from spec import NSQD
from spec.stream_codec import encode

__all__ = ["StreamCampaign", "replay_stream_finding"]

_same, _ddmin, _CLOSE_RULE = same_finding, ddmin, CLOSE_RULE  # their old names (moved for fuzz.stream_stateful)

@dataclass
class Finding:
    signature: Signature
    cases: list[Case]
    detail: str
    replays: str
    stderr: tuple[str, ...] = ()
    count: int = 1
    note: str = ""
    traffic: list[Any] = field(default_factory=list)  # the last confirming replay's (repro.mcap, repro.pcap)
    program: list[dict[str, Any]] | None = None  # the stateful engine's: its ops (fuzz.stream_stateful.Op)

    def writes(self) -> list[Write]:
        if self.program is not None:
            return [Write(bytes.fromhex(w["hex"]), w.get("end", "")) for op in self.program for w in op["writes"]]
        return [w for c in self.cases for w in c.writes]


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
    findings: list[Finding] = field(default_factory=list)
    unconfirmed: int = 0
    cases: int = 0
    by_kind: dict[str, int] = field(default_factory=dict)
    restarts: int = 0
    engine: str = "stateless"  # stateless | stateful | both (the duration split between them)
    db: str | None = None  # hypothesis's example database of the stateful engine (--db)
    worker: int = 0  # a --jobs worker's index: its own seed stream
    tick: Callable[[StreamCampaign], None] | None = None  # live progress (fuzz.stream_progress)
    tried: dict[str, dict[str, int]] = field(default_factory=dict)  # kind -> message -> cases
    fuzz_s: float = 0.0  # seconds spent fuzzing (triage's replays excluded)
    triage_s: float = 0.0
    started: float = field(default_factory=time.monotonic)
    stop: Callable[[], bool] = lambda: False  # a --jobs parent's stop request
    current: Any = None  # the backend now fuzzed (closed at the end, whatever ends the campaign)
    workers: list[dict[str, Any]] | None = None  # --jobs: each worker's figures (fuzz.stream_jobs)

    def _over(self, deadline: float) -> bool:
        return (time.monotonic() >= deadline or (self.max_cases is not None and self.cases >= self.max_cases)
                or (self.stop_after is not None and len(self.findings) >= self.stop_after) or self.stop())

    def note_tried(self, kind: str, data: bytes) -> None:
        """Which message ids x mutation kinds were sent (the progress table, summary.json)."""
        row = self.tried.setdefault(kind, {})
        for name in message_names(data):
            row[name] = row.get(name, 0) + 1

    def _tick(self) -> None:
        if self.tick is not None:
            self.tick(self)

    def run(self) -> dict[str, Any]:
        self.started = t0 = time.monotonic()
        engines = ["stateless", "stateful"] if self.engine == "both" else [self.engine]
        backend = self.current = Backend(self.target, self.spawn)
        try:
            for k, name in enumerate(engines):
                deadline = t0 + self.duration * (k + 1) / len(engines) if self.duration is not None else float("inf")
                if name == "stateful":
                    from fuzz.stream_stateful import StreamStatefulEngine

                    backend = StreamStatefulEngine(self, backend, self.db, self.worker).run(
                        lambda d=deadline: self._over(d), self._tick)
                else:
                    backend = self._stateless(backend, deadline)
        finally:
            self.current.close()
        return self.summary(time.monotonic() - t0)

    def add_program(self, backend: Backend, hit: Any, ops: list[Any]) -> Backend:
        """A stateful program's failure: triaged like a case's (fuzz.stream_stateful)."""
        from fuzz.stream_stateful import triage_program

        t0 = time.monotonic()
        try:
            return triage_program(self, backend, hit, ops)
        finally:
            self.triage_s += time.monotonic() - t0

    def add_program_finding(self, sig: Signature, detail: str, replays: str, stderr: tuple[str, ...], note: str,
                            program: list[dict[str, Any]], traffic: list[Any] | None = None) -> None:
        """A stateful program's confirmed finding; ``traffic``: its last confirming replay's
        (repro.mcap, repro.pcap), as a case's finding has it."""
        self._add(Finding(sig, [], detail, replays, stderr, note=note, program=program, traffic=list(traffic or [])))

    def _stateless(self, backend: Backend, deadline: float) -> Backend:
        rng = random.Random(self.seed if not self.worker else hash((self.seed, self.worker)))
        window: list[Case] = []
        fds0, conns0, leak_reported = backend.fds(), 0, False
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
                    t1 = time.monotonic()
                    self.fuzz_s += t1 - t_fuzz
                    backend = self.current = self._triage(backend, hit, list(window) if probe else window[-hit.suspects:], probe)
                    t_fuzz = time.monotonic()
                    self.triage_s += t_fuzz - t1
                    window.clear()
                    continue
                if not leak_reported and self.cases % 400 == 0 and fds0 is not None:
                    fds = backend.fds()
                    grown = (fds or 0) - fds0
                    if fds is not None and grown > int(NSQD.params["fd_growth_max"]) and backend.connections - conns0 >= 50:
                        leak_reported = True
                        self._add(Finding(Signature("leak", "open descriptors grow with connections", (), "NSQD-CON-3"),
                                          [], f"{fds0} -> {fds} open descriptors over {backend.connections - conns0} "
                                          "connections", "observed over the campaign", note="connect/close cycles"))
        finally:
            self.fuzz_s += time.monotonic() - t_fuzz
        return backend

    def _triage(self, backend: Backend, hit: Hit, suspects: list[Case], probe: bool) -> Backend:
        sig = hit.signature
        known = next((f for f in self.findings if f.signature.key == sig.key), None)
        if known is not None and sig.oracle != "desync":  # deduplicated before any replay: counted
            known.count += 1
            return backend.fresh() if sig.oracle in ("crash", "hang", "sanitizer") else backend
        if self.target is not None and self.spawn is None and sig.oracle in ("crash", "hang") \
                and backend.session.death() is not None:
            raise SetupError(f"the attached backend is gone ({hit.detail}); findings so far are kept")
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
            ok, backend, _ = _reproduces(backend, suspects, sig, probe=True)
            self.restarts += 1
            if ok:
                box = {"b": backend}

                def still(cs: list[Case]) -> bool:
                    good, box["b"], _ = _reproduces(box["b"], cs, sig, probe=True)
                    return good

                culprit = _ddmin(list(suspects), still, budget=20)
                backend = box["b"]
            suspects = []
        for c in reversed(suspects):  # the newest suspect first
            ok, backend, _ = _reproduces(backend, [c], sig, probe=probe)
            self.restarts += 1
            if ok:
                culprit = [c]
                break
        if culprit is None and len(suspects) > 1 and sig.oracle != "effect":
            ok, backend, _ = _reproduces(backend, suspects, sig, probe=probe)
            culprit = suspects if ok else None
        if culprit is None:
            self.unconfirmed += 1
            return backend.fresh()
        if sig.oracle == "desync":  # named by what lost the stream its sync
            kind = culprit[-1].kind
            sig = Signature("desync", f"stream lost after {kind}", (), desync_rule(kind))
            hit = Hit(sig, hit.detail, hit.stderr)
        known = next((f for f in self.findings if f.signature.key == sig.key), None)
        if known is not None:
            known.count += 1
            return backend.fresh()
        state = {"b": backend}

        def test(writes: list[Write]) -> bool:
            ok, state["b"], _ = _reproduces(state["b"], [Case(_replay_kind(sig), tuple(writes))], sig, probe=probe)
            return ok

        writes = [w for c in culprit for w in c.writes]
        if sig.oracle != "effect":
            writes = _ddmin(writes, test, budget=24)
        if len(writes) == 1 and not writes[0].end and sig.oracle in ("crash", "sanitizer"):
            data = writes[0].data
            for cut in (len(data) // 2, len(data) * 3 // 4, len(data) - 1):  # a shorter tail, if it still reproduces
                if 0 < cut < len(data) and test([Write(data[:cut])]):
                    data = data[:cut]
            writes = [Write(data)]
        c0 = culprit[0]
        minimal = [Case(c0.kind, tuple(writes), c0.valid, c0.note, expect=c0.expect, or_error=c0.or_error,
                        check=c0.check)]
        confirmed = 0
        traffic: list[Any] = []
        for _ in range(self.replays):
            log = TrafficLog()
            ok, state["b"], last = _reproduces(state["b"], minimal, sig, probe=probe, log=log)
            confirmed += ok
            traffic = log.records if ok else traffic
            if last is not None and last.stderr:
                hit = Hit(hit.signature, hit.detail, last.stderr)
        if confirmed < self.replays:
            self.unconfirmed += 1
            return state["b"].fresh()
        self._add(Finding(sig, minimal, hit.detail, f"{confirmed} of {self.replays}", hit.stderr,
                          note=culprit[0].note + (" (then a probe command)" if probe else ""), traffic=traffic))
        return state["b"].fresh()

    def _add(self, f: Finding) -> None:
        self.findings.append(f)
        if self.out is not None:
            write_finding(self.out / f"finding-{len(self.findings)}", f, self.spawn, self.target, probe="probe" in f.note)

    def summary(self, elapsed: float) -> dict[str, Any]:
        """``summary.json``: cases, judged cases/s (triage's replays excluded), findings by
        class (the oracle) and each one, which message ids x mutation kinds were sent."""
        by_class: dict[str, int] = {}
        for f in self.findings:
            by_class[f.signature.oracle] = by_class.get(f.signature.oracle, 0) + 1
        s = {"protocol": "nsqd", "engine": self.engine, "seed": self.seed, "cases": self.cases,
             "elapsed_s": round(elapsed, 2), "cases_per_s": round(self.cases / elapsed, 1) if elapsed else 0,
             "fuzz_s": round(self.fuzz_s, 2), "triage_s": round(self.triage_s, 2),
             "judged_cases_per_s": round(self.cases / self.fuzz_s, 1) if self.fuzz_s else 0,
             "by_kind": self.by_kind, "tried": self.tried, "findings_by_class": by_class,
             "findings": [{"signature": f.signature.describe(), "oracle": f.signature.oracle, "rule": f.signature.rule,
                           "count": f.count, "replays": f.replays, "engine": "stateful" if f.program is not None
                           else "stateless"} for f in self.findings],
             "unconfirmed": self.unconfirmed, "restarts": self.restarts, "db": self.db,
             "jobs": len(self.workers) if self.workers is not None else 1}
        if self.workers is not None:
            s["workers"] = self.workers
        if self.out is not None:
            (self.out / "summary.json").write_text(json.dumps(s, indent=2) + "\n")
        return s


def write_finding(d: Path, f: Finding, spawn: str | None, target: tuple[str, int] | None, *, probe: bool) -> None:
    d.mkdir(parents=True, exist_ok=True)
    data = b"".join(w.data for w in f.writes())
    doc = {"protocol": "nsqd", "oracle": f.signature.oracle, "kind": f.signature.kind, "access": f.signature.access,
           "frames": list(f.signature.frames), "rule": f.signature.rule, "level": "MUST",
           "description": f.signature.describe(), "detail": f.detail, "note": f.note, "replays": f.replays,
           "probe": probe, "writes": [{"hex": w.data.hex(), "end": w.end} for w in f.writes()],
           "expect": [list(c.expect) for c in f.cases if c.check], "or_error": any(c.or_error for c in f.cases)}
    if f.program is not None:
        doc["program"] = f.program
    (d / "finding.json").write_text(json.dumps(doc, indent=2) + "\n")
    write_stream_repro(d, doc, f.traffic)
    (d / "input.hex").write_text(data.hex(" ") + "\n")
    (d / "input.py").write_text(f"# {f.signature.describe()}\nINPUT = {data!r}\n")
    (d / "stderr.txt").write_text("\n".join(f.stderr) + "\n")
    how = ["--spawn", spawn] if spawn else (["--target", f"{target[0]}:{target[1]}"] if target else [])
    (d / "replay.txt").write_text(shlex.join(["mcp-fuzz", "--protocol", "nsqd", "--replay", str(d.resolve()), *how]) + "\n")


def replay_stream_finding(path: str, target: tuple[str, int] | None, spawn: str | None,
                          prog: str = "mcp-fuzz") -> int:
    """Replay a finding (``finding-N/``, its finding.json, repro.mcap or repro.pcap) once in a
    fresh backend: 1 reproduced, 0 not, 2 unreadable."""
    doc_path = path
    try:
        doc = load_stream_finding(path)
        writes = [Write(bytes.fromhex(w["hex"]), w.get("end", "")) for w in doc["writes"]]
        expect = tuple(doc.get("expect", [[]])[0]) if doc.get("expect") else ()
        sig = Signature(doc["oracle"], doc["kind"], tuple(doc.get("frames", [])), doc["rule"], doc.get("access", ""))
        program = None
        if doc.get("program"):
            from fuzz.stream_stateful import Op

            program = [Op.from_json(o) for o in doc["program"]]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        print(f"{prog}: error: {'--replay: ' if prog == 'mcp-fuzz' else ''}cannot read {doc_path}: {exc}")
        return 2
    if not writes and program is None:
        print(f"{prog}: {sig.describe()}: observed over a campaign (connect/close cycles); replay it with "
              "mcp-conform --protocol nsqd --select NSQD-CON-3")
        return 2
    backend = Backend(target, spawn)
    if program is not None:
        from fuzz.stream_stateful import play_program

        try:
            seen = play_program(backend, program)
        finally:
            backend.close()
        if seen is not None and _same(seen.signature, sig):
            print(f"reproduced {sig.rule}: {sig.describe()}")
            return 1
        print(f"did not reproduce {sig.describe()}" + (f" (saw {seen.signature.describe()})" if seen else ""))
        return 0
    try:
        case = Case(_replay_kind(sig), tuple(writes), bool(expect), sig.kind if expect else "", expect=expect,
                    or_error=bool(doc.get("or_error")), check=bool(expect))
        ok, backend, hit = _reproduces(backend, [case], sig, probe=bool(doc.get("probe")))
    finally:
        backend.close()
    if ok:
        print(f"reproduced {sig.rule}: {sig.describe()}")
        return 1
    print(f"did not reproduce {sig.describe()}" + (f" (saw {hit.signature.describe()})" if hit else ""))
    return 0

"""Nsqd's triage (issue 37: the protocol's part of the one campaign loop, ``fuzz.loop``): from
a hit the engines saw (``fuzz.nsqd_engine``) to a finding, as ``fuzz.triage`` is MCP's.

A hit is triaged: the case (or, for a failed probe, each case since the last good one) is
replayed in a fresh process until one reproduces alone; it is minimised (delta debugging
over its writes, then over its bytes); it must then reproduce N of N times (``n_of_n``),
each in a fresh process, with the same signature, or it is dropped as unconfirmed; its
signature deduplicates it. Before any replay, the same observation without the input (a
connection sent nothing; the probe with no case before it) decides whether the input made
the difference: if the baseline fails too, the finding is the target's behaviour, under the
rule the baseline broke, with no input blamed (``fuzz.nsqd_blame``, issue 36 item 2). A hit
whose signature is already a finding (or was one's before minimising) is counted, not
triaged again; one that did not reproduce ``UNCONFIRMED_TRIES`` times is counted too; triage
has a budget (``TRIAGE_SHARE`` of the campaign) and ``--duration`` bounds it, within
``GRACE_S`` (``fuzz.budget``; timed and counted by ``fuzz.loop.triage_time``). A stateful
program's failure is triaged by careful replays (``fuzz.nsqd_stateful.triage_program``).
``finding-N/`` holds ``finding.json``, the input as hex and as a Python bytes literal, the
stderr excerpt, the replay's traffic and ``replay.txt`` (``fuzz.nsqd_repro``).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import Any, ClassVar

from mcp_conform.fuzz.budget import TRIAGE_SHARE, over_budget
from mcp_conform.fuzz.confirm import Confirmation
from mcp_conform.fuzz.finding_files import TrafficLog
from mcp_conform.fuzz.findings import Finding
from mcp_conform.fuzz.loop import WorkerTarget, triage_time
from mcp_conform.fuzz.nsqd_backend import (
    REPLAY_DEATH_S,
    Backend,
    Hit,
    _defaults,
    _replay_kind,
    _reproduces,
)
from mcp_conform.fuzz.nsqd_blame import PROBED, baseline
from mcp_conform.fuzz.nsqd_mutators import Case, Write
from mcp_conform.fuzz.nsqd_oracles import Signature, desync_rule, same_finding
from mcp_conform.fuzz.triage_core import (
    HitTriage,
    Parts,
    fewer_parts,
    fewest,
    prefix_culprit,
    search,
)
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd_codec import encode
from mcp_conform.spec.profiles import NSQD_PROFILE

__all__ = ["StreamTarget", "StreamTriage", "nsqd_finding"]


#: a worker's Nsqd backend (``fuzz.nsqd_backend.Backend``) as the loop sees a target
StreamTarget = WorkerTarget


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
class StreamTriage(HitTriage):
    """One worker's Nsqd triage (an engine's turn's; what it learnt, ``LEARNT``, carried on to
    the next turn's; its steps, counts and bounds: ``fuzz.triage_core.HitTriage``;
    ``untriaged`` by signature, ``tries`` by (signature key, how))."""

    LEARNT: ClassVar[tuple[str, ...]] = ("tries", "aliases", "baselines")
    DEATHS: ClassVar[tuple[str, ...]] = ("crash", "hang", "sanitizer")
    aliases: dict[Any, Finding] = field(default_factory=dict)  # a hit's key -> the finding it became
    #: how long a replay of the hit now triaged waits for it to show (``Backend.suspects``)
    wait: float = REPLAY_DEATH_S

    def consider(self, backend: Backend, hit: Hit, window: list[Case], probe: bool) -> Backend:
        """A hit after the cases of ``window`` (then the probe command, ``probe``) triaged,
        timed (``fuzz.loop.triage_time``); the backend to go on with."""
        def triage() -> None:
            # a death may show only at the next case's write: the one before is a suspect too
            suspects, self.wait = (list(window), REPLAY_DEATH_S) if probe else backend.suspects(hit, window)
            self._triage(backend, hit, suspects, probe)
        return self.triaged(hit.signature.describe(), triage)  # _triage's backend is the one now fuzzed

    def add_program(self, backend: Backend, hit: Any, ops: list[Any]) -> Backend:
        """A stateful program's failure: triaged like a case's (fuzz.nsqd_stateful)."""
        from mcp_conform.fuzz.nsqd_stateful import triage_program

        self.wait = REPLAY_DEATH_S
        with triage_time(self, hit.signature.describe()):
            if self.skip(hit.signature, backend, "program"):
                return self.restart(backend) if hit.signature.oracle in self.DEATHS else backend
            blame, backend = self.blamed(backend, hit, False)
            return triage_program(self, backend, hit, ops) if blame else backend
        return self.current

    def add_program_finding(self, sig: Signature, detail: str, replays: str, stderr: tuple[str, ...], note: str,
                            program: list[dict[str, Any]], traffic: list[Any] | None = None) -> None:
        """A stateful program's confirmed finding; ``traffic``: its last confirming replay's
        (repro.mcap, repro.pcap), as a case's finding has it."""
        self.add(nsqd_finding(sig, [], detail, replays, stderr, note=note, program=program, traffic=traffic))

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
        return self.counted(self.known(sig), (sig.key, how), sig.describe())

    def _shows(self, sig: Signature, *, probe: bool) -> Callable[[list[Case]], bool]:
        """The search's predicate (``HitTriage.shows``): ``cases`` replayed (``_reproduces``) on
        a fresh process of the backend now fuzzed (``current``, which follows each replay's
        backend) still show ``sig`` (then the probe command, ``probe``); each replay a restart
        counted (``triage replay``)."""
        def replay(cases: list[Case]) -> Signature | None:
            ok, self.current, _ = self.fresh(lambda: _reproduces(self.current, cases, sig, probe=probe, wait=self.wait))
            return sig if ok else None
        return self.shows(replay)

    def blamed(self, backend: Backend, hit: Hit, probe: bool) -> tuple[bool, Backend]:
        """Whether the input makes the difference: the baseline (``fuzz.nsqd_blame.baseline``,
        ``HitTriage.baseline``) on fresh backends, once a worker (with the probe or without).
        A failing baseline, confirmed ``n_of_n`` times, is kept as the target's behaviour, no
        input blamed; it explains the hit when it is of its kind (a death for a death, a bad
        frame for a bad frame; any for what a probe showed): then (False, backend)."""
        key = probe or hit.signature.oracle in ("hang", "desync")
        ran = key not in self.baselines
        if ran:
            self.current = backend

        def observe(log: list[Any], first: Hit | None) -> Hit | None:
            b = self.current = self.fresh(self.current.fresh)
            return baseline(b, (first or hit).signature, probe=key)

        def found(first: Hit, last: Hit, log: list[Any], replays: str) -> Finding | None:
            how = ("the probe command with no case before it)" if first.detail.endswith(PROBED)
                   else "a baseline connection sent nothing)")
            return None if self.known(first.signature) is not None else nsqd_finding(
                first.signature, [], first.detail, replays, first.stderr, no_input=True, probe=key,
                note=f"the target's behaviour, whatever it is sent: no input blamed ({how}")

        base = self.no_input(key, observe, lambda a, b: same_finding(a.signature, b.signature), found,
                             lambda h: (h.signature.rule, f"{h.signature.describe()}, no input", h.detail),
                             lambda: self.restart(self.current))
        backend = self.current if ran else backend
        if base is None:
            return True, backend
        h, b = hit.signature.oracle, base.signature.oracle
        if not (h in ("hang", "desync", "effect") or h == b or {h, b} <= {"crash", "sanitizer"}):
            return True, backend
        self.again_as(hit, self.known(base.signature))
        return False, backend

    def _triage(self, backend: Backend, hit: Hit, suspects: list[Case], probe: bool) -> Backend:
        sig = hit.signature
        if self.skip(sig, backend, "probe" if probe else "case"):
            return self.restart(backend) if sig.oracle in self.DEATHS else backend
        blame, backend = self.blamed(backend, hit, probe)
        if not blame:
            return backend
        return self._triage_input(backend, hit, suspects, probe)

    def _triage_input(self, backend: Backend, hit: Hit, suspects: list[Case], probe: bool) -> Backend:
        sig = hit.signature
        culprit: list[Case] | None = None
        if sig.oracle == "effect" and any(m.name == sig.kind for m in NSQD.messages):
            # a command's own effect: the command alone (plain values), judged by its effect
            msg = NSQD.message(sig.kind)
            culprit = [Case("valid", (Write(encode(NSQD, msg.name, **_defaults(msg))),), True, msg.name,
                            expect=msg.effect.to, or_error=msg.effect.or_error, check=True)]
            suspects, probe = [], False
        self.current = backend
        if probe and len(suspects) > 2:
            # a failed probe: the cases since the last good one, replayed together, then delta
            # debugged down to the case(s) that break the stream (log n replays, not n)
            culprit = search(suspects, self._shows(sig, probe=True), tries=[], budget=20)
        elif sig.oracle in ("crash", "sanitizer") and len(suspects) > 2 and not probe:
            # every case its process was sent before the death's cause showed (a real backend
            # handles one frame per 20 ms loop and lagged a dozen cases behind the fuzzer: its
            # culprit was seldom among the last two)
            culprit = prefix_culprit(suspects, self._shows(sig, probe=False))
        elif culprit is None:  # the newest suspect alone first, then all of them
            culprit = search(suspects, self._shows(sig, probe=probe), whole=sig.oracle != "effect", budget=0)
        backend = self.current
        if culprit is None:
            self.not_confirmed(sig.rule, (sig.key, "probe" if probe else "case"))
            return self.restart(backend)
        if sig.oracle == "desync":  # named by what lost the stream its sync
            kind = culprit[-1].kind
            sig = Signature("desync", f"stream lost after {kind}", (), desync_rule(kind))
            hit = Hit(sig, hit.detail, hit.stderr)
        if self.again_as(hit, self.known(sig)):
            return self.restart(backend)
        self.current = backend

        test_cases = self._shows(sig, probe=probe)

        def test(writes: list[Write]) -> bool:
            return test_cases([Case(_replay_kind(sig), tuple(writes))])

        if len(culprit) > 1 and sig.oracle != "desync":
            # several cases, each as it was sent (its own connection or not, its own watch): a
            # close after a valid frame that an earlier case set up (Nsqd's E-6: SET_PID's early
            # return keeps the frame size) is no close once the two are one case of raw writes
            minimal = fewest(list(culprit), test_cases, budget=16)
            writes = [w for c in minimal for w in c.writes]
        else:  # one case of them all, its fewest writes (each replay a case of the signature's kind)
            writes = [w for c in culprit for w in c.writes]
            if sig.oracle != "effect":
                one = Case(_replay_kind(sig), tuple(writes))
                writes = list(fewer_parts(one, test_cases, Parts(lambda c: c.writes, lambda c, ws: replace(
                    c, writes=tuple(ws)), 24)).writes)
            c0 = culprit[0]
            minimal = [Case(c0.kind, tuple(writes), c0.valid, c0.note, expect=c0.expect, or_error=c0.or_error,
                            check=c0.check)]

        def confirm(cases: list[Case]) -> Confirmation[tuple[Hit, TrafficLog]]:
            def once(log: TrafficLog) -> Hit | None:
                # each waits twice the triaged hit's own wait, at least 1 s (``self.wait``: a
                # loaded host's slow death is no reason to call it unconfirmed), its traffic
                # logged, its fresh process counted as every triage replay's is
                ok, self.current, h = self.fresh(lambda: _reproduces(
                    self.current, cases, sig, probe=probe, log=log, wait=min(REPLAY_DEATH_S, max(1.0, 2 * self.wait))))
                return h if ok else None
            return self.confirm_logged(once, until_miss=False, log=TrafficLog)

        conf = confirm(minimal)
        last = conf.hits[-1][0] if conf.confirmed else None
        if last is not None and last.stderr:
            hit = Hit(hit.signature, hit.detail, last.stderr)
        if self.missed(sig.rule, (hit.signature.key, "probe" if probe else "case"), conf, shape=sig.describe(),
                       actual=hit.detail, size=f"{len(writes)} write(s)"):
            return self.restart(self.current)
        if len(minimal) == 1 and len(writes) == 1 and not writes[0].end and sig.oracle in ("crash", "sanitizer") \
                and not over_budget(self, time.monotonic() + 0.5 * TRIAGE_SHARE * (self.duration or 0.0)):
            # a shorter tail, once it is confirmed as the whole input was (after it: an input
            # that does not replay spends no time on cuts), while half of triage's share is left;
            # kept when it is confirmed too (HitTriage.shorter)
            def tail() -> list[Case]:
                data = writes[0].data
                for cut in (len(data) // 2, len(data) * 3 // 4, len(data) - 1):
                    if 0 < cut < len(data) and test([Write(data[:cut])]):
                        data = data[:cut]
                return [replace(minimal[0], writes=(Write(data),))] if len(data) < len(writes[0].data) else minimal
            minimal, conf = self.shorter(minimal, conf, tail, lambda cases, _: confirm(cases))
        self.add(nsqd_finding(sig, minimal, hit.detail, conf.replays, hit.stderr,
                              note=culprit[0].note + (" (then a probe command)" if probe else ""),
                              traffic=conf.hits[-1][1].records))
        self.aliases[hit.signature.key] = self.store.groups[self.findings[-1].key]
        return self.restart(self.current)

    def again_as(self, hit: Hit, known: Finding | None) -> bool:
        """Whether ``hit`` is ``known``'s (``HitTriage.again``): then also its key's alias."""
        if known is not None:
            self.aliases[hit.signature.key] = known
        return self.again(known)

    def restart(self, backend: Backend) -> Backend:
        """The backend restarted to go on fuzzing (``Backend.restart``: a spare started in the
        background), timed on its own (``restart_seconds``): a restart after a hit counted, not
        triaged, is no triage."""
        b = self.current = self.restarted(backend.restart)
        self.target.count_restart("after a hit")
        return b

    def add_found(self, sig: Signature, detail: str, replays: str, note: str) -> None:
        """A finding no input is replayed for (``fuzz.nsqd_blame.leak_check``'s)."""
        self.add(nsqd_finding(sig, [], detail, replays, (), note=note))

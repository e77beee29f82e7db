"""Nsqd's stateless engine (issue 21; issue 37: an engine of the one campaign loop,
``fuzz.loop``, as ``fuzz.engine_stateless`` is MCP's).

Cases come from ``fuzz.nsqd_mutators`` (seeded); each is written on a connection to the
backend (``fuzz.nsqd_backend.Backend``) and judged at once by the oracles of
``fuzz.nsqd_oracles`` (death, sanitizer report, a close after valid frames, the backend's own
frames); one valid command in four is judged by its effect; every ``probe_every`` cases a
probe command must still take its effect (else the stream lost sync, or the backend hangs).
A hit goes to the worker's triage (``fuzz.nsqd_triage.StreamTriage.consider``) with the cases
since the stream was last proven in sync.
"""

from __future__ import annotations

from dataclasses import replace

from mcp_conform.fuzz.campaign_core import CaseEngine
from mcp_conform.fuzz.nsqd_backend import Hit, message_names
from mcp_conform.fuzz.nsqd_mutators import Case, draw_case
from mcp_conform.fuzz.nsqd_triage import StreamTriage

__all__ = ["StreamStatelessEngine"]


class StreamStatelessEngine(CaseEngine):
    """Cases on one connection at a time until the budget is spent (``fuzz.campaign_core``)."""

    triage: StreamTriage

    def __init__(self, triage: StreamTriage, seed: int, worker: int = 0, probe_every: int = 40) -> None:
        # the cases kept (``CaseEngine.sent``): those since the stream was last proven in sync,
        # at most ``probe_every`` (the probe then proves it, or its hit takes them)
        super().__init__(triage, seed, worker, history=max(1, probe_every))
        self.probe_every = probe_every
        self.probed = False  # the hit now triaged is the probe's

    def draw(self) -> Case:
        case = draw_case(self.rng)
        if case.expect and self.stats.cases % 4 == 0:  # one valid command in four is judged by its effect
            case = replace(case, check=True)
        return case

    def tried(self, case: Case) -> tuple[str, list[str]]:
        return case.kind, message_names(case.data)

    def send(self, case: Case) -> Hit | None:
        backend = self.triage.current
        hit = backend.run(case)
        self.probed = False
        if hit is None and backend.synced:  # a judged effect proved the stream in sync
            backend.synced = False
            self.sent.clear()
        if hit is None and len(self.sent) >= self.probe_every:
            hit, self.probed = backend.probe(), True
            if hit is None:
                self.sent.clear()
        return hit

    def triage_hit(self, hit: Hit) -> None:
        t = self.triage
        t.current = t.consider(t.current, hit, self.taken(), self.probed)

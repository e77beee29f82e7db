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

import random
from collections.abc import Callable
from dataclasses import replace

from mcp_conform.fuzz.loop import EngineStats, FuzzClock
from mcp_conform.fuzz.nsqd_backend import message_names
from mcp_conform.fuzz.nsqd_mutators import Case, draw_case
from mcp_conform.fuzz.nsqd_triage import StreamTriage

__all__ = ["StreamStatelessEngine"]


class StreamStatelessEngine:
    """Cases on one connection at a time until the budget is spent."""

    def __init__(self, triage: StreamTriage, seed: int, worker: int = 0, probe_every: int = 40) -> None:
        self.triage, self.probe_every = triage, probe_every
        self.stats = EngineStats()
        self.rng = random.Random(seed if not worker else hash((seed, worker)))

    def run(self, deadline: float, max_cases: int | None, tick: Callable[[EngineStats], None] | None,
            stop: Callable[[], bool]) -> EngineStats:
        st, triage = self.stats, self.triage
        backend = triage.current
        window: list[Case] = []
        clock = FuzzClock(st, tick)
        try:
            while not st.spent(deadline, max_cases, stop):
                case = draw_case(self.rng)
                if case.expect and st.cases % 4 == 0:  # one valid command in four is judged by its effect
                    case = replace(case, check=True)
                clock.case(case.kind, message_names(case.data))
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
                    with clock.triage():
                        backend = triage.current = triage.consider(backend, hit, window, probe)
                    window.clear()
        finally:
            clock.stop()
        return st

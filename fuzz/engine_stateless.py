"""The stateless engine: batches of generated and mutated datagrams, each batch judged as a
whole by every oracle, a batch looked into only when something was found.

One round: up to ``BATCH`` cases (``fuzz.mutators``) sent back to back, then the liveness
probe (``TargetBase.probe``). The probe's ACK proves the node is live and, since a node
handles its datagrams in order, that every ACK it was going to send for the batch has been
sent: the ACKs that came name their cases by sequence number (``fuzz.oracles.judge_exchange``)
and the silence of the rest is proven without a timeout of its own. The monitor judges all
traffic, the process's fate and the vehicle's record are read once per round. A flaw goes
to triage (confirm on a fresh node, shrink, group); a dead or hung node is restarted.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace

from mcp_conform.fuzz.loop import EngineStats
from mcp_conform.fuzz.mutators import CaseGenerator
from mcp_conform.fuzz.oracles import DeliveryLedger, Flaw, Input, MonitorOracle, judge_exchange
from mcp_conform.fuzz.replay import frame_token, vehicle_counts
from mcp_conform.fuzz.target_base import DIED, TargetBase
from mcp_conform.fuzz.triage import Triage
from mcp_conform.spec.codec import Action

__all__ = ["BATCH", "EngineStats", "StatelessEngine"]

BATCH = 64  # cases per probe
BATCH_BYTES = 192 * 1024  # at most this much per batch, well inside a socket buffer
VEHICLE_WATCH = 3.0  # s: how long a passthrough frame's forwards are counted
_PASSTHROUGH = int(Action.MAV_PASSTHROUGH)


class StatelessEngine:
    """Runs rounds against one target until the budget is spent."""

    def __init__(self, target: TargetBase, triage: Triage, seed: int, *, worker: int = 0,
                 seeds: list[bytes] | None = None, batch: int = BATCH) -> None:
        self.target = target
        self.triage = triage
        self.batch = batch
        self.stats = EngineStats()
        drv = target.driver
        self.gen = CaseGenerator(seed, target.node_id, target.broadcast_id, our_id=drv.our_id,
                                 seeds=seeds or (), next_seq=drv.next_seq, worker=worker)
        self.monitor = MonitorOracle(target.node_id, target.rto, target.ack_window,
                                     target.broadcast_id, drv.listen)
        self.ledger = DeliveryLedger(target.node_id, target.broadcast_id)
        self._vehicle_flagged: set[bytes] = set()
        self._pending_vehicle: list[Flaw] = []

    def _fresh_oracles(self) -> None:
        drv = self.target.driver
        self.monitor = MonitorOracle(self.target.node_id, self.target.rto, self.target.ack_window,
                                     self.target.broadcast_id, drv.listen)
        self.ledger = DeliveryLedger(self.target.node_id, self.target.broadcast_id)

    def run(self, deadline: float, max_cases: int | None,
            tick: Callable[[EngineStats], None] | None = None,
            stop: Callable[[], bool] = lambda: False) -> EngineStats:
        """Rounds until ``deadline`` (time.monotonic) or ``max_cases``."""
        st = self.stats
        while not st.spent(deadline, max_cases, stop):
            left = self.batch if max_cases is None else min(self.batch, max_cases - st.cases)
            t0 = time.monotonic()
            flaws, inputs = self.round(left)
            st.seconds += time.monotonic() - t0
            st.batches += 1
            if flaws:
                st.flaws += len(flaws)
                self._triage(flaws, inputs)
            while self._pending_vehicle:
                f = self._pending_vehicle.pop()
                st.flaws += 1
                assert f.datagram is not None
                self._triage([replace(f, culprit=0)], [Input.of(f.datagram)])
            if tick is not None:
                tick(st)
        return st

    def round(self, n: int) -> tuple[list[Flaw], list[Input]]:
        """One batch of ``n`` cases and its probe, judged."""
        target, drv, gen = self.target, self.target.driver, self.gen
        inputs: list[Input] = []
        size = 0
        mark = drv.mark()
        for _ in range(n):
            case = gen.next()
            if inputs and size + len(case.data) > BATCH_BYTES:
                break
            drv.send_raw(case.data)
            inp = Input.of(case.data)
            token = case.token if case.token is not None else (
                frame_token(case.data) if inp.header and inp.header[3] == _PASSTHROUGH else None)
            self.ledger.sent(len(inputs), inp, token)
            inputs.append(inp)
            size += len(case.data)
            self.stats.by_mutator[case.mutator] = self.stats.by_mutator.get(case.mutator, 0) + 1
        probe = target.probe()
        self.ledger.sent(len(inputs), Input.of(probe.sent.data), None)
        self.stats.cases += len(inputs)
        flaws = judge_exchange(inputs, target, mark, probe)
        index = {inp.data: i for i, inp in enumerate(inputs)}
        flaws += [replace(f, culprit=index.get(f.datagram)) if f.datagram is not None else f
                  for f in self.monitor.feed(target.traffic.drain())]
        if target.vehicle is not None and self.ledger.expected:
            # over-delivery is judged whenever it shows; a token is watched for a while
            for f in self.ledger.judge(vehicle_counts(target), settled=False):
                if f.datagram is not None and f.datagram not in self._vehicle_flagged:
                    self._vehicle_flagged.add(f.datagram)
                    self._pending_vehicle.append(f)
            self.ledger.expire(time.monotonic() - VEHICLE_WATCH)
        return flaws, inputs

    def _triage(self, flaws: list[Flaw], inputs: list[Input]) -> None:
        if any(f.source in ("liveness", "process") for f in flaws):
            # attach mode: a node that does not answer now is lost, and nothing it did not
            # say counts (TargetLost ends the campaign; issue 19 item 1)
            self.target.check_live("after a batch it did not answer")
        seen: set[str] = set()
        for f in flaws:
            if f.rule in seen:
                continue
            seen.add(f.rule)
            self.triage.consider(f, inputs, "batch")
        # triage replays on fresh nodes; a dead node is restarted either way
        if not self.target.alive() or any(f.source in ("liveness", "process") for f in flaws):
            if self.target.spawned:
                self.target.restart(DIED)
        self.stats.restarts = self.target.restarts
        self.target.traffic.drain()
        self._fresh_oracles()

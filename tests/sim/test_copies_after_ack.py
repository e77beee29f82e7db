"""MCP-RTX-1's "until it is ACKed", observed after the right ACK (the startup's watch,
``harness.session_base.WithheldCopies.watch_after_right_ack``), in the simulator.

A copy that arrives after the right ACK may have crossed it: sent before the node read the ACK
(its timer fired first; a loaded host kept its reader off the CPU past the runner's grace). That
node is correct -- it stops -- and one such copy proves nothing: CI's loaded runs failed the
sample node's ``arm-early`` run so under ``--parallel 3`` ("1 copies after the right ACK"). A
node that goes on retransmitting sends another copy a period later, and that proves the rule
broken. Both are models here: the reference endpoint with its reader one timer late, and one
that needs three right ACKs to stop.
"""

from __future__ import annotations

import random
from typing import Any

import pytest

from mcp_conform.reference_impl.endpoint import Endpoint
from mcp_conform.sim.faults import FaultMixin
from mcp_conform.sim.models import DroneModel
from mcp_conform.sim.runner import run_cases
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action, peek_header

SHORT = {"rto": 0.2, "ack_window": 0.25}
DESCRIPTION = {"rto": 5.0, "ack_window": 2.0}
_ACK = int(Action.ACK)


def _right_ack(ep: Endpoint, data: bytes) -> bool:
    u = ep._in_flight
    head = peek_header(data) if u is not None else None
    return (u is not None and head is not None and head[3] == _ACK and head[1] == u.dst
            and len(data) >= 2 and int.from_bytes(data[-2:], "big") == u.seq)


class LateReader(FaultMixin):
    """Correct: the right ACK is read only after the retransmission timer that was due next
    has fired (one copy crosses the ACK, then retransmission stops)."""

    _held: tuple[bytes, Any] | None = None

    def receive_datagram(self, data: bytes, addr: Any, now: float) -> None:
        if self._held is None and _right_ack(self, data):
            self._held = (data, addr)
            return
        super().receive_datagram(data, addr, now)

    def _on_retransmit(self, msg: Any, addr: Any, now: float, u: Any) -> None:
        super()._on_retransmit(msg, addr, now, u)
        if self._held is not None:
            (data, a), self._held = self._held, None
            self.deviations.append((now, f"seq {u.seq}: a copy crossed its ACK"))
            Endpoint.receive_datagram(self, data, a, now)


class NeedsThreeAcks(FaultMixin):
    """Faulty (MCP-RTX-1): the right ACK ends retransmission only the third time it comes."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._seen: dict[int, int] = {}

    def receive_datagram(self, data: bytes, addr: Any, now: float) -> None:
        if _right_ack(self, data):
            u = self._in_flight
            n = self._seen[u.seq] = self._seen.get(u.seq, 0) + 1
            if n < 3:
                self.deviations.append((now, f"seq {u.seq}: right ACK {n} ignored"))
                return
        super().receive_datagram(data, addr, now)


def _factory(cls: type[Endpoint], rto: float):
    spawns = random.Random(7)
    retries = int(SPEC.params["retries"])

    def endpoint(node_id: int, timeout: float, _retries: int, rng: random.Random) -> Endpoint:
        return cls(node_id, timeout=timeout, retries=retries, rng=rng)

    def make(now: float) -> DroneModel:
        return DroneModel(1, rto, retries, random.Random(spawns.getrandbits(64)), ready_at=now + 0.05,
                          endpoint=endpoint)

    make.__name__ = cls.__name__
    return make


def _rtx1(run) -> str | None:
    return next((c["outcome"] for c in run.report["cases"]
                 if c["id"] == "RTX/test_mission_ready_is_retransmitted_until_acked"), None)


@pytest.mark.parametrize("timing", [SHORT, DESCRIPTION], ids=["short", "description-5s"])
def test_a_copy_that_crossed_the_right_ack_is_no_violation(timing):
    run = run_cases(_factory(LateReader, timing["rto"]), seed=5, select=["RTX"], **timing)
    assert _rtx1(run) == "passed", run.explain()
    assert not run.rules_with("failed", "warned"), run.explain()


@pytest.mark.parametrize("timing", [SHORT, DESCRIPTION], ids=["short", "description-5s"])
def test_a_node_that_goes_on_after_the_right_ack_fails_rtx1(timing):
    run = run_cases(_factory(NeedsThreeAcks, timing["rto"]), seed=5, select=["RTX"], **timing)
    assert _rtx1(run) == "failed", run.explain()
    case = next(c for c in run.report["cases"] if c["id"].endswith("until_acked"))
    assert "after the right ACK" in case["actual"], case

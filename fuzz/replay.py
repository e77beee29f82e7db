"""Replaying a sequence of datagrams against a node and judging what it did: the one path
behind confirmation, shrinking and ``mcp-fuzz --replay`` (so a reproducer replays exactly as
its finding was confirmed).

A sequence is sent in one of two paces: ``batch`` (back to back, as the stateless engine
sends) or ``paced`` (each well-formed unicast to the node awaits its ACK before the next is
sent, as the stateful engine plays the manager). A liveness probe follows; with the vehicle,
a sentinel passthrough frame after it shows when every earlier forward has arrived.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field

from mcp_conform.fuzz.drone_target import FuzzTarget
from mcp_conform.fuzz.oracles import (
    DeliveryLedger,
    Flaw,
    Input,
    MonitorOracle,
    judge_exchange,
    judge_withheld,
)
from mcp_conform.fuzz.target_base import REPLAY, TargetBase
from mcp_conform.spec.codec import Action
from mcp_conform.vehicle.probe import make_probe, probe_token

__all__ = ["WITHHOLD", "Outcome", "frame_token", "run_sequence"]

_ACK = int(Action.ACK)
SENTINEL_WAIT = 2.0  # s: how long the sentinel frames may take to reach the vehicle
SENTINEL_SRC = 0x5E47  # the sentinel's own source ID
#: Scenario "withhold:N": a fresh node whose Mission_Ready ACK is withheld for N copies, then
#: given out of order (TargetBase.restart_withholding), before the datagrams are sent.
WITHHOLD = "withhold:"


def frame_token(data: bytes) -> str | None:
    """The probe token of a Mav_Passthrough datagram's frame, if it carries one."""
    from mcp_conform.spec.codec import HEADER_SIZE
    from mcp_conform.spec.mavframe import FrameError, parse_frame

    if len(data) <= HEADER_SIZE:
        return None
    try:
        msg = parse_frame(data[HEADER_SIZE:])
    except (FrameError, Exception):  # noqa: BLE001 - pymavlink raises anything on garbage
        return None
    if msg.get_type() != "STATUSTEXT":
        return None
    return probe_token(msg.text)


@dataclass
class Outcome:
    """What one replay showed."""

    flaws: list[Flaw] = field(default_factory=list)
    probe_acked: bool = True
    restarted: bool = False
    traffic: list = field(default_factory=list)  # the TrafficRecords of this replay

    def rules(self) -> set[str]:
        return {f.rule for f in self.flaws}


def vehicle_counts(target: TargetBase) -> dict[str, int]:
    v = target.vehicle
    return dict(v.probe_tokens()) if v is not None else {}


def settle_vehicle(target: TargetBase, ledger: DeliveryLedger | None, tag: str) -> bool:
    """Send a sentinel passthrough and wait for it to reach the vehicle: every frame sent
    before it has then arrived (a node forwards in order). False when it never came."""
    v = target.vehicle
    if v is None:
        return False
    drv = target.driver
    # from a source of its own first: the manager's numbering may be what the node gets wrong
    # (a node that takes a wrapped seq for a duplicate drops the second sentinel), so the first
    # has the whole wait: on a loaded host its forward can take over a second
    for src, wait in ((SENTINEL_SRC, SENTINEL_WAIT), (drv.our_id, SENTINEL_WAIT / 2)):
        token = f"sent{tag}{time.monotonic_ns() % 10**9}"
        sent = drv.send(Action.MAV_PASSTHROUGH, make_probe(token), target.node_id, src=src)
        if ledger is not None:
            ledger.sent(-1, Input.of(sent.data), None)
        drv.exchange(sent, rto=max(target.rto, 0.5), copies=2)
        if v.wait_for(lambda t=token: v.probe_count(t) >= 1, wait):
            return True
    return False


def run_sequence(target: TargetBase, datagrams: Sequence[bytes], *, pace: str = "batch",
                 fresh: bool = True, monitor: bool = True, scenario: str | None = None) -> Outcome:
    """Send ``datagrams`` to the node (a fresh one when spawned and ``fresh``, started as
    ``scenario`` says; in attach mode the node, once its liveness probe is ACKed, else
    ``TargetLost``), then judge."""
    out = Outcome()
    if (scenario is not None and scenario.startswith(WITHHOLD) and target.spawned
            and isinstance(target, FuzzTarget)):  # a drone's startup: the drone role's
        copies = int(scenario[len(WITHHOLD):])
        w = target.restart_withholding(copies)
        out.restarted = True
        flaw = judge_withheld(w.copies, w.after_wrong_ack, copies, target.alive())
        if flaw is not None:
            out.flaws.append(flaw)
    elif fresh and target.spawned:
        target.restart(REPLAY)
        out.restarted = True
    elif not target.alive():
        return Outcome([Flaw("MCP-ROB-5", "a live node", "the node is not running")], False)
    else:
        # attach mode: the same node every time, so it must be proven live before the
        # input, or what follows is the silence of a dead node (issue 19 item 1)
        target.check_live("before a replay")
    drv = target.driver
    target.wait_quiet(gap=0.05, limit=0.5)
    target.traffic.drain()
    mon = MonitorOracle(target.node_id, target.rto, target.ack_window, target.broadcast_id,
                        drv.listen) if monitor else None
    ledger = DeliveryLedger(target.node_id, target.broadcast_id)
    inputs = [Input.of(d) for d in datagrams]
    before = vehicle_counts(target)  # the vehicle outlives restarts: count only this replay's
    mark = drv.mark()
    for i, (data, inp) in enumerate(zip(datagrams, inputs, strict=True)):
        sent = drv.send_raw(data)
        ledger.sent(i, inp, frame_token(data) if inp.header and inp.header[3] == Action.MAV_PASSTHROUGH else None)
        m = inp.msg
        if pace == "paced" and m is not None and m.action != _ACK and m.dst == target.node_id:
            drv.wait_for(drv.ack_for(sent), max(target.rto, 0.5), mark)
    probe = target.probe()
    ledger.sent(len(inputs), Input.of(probe.sent.data), None)
    out.probe_acked = probe.acked
    judged = judge_exchange(inputs, target, mark, probe)
    out.flaws += judged
    dead = any(f.source in ("liveness", "process") for f in judged)
    if not dead and target.vehicle is not None and ledger.expected:
        settled = settle_vehicle(target, ledger, "r")
        after = vehicle_counts(target)
        out.flaws += ledger.judge({k: n - before.get(k, 0) for k, n in after.items()}, settled=settled)
    out.traffic = target.traffic.drain()
    if mon is not None:
        out.flaws += mon.feed(out.traffic)
        out.flaws += mon.advance(time.time_ns())
    return out

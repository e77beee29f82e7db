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

__all__ = ["WITHHOLD", "Outcome", "frame_token", "run_sequence", "settled_count"]

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


def settled_count(target: TargetBase, token: str, before: int = 0) -> int:
    """The vehicle's count of ``token``'s frame (less ``before``) once the node's forwards of
    it have settled, as MCP-DUP-1's conformance case takes its baseline before a copy
    (``CaseContext.settle``, then ``quiet_count``): the frame arrived (within
    max(2 x ack window, 1 s, rto)), then the count unchanged for half the ACK window (at most
    one ACK window). Nothing is sent meanwhile: the node sees the copy right after its
    original, as the case sends it."""
    v = target.vehicle
    assert v is not None
    v.wait_for(lambda: v.probe_count(token) > before, max(2 * target.ack_window, 1.0, target.rto))
    stable = max(target.ack_window / 2, 0.1)
    deadline = time.monotonic() + max(target.ack_window, 2 * stable)
    count, since = v.probe_count(token), time.monotonic()
    while time.monotonic() < deadline:
        time.sleep(0.02)
        now_count = v.probe_count(token)
        if now_count != count:
            count, since = now_count, time.monotonic()
        elif time.monotonic() - since >= stable:
            break
    return count - before


def run_sequence(target: TargetBase, datagrams: Sequence[bytes], *, pace: str = "batch",
                 fresh: bool = True, monitor: bool = True, scenario: str | None = None) -> Outcome:
    """Send ``datagrams`` to the node (a fresh one when spawned and ``fresh``, started as
    ``scenario`` says; in attach mode the node, once its liveness probe is ACKed, else
    ``TargetLost``), then judge. With the vehicle, a copy of the message last delivered from
    its src carrying a frame is sent once its original's forwards have settled
    (``settled_count``): whether the copy added a delivery (MCP-DUP-1) or the original was
    forwarded twice (MCP-PAY-8) is then told apart (``fuzz.delivery``)."""
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
        token = frame_token(data) if inp.header and inp.header[3] == Action.MAV_PASSTHROUGH else None
        base = None
        if token is not None and target.vehicle is not None and ledger.repeats_last(inp, token):
            # a copy to be discarded: its original's forwards settled first (MCP-DUP-1 vs PAY-8)
            base = settled_count(target, token, before.get(token, 0))
        sent = drv.send_raw(data)
        ledger.sent(i, inp, token, base=base)
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

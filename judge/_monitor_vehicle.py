"""Autopilot-link rules of the trace monitor, and the conversions that feed them.

A drone's MAVLink link shows what MCP cannot: when it arms (MCP-BLK-4), whether its
autopilot had a GPS fix when it said Mission_Ready (MCP-BLK-5), whether it commanded RTL
after End_Mission (MCP-BLK-7), and which Mav_Passthrough frames it delivered (written to
the autopilot): once per delivered message (MCP-PAY-8), not again for a duplicate
(MCP-DUP-1), again for a new number with the same bytes (MCP-DUP-2), per source
(MCP-DUP-3), across the wrap (MCP-SEQ-3), and never for a message to another ID
(MCP-ACK-5, "neither ACKs nor acts on").

A Mav_Passthrough frame that reaches the autopilot altered (truncated, corrupted) is not
"forwarded ... exactly once" (MCP-PAY-8: "A drone linked to an autopilot forwards each
delivered Mav_Passthrough frame to it exactly once."): when an ACKed one never arrives
intact but bytes that did not parse and are an altered form of it (:func:`alteration`)
were written meanwhile, MCP-PAY-8 is violated, with the frame sent and what arrived.

Feed it :class:`VehicleEvent` records: :func:`events_from_mavlink` turns one raw MAVLink
frame (as a capture's ``/mavlink`` channel or the simulated vehicle's frame tap holds it,
bytes that did not parse included) into them; :func:`events_from_vehicle` turns the
simulated vehicle's own event records. The link is taken as complete for a drone once any
event was fed for it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from mcp_conform.judge._monitor_base import (
    HDR,
    MANAGER,
    NS,
    PASSTHROUGH,
    VehicleEvent,
    _Exchange,
    _Node,
    fmt_s,
    late_ack_wait_ns,
)
from mcp_conform.spec.mavframe import FrameError, is_frame, parse_frame
from mcp_conform.vehicle.probe import probe_token
from mcp_conform.vehicle.records import COPTER_MODE_NAMES, RTL, mode_name

if TYPE_CHECKING:
    from mcp_conform.judge._monitor_host import MonitorHost
else:
    MonitorHost = object  # the host's state, declared for the type checker only

_ARM_DISARM = 400  # MAV_CMD_COMPONENT_ARM_DISARM
_DO_SET_MODE = 176  # MAV_CMD_DO_SET_MODE
_RETURN_TO_LAUNCH = 20  # MAV_CMD_NAV_RETURN_TO_LAUNCH
_TAKEOFF = 22  # MAV_CMD_NAV_TAKEOFF
_FIX_MIN = 2  # GPS_RAW_INT fix_type below 2: no fix (MCP-BLK-5)
_RTL_NAME = COPTER_MODE_NAMES[RTL]
#: Allowance between the clocks of the MCP trace and of the autopilot link (two clocks of
#: one host in the runner; a forwarded frame cannot precede its message by more).
_CLOCKS_NS = 5_000_000


def _key(frame: bytes) -> Any:
    """How a forwarded frame is recognised: its probe token (a drone may re-encode a probe
    as MAVLink v1), else its exact bytes."""
    try:
        msg = parse_frame(frame)
    except FrameError:
        return frame
    if msg.get_type() == "STATUSTEXT":
        token = probe_token(msg.text)
        if token is not None:
            return token
    return frame


def alteration(sent: bytes, got: bytes) -> str | None:
    """How ``got`` differs from the frame ``sent`` when it is an altered form of it (MCP-PAY-8):
    cut short (at least its header left), bytes changed, or a changed prefix or suffix with
    at least half of the frame as sent; ``None`` for the same bytes or unrelated ones."""
    sent, got = bytes(sent), bytes(got)
    if not sent or not got or got == sent:
        return None
    n = min(len(sent), len(got))
    p = next((i for i in range(n) if sent[i] != got[i]), n)
    s = next((i for i in range(n - p) if sent[-1 - i] != got[-1 - i]), n - p)
    header = 6 if sent[0] == 0xFE else 10
    if p == len(got):  # a prefix of the frame
        return f"truncated to {len(got)} of {len(sent)} bytes" if len(got) >= header else None
    if p + s < max(len(sent) // 2, header):
        return None
    if len(got) == len(sent):
        k = sum(a != b for a, b in zip(sent, got, strict=True))
        return f"{k} of {len(sent)} bytes differ (the first at offset {p})"
    return f"{len(got)} bytes instead of {len(sent)}: the first {p} and the last {s} as sent"


def events_from_mavlink(raw: bytes, direction: str = "rx") -> list[VehicleEvent]:
    """The events one MAVLink frame shows. ``direction`` is ``"rx"`` for a frame the drone
    wrote to its autopilot, ``"tx"`` for one the autopilot sent to the drone. Bytes the drone
    wrote that are no valid frame, and a frame of an unknown message id, are ``unparsed``."""
    try:
        msg = parse_frame(bytes(raw))
    except FrameError as exc:
        return [VehicleEvent("unparsed", frame=bytes(raw), detail=str(exc))] if direction == "rx" else []
    kind = msg.get_type()
    if direction == "tx":
        if kind == "GPS_RAW_INT":
            return [VehicleEvent("fix" if msg.fix_type >= _FIX_MIN else "fix_lost",
                                 detail=f"fix_type {msg.fix_type}")]
        return []
    token = probe_token(msg.text) if kind == "STATUSTEXT" else None
    out = [VehicleEvent("frame", frame=bytes(raw), token=token, detail=kind)]
    if kind.startswith("UNKNOWN_"):
        out.append(VehicleEvent("unparsed", frame=bytes(raw), detail=f"unknown message id {kind[8:]}"))
    if kind in ("COMMAND_LONG", "COMMAND_INT"):
        cmd = int(msg.command)
        if cmd == _ARM_DISARM:
            out.append(VehicleEvent("arm" if msg.param1 == 1 else "disarm", detail=kind))
        elif cmd == _DO_SET_MODE:
            out.extend(_mode(int(msg.param2), kind))
        elif cmd == _RETURN_TO_LAUNCH:
            out.append(VehicleEvent("rtl", detail="MAV_CMD_NAV_RETURN_TO_LAUNCH"))
        elif cmd == _TAKEOFF:
            out.append(VehicleEvent("takeoff", detail=kind))
    elif kind == "SET_MODE":
        out.extend(_mode(int(msg.custom_mode), kind))
    return out


def _mode(custom: int, via: str) -> list[VehicleEvent]:
    name = mode_name(custom)
    out = [VehicleEvent("mode", mode=name, detail=via)]
    if name == _RTL_NAME:
        out.append(VehicleEvent("rtl", mode=name, detail=via))
    return out


def frame_hex(data: bytes, limit: int = 300) -> str:
    """``data`` as hex with its length (cut after ``limit`` bytes)."""
    h = bytes(data[:limit]).hex(" ")
    return f"{h}{' ...' if len(data) > limit else ''} ({len(data)} bytes)"


def events_from_vehicle(event: Any) -> list[VehicleEvent]:
    """The monitor's events for one ``vehicle.records.Event`` of the simulated vehicle
    (requests with their results; frames come through :func:`events_from_mavlink`)."""
    kind, d = event.kind, event.detail
    if kind == "connect":
        return [VehicleEvent("link", detail=str(d.get("peer", "")))]
    if kind in ("fix", "fix_lost"):
        return [VehicleEvent(kind)]
    if kind == "command":
        cmd, params, ok = d.get("command"), d.get("params") or (0.0,) * 7, d.get("result") == 0
        if cmd == _ARM_DISARM:
            return [VehicleEvent("arm" if params[0] == 1 else "disarm", ok=ok, detail=str(d.get("name")))]
        if cmd == _TAKEOFF:
            return [VehicleEvent("takeoff", ok=ok)]
        return []
    if kind == "rtl":
        return [VehicleEvent("rtl", ok=bool(d.get("accepted")), detail=str(d.get("via", "")))]
    if kind == "mode":
        return [VehicleEvent("mode", mode=str(d.get("mode")), detail=str(d.get("via", "")))]
    if kind in ("busy", "idle"):
        return [VehicleEvent(kind, detail=str(d.get("action") or ""))]
    return []


class VehicleRules(MonitorHost):
    """Mixin of :class:`judge.monitor.Monitor`: autopilot-link judgement."""

    def _delivery_wait(self) -> int:
        """How long a delivered frame may take to reach the autopilot (a node may queue it
        behind slow work such as a takeoff)."""
        return late_ack_wait_ns(self.rto_ns, self.window_ns)

    def _quiet_ns(self) -> int:
        """How long a frame's count on the link must stand still before a copy sent after it is
        a copy of a delivery whose writes are done: the case's (``conformance.drone_case``'s
        ``quiet_count``, half the ACK window, at least 0.1 s)."""
        return max(self.window_ns // 2, NS // 10)

    def _vehicle_event(self, t: int, drone: int, ev: VehicleEvent) -> None:
        node = self._node(drone)
        node.vehicle = True
        kind = ev.kind
        if kind == "link":
            if node.fix is None:
                node.fix = False
        elif kind == "fix":
            node.fix = True
        elif kind == "fix_lost":
            node.fix = False
        elif kind == "arm":
            self._judge_arm(node, t, ev)
        elif kind == "rtl" or (kind == "mode" and ev.mode == _RTL_NAME):
            node.forwards.append((t, "RTL"))
            if node.end is not None and node.end.acks and self._complete_for(node.id):
                self._observe(node.id, "MCP-BLK-7")  # the RTL after End_Mission: judged, not awaited
        elif kind == "frame" and ev.frame is not None:
            self._judge_forward(node, t, ev.token if ev.token is not None else ev.frame)
        elif kind == "unparsed" and ev.frame is not None:
            node.unparsed.append((t, ev.frame, ev.detail))
        elif kind == "busy":
            node.busy = ev.detail or "an earlier command"
        elif kind == "idle" and node.busy is not None:
            node.busy, node.busy_end = None, t

    def _check_ready_fix(self, node: _Node, i: int, t: int) -> None:
        """MCP-BLK-5: no Mission_Ready while the autopilot reports no GPS fix."""
        if not node.vehicle or node.fix is None:
            return
        self._observe(node.id, "MCP-BLK-5")
        if node.fix is False:
            self._emit("MCP-BLK-5", node.id, t, "no Mission_Ready while the autopilot reports no GPS fix",
                       f"Mission_Ready (datagram #{i}) while the autopilot reports no fix", [(i, t)])

    def _judge_arm(self, node: _Node, t: int, ev: VehicleEvent) -> None:
        """MCP-BLK-4 (complete trace): no ARM before Start_Mission reached the drone."""
        if not self._complete_for(node.id) or node.id == MANAGER:
            return
        self._observe(node.id, "MCP-BLK-4")
        start = node.start
        if start is None or start.first[1] > t:
            res = "" if ev.ok is None else (" (accepted)" if ev.ok else " (refused)")
            self._emit("MCP-BLK-4", node.id, t, "no ARM on the autopilot before Start_Mission",
                       f"ARM requested{res} before any Start_Mission to drone {node.id}",
                       [node.ready] if node.ready is not None else [])

    # ------------------------------------------------------------------ passthrough
    def _passthrough_key(self, ex: _Exchange) -> Any:
        return _key(ex.payload)

    def _judge_forward(self, node: _Node, t: int, key: Any) -> None:
        """A frame the drone wrote to its autopilot: which message it delivers."""
        if not self._complete_for(node.id):
            return  # a lossy trace may miss another message with the same frame
        cands = [ex for ex in self._pt.get(key, ()) if ex.first[1] <= t + _CLOCKS_NS]
        mine = [ex for ex in cands if ex.dst == node.id]
        if not mine:
            others = [ex for ex in cands if not ex.bcast and ex.dst != node.id
                      and t - ex.last_t <= self._delivery_wait()]
            if others:
                ex = others[-1]
                self._emit("MCP-ACK-5", node.id, t, "a message addressed to another ID is not acted on",
                           f"the frame of {ex.describe()} reached drone {node.id}'s autopilot",
                           [ex.copies[-1]])
            return
        waiting = [ex for ex in mine if not ex.deliveries]  # frames are forwarded in order
        ex = waiting[0] if waiting else mine[-1]
        if not ex.deliveries:
            self._delivered_observations(node, ex)
        seen = sum(1 for c in ex.copies if c[1] <= t)
        self._node_delivers.add(node.id)
        ex.deliveries = (*ex.deliveries, (t, seen))
        self._observe(node.id, "MCP-PAY-8")
        last = node.delivered_from.get(ex.src)
        node.delivered_from[ex.src] = ex
        if len(ex.deliveries) < 2:
            return
        prev_t, prev_seen = ex.deliveries[-2]
        if seen > prev_seen and ex.copies[prev_seen][1] - prev_t < self._quiet_ns():
            # the copy left while the earlier delivery's writes were still coming: this write
            # may be the earlier delivery's second (MCP-PAY-8) or the copy's delivery (MCP-DUP-1)
            # -- every explanation breaks one, neither rule in all, so neither is reported (as
            # D-9 for ACKs); the case sends its copy only once the count has stopped moving
            # (``conformance.drone_case``'s ``redeliver``)
            return
        if seen > prev_seen and last is not ex:
            # a late copy of an older message, not the last delivered: not specified (MCP-DUP-4)
            self._observe(node.id, "MCP-DUP-4")
        elif seen > prev_seen:
            self._emit("MCP-DUP-1", node.id, t, "a duplicate is ACKed but not delivered again",
                       f"{ex.describe()} delivered again after copy {seen}", ex.copies[:seen])
        else:
            self._emit("MCP-PAY-8", node.id, t, "each delivered frame forwarded exactly once",
                       f"the frame of {ex.describe()} written {len(ex.deliveries)} times "
                       f"for {seen} cop{'y' if seen == 1 else 'ies'}", ex.copies[:seen])

    def _delivered_observations(self, node: _Node, ex: _Exchange) -> None:
        """A first delivery shows the rules whose condition it meets observed."""
        prior = [p for p in self._pt_to.get(node.id, ()) if p is not ex and p.deliveries
                 and p.first[1] < ex.first[1]]
        same = [p for p in prior if p.src == ex.src]
        if same and same[-1].data[HDR:] == ex.data[HDR:]:
            node.seen.add("MCP-DUP-2")
        if same and same[-1].seq > ex.seq:
            node.seen.add("MCP-SEQ-3")
        if any(p.src != ex.src and p.seq == ex.seq for p in prior):
            node.seen.add("MCP-DUP-3")

    def _passthrough_acked(self, ex: _Exchange, node: _Node, t: int) -> None:
        """A Mav_Passthrough the drone ACKed: it must show on the link, unless a duplicate."""
        if node.vehicle and ex.action == PASSTHROUGH and self._complete_for(node.id):
            self._timers.at(t + self._delivery_wait(), self._delivery_deadline, ex, node)

    def _delivery_deadline(self, now: int, ex: _Exchange, node: _Node) -> None:
        due = ex.acks[-1][1] + self._delivery_wait()
        if now < due:  # ACKed again since: it may have been received late
            self._timers.at(due, self._delivery_deadline, ex, node)
            return
        if not ex.deliveries and self._judge_altered(now, ex, node):
            return
        if ex.deliveries or node.id not in self._node_delivers:
            return  # delivered, or a drone that does not forward passthrough at all
        prior = [p for p in self._pt_to.get(node.id, ()) if p is not ex and p.first[1] < ex.first[1]
                 and p.deliveries]
        if not prior:
            return
        same_src = [p for p in prior if p.src == ex.src]
        other_src = [p for p in self._pt_to.get(node.id, ()) if p.src != ex.src and p.seq == ex.seq
                     and p.first[1] < ex.first[1]]
        if other_src:
            rule, why = "MCP-DUP-3", f"same seq as {other_src[-1].describe()}, another src"
            ev = other_src[-1]
        elif same_src and same_src[-1].data[17:] == ex.data[17:]:
            rule, why = "MCP-DUP-2", "a new seq with the same bytes as the previous message"
            ev = same_src[-1]
        elif same_src and same_src[-1].seq > ex.seq:
            rule, why = "MCP-SEQ-3", f"after seq {same_src[-1].seq}: the numbers wrapped"
            ev = same_src[-1]
        else:
            return  # not delivered, and nothing in the trace says which rule made it so
        self._observe(node.id, rule)
        self._emit(rule, node.id, now, "a new message is delivered (its frame reaches the autopilot)",
                   f"{ex.describe()} ACKed but not delivered within {fmt_s(self._delivery_wait())} ({why})",
                   [ev.first, ex.first] + ex.acks[:1])

    def _judge_altered(self, now: int, ex: _Exchange, node: _Node) -> bool:
        """MCP-PAY-8: an ACKed passthrough frame never arrived intact, but an altered form of
        it (:func:`alteration`) was written to the autopilot since its first copy."""
        if not is_frame(ex.payload):
            return False  # what the frame should look like is unknown: nothing to compare
        for entry in node.unparsed:
            t, got, why = entry
            if t + _CLOCKS_NS < ex.first[1]:
                continue
            how = alteration(ex.payload, got)
            if how is None:
                continue
            node.unparsed.remove(entry)  # one arrival, one message
            self._observe(node.id, "MCP-PAY-8")
            self._emit("MCP-PAY-8", node.id, now, f"the frame of {ex.describe()} forwarded as sent: "
                       f"{frame_hex(ex.payload)}",
                       f"{frame_hex(got)} arrived instead ({how}; {why})", [ex.first] + ex.acks[:1])
            return True
        return False

    def _track_passthrough(self, ex: _Exchange) -> None:
        key = self._passthrough_key(ex)
        self._pt.setdefault(key, []).append(ex)
        if not ex.bcast:
            self._pt_to.setdefault(ex.dst, []).append(ex)

    def _end_acked(self, ex: _Exchange, node: _Node, t: int) -> None:
        """MCP-BLK-7: after End_Mission the drone commands RTL."""
        if node.vehicle and node.id != MANAGER:
            self._timers.at(t + self._rtl_wait(), self._rtl_deadline, ex, node)

    def _rtl_wait(self) -> int:
        return max(3 * NS, 3 * self.window_ns, 2 * self.rto_ns)

    def _pending_bound(self) -> int:
        """How long past End_Mission's ACK the RTL may wait for the autopilot's pending
        actions: half the runner's per-case limit (``harness.config.RunConfig.per_case_limit``,
        max(60 s, 30 rto + 10 window)), the bound of the case's own wait (one judge)."""
        return max(30 * NS, 15 * self.rto_ns + 5 * self.window_ns)

    def _rtl_due(self, now: int, ex: _Exchange, node: _Node) -> int:
        """MCP-BLK-7's deadline: the RTL window after End_Mission's last ACK, or after the
        end of what the autopilot showed in progress of an earlier command once End_Mission
        was ACKed ("finishes pending actions, then commands RTL"; a take-off climbing, an
        AUTO mission flying: ``busy``/``idle``), never past :meth:`_pending_bound`, as the case
        waits (``conformance.drone_case.await_past_pending``)."""
        wait, acked = self._rtl_wait(), ex.acks[0][1]
        due = ex.acks[-1][1] + wait
        last_busy = now if node.busy is not None else node.busy_end
        if last_busy is not None and last_busy >= acked:
            due = max(due, min(last_busy + wait, acked + self._pending_bound()))
        return due

    def _rtl_deadline(self, now: int, ex: _Exchange, node: _Node) -> None:
        due = self._rtl_due(now, ex, node)
        if now < due:  # ACKed again since (it may have been received late), or the autopilot busy
            self._timers.at(due, self._rtl_deadline, ex, node)
            return
        self._observe(node.id, "MCP-BLK-7")
        since = ex.first[1] if self._complete_for(node.id) else node.last_command_t
        if any(k == "RTL" and ft >= since for ft, k in node.forwards):
            return
        still = f"; {node.busy} still in progress" if node.busy is not None else ""
        self._emit("MCP-BLK-7", node.id, now, "an RTL on the autopilot after End_Mission",
                   f"no RTL within {fmt_s(now - ex.acks[0][1])} of End_Mission's ACK{still}",
                   [ex.first, ex.acks[0]])

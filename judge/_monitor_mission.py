"""Mission rules of the trace monitor that judge the manager's commands against the items it
was handed and against what reaches each drone: MCP-FLOW-4/6 (a list carries the mission's
items), MCP-FLOW-5 (a WP_On one of its waypoints; every waypoint in a WP_On to each drone,
``judge.waypoints``: the manager case's judge too), and D-11's broadcast that goes to every
drone: a further command to one whose Start_Mission awaits its ACK (MCP-BLK-3), a command to one
after its End_Mission (MCP-BLK-6). A mixin of :class:`judge.monitor.Monitor` under
``SenderRules``.
"""

from __future__ import annotations

from mcp_conform.judge._monitor_base import (
    HDR,
    JITTER_NS,
    MANAGER,
    OBSTACLES,
    RTX_TOLERANCE,
    WP_LIST,
    WP_ON,
    _Exchange,
    _Node,
    action_name,
    gaps,
    median,
    pack_item,
)
from mcp_conform.judge._monitor_rtx import RetransmissionRules, _running_gaps
from mcp_conform.judge.waypoints import waypoints_missed

_LIST_FLOW = {WP_LIST: ("MCP-FLOW-4", 1), OBSTACLES: ("MCP-FLOW-6", 3)}


#: The bytes of a packed mission item that hold target_system and target_component
#: ('<fffffffHHBBBBB': 7 floats, seq, command, then the two targets): not in a WPL file.
_TARGETS = slice(32, 34)


def _file_fields(item: bytes) -> bytes:
    """A packed item without its target_system / target_component bytes."""
    return item[:_TARGETS.start] + item[_TARGETS.stop:]


class MissionRules(RetransmissionRules):
    """Mixin of :class:`judge.monitor.Monitor` (through ``SenderRules``)."""

    def _broadcast_to_every_drone(self, ex: _Exchange, i: int, t: int) -> list[_Node]:
        """D-11: the manager's broadcast ``ex`` goes to every drone. MCP-BLK-3 for each drone whose
        Start_Mission awaits its ACK (:meth:`_awaiting_start`; those drones returned: the broadcast
        is a command of their missions too), MCP-BLK-6 for each whose End_Mission was sent."""
        waiting = self._awaiting_start(t)
        for d in waiting:
            s = d.start
            assert s is not None
            self._emit("MCP-BLK-3", MANAGER, t, "no further command to that drone until Start_Mission is ACKed",
                       f"{ex.describe()} (a broadcast: to drone {d.id} too, D-11) sent before its ACK "
                       f"({s.describe()})", [s.copies[-1], (i, t)])
        for d in self._nodes.values():
            if d.end is not None and d.id != MANAGER and not d.end.tester:
                self._emit("MCP-BLK-6", MANAGER, t, f"no command to drone {d.id} after its End_Mission",
                           f"{ex.describe()} (a broadcast: to drone {d.id} too, D-11)", [d.end.first, (i, t)])
        return waiting

    def _awaiting_start(self, t: int) -> list[_Node]:
        """D-11 and MCP-BLK-3 (complete trace): the drones whose Start_Mission awaits its ACK at
        ``t`` -- sent, not answered before ``t`` (no ACK, nor one the manager may have taken for
        it: ``_on_mission``'s), its next copy not yet overdue (a manager that gave it up at its
        timer, its retry limit, has moved on: MCP-RTX-1's business, ``_check_stop_and_wait``'s
        rule for a unicast). A broadcast then is a further command to that drone before the ACK
        ("does not send any subsequent MCP commands until an acknowledgement is received"),
        and a command of its mission (its list, its WP_On: counted once, under MCP-BLK-3)."""
        out = []
        for d in self._nodes.values():
            s = d.start
            if s is None or s.tester or s.bcast or d.end is not None or d.id == MANAGER:
                continue
            if not self._complete_for(MANAGER, d.id):
                continue
            answer = s.acks[0] if s.acks else self._taken_ack(s)
            if answer is not None:
                if answer[1] >= t:  # the ACK is stamped before it leaves (D-11)
                    out.append(d)
                continue
            est = median(_running_gaps(s)) if gaps(s.copies) else self.rto_ns
            if t - s.last_t < est * (1 - RTX_TOLERANCE) - JITTER_NS:
                out.append(d)
        return out

    def _judge_every_waypoint(self, d: _Node, ex: _Exchange, i: int, t: int) -> None:
        """MCP-FLOW-5 (complete trace), at ``d``'s End_Mission: every waypoint of the mission in a
        WP_On to ``d`` (unicast, or broadcast while its mission was on, D-11) -- the manager case's
        judge (``judge.waypoints``). Not judged where a WP_On to it could not be decoded
        (MCP-PAY-5's), or where the manager moved on from a command to it that was never answered
        (it may have given the drone up: its retry limit, MCP-RTX-1's business)."""
        if self.waypoints is None or d.start is None or not self._complete_for(MANAGER, d.id):
            return
        last = d.last_command
        if any(not c.acks and self._taken_ack(c) is None
               for c in (*d.unanswered, *((last,) if last is not None and last is not ex else ()))):
            return
        self._observe(MANAGER, "MCP-FLOW-5")
        missed = waypoints_missed(d.wp_items, self.waypoints)
        if missed:
            self._emit("MCP-FLOW-5", MANAGER, t, f"every waypoint of the mission in a WP_On to drone {d.id}",
                       f"End_Mission to drone {d.id} with {len(missed)} of {len(self.waypoints)} waypoints "
                       f"in no WP_On to it (first: item {missed[0].seq})", [d.start.first, (i, t)])

    def _judge_items(self, ex: _Exchange, i: int, t: int) -> None:
        """MCP-FLOW-4/6: a list carries the mission's items; MCP-FLOW-5: a WP_On one of them."""
        challenge = self.challenge or self.inferred_challenge
        if ex.action == WP_ON:
            if challenge == 2 and self.waypoints is not None and not self._carries_waypoints(ex):
                self._emit("MCP-FLOW-5", MANAGER, t, "WP_On carries one of the mission's waypoints",
                           f"{ex.describe()} carries item {ex.payload.seq}, not a mission waypoint", [(i, t)])
            return
        rule, number = _LIST_FLOW[ex.action]
        if challenge == number and not self._carries_waypoints(ex):
            self._emit(rule, MANAGER, t, f"{action_name(ex.action)} carries the mission's {len(self.waypoints or ())} "
                       "items", f"{ex.describe()} carries {len(ex.payload)} other item(s)", [(i, t)])

    def _carries_waypoints(self, ex: _Exchange) -> bool:
        """Does the command carry the mission's items: every field a QGC WPL 110 line holds,
        in the file's order (a WP_On: one of them)? target_system and target_component are
        not in the file, so a manager fills them as it likes: they are not compared."""
        if self.waypoints is None:
            return True
        if self._packed_waypoints is None:  # as on the wire (float32), in the file's order
            self._packed_waypoints = [_file_fields(pack_item(*w)) for w in self.waypoints]
            self._waypoint_set = frozenset(self._packed_waypoints)
        payload = ex.data[HDR:]
        if ex.action == WP_ON:
            return _file_fields(payload) in self._waypoint_set
        size = len(payload[2:]) // max(1, len(ex.payload)) if ex.payload else 0
        got = [_file_fields(payload[2 + k * size:2 + (k + 1) * size]) for k in range(len(ex.payload))]
        return got == self._packed_waypoints

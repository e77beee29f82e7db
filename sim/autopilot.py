"""The drone model's autopilot client in the simulator (issue 38): what the reference drone's
``reference_impl.autopilot.AutopilotLink`` does on its MAVLink link, sans-I/O -- bytes and
``now`` in (:meth:`AutopilotClient.receive`, :meth:`AutopilotClient.on_timer`), frames and the
next timer out (:meth:`AutopilotClient.take_output`, :meth:`AutopilotClient.timer`) -- so that a
node model of :mod:`sim.models` talks MAVLink to the runner's vehicle (``vehicle.SimVehicle`` on
the session's clock, :mod:`sim.vehicle`) in virtual time.

As the reference's worker: a HEARTBEAT each second (type ONBOARD_CONTROLLER, autopilot
INVALID, as companion computers send; over UDP the vehicle learns the node's address from it);
the telemetry read (HEARTBEAT: the vehicle's IDs, armed, mode; GPS_RAW_INT: the 3D fix
MCP-BLK-5 waits for; GLOBAL_POSITION_INT: home and the climb; the mission protocol's requests;
COMMAND_ACK); the jobs run in order, each wait bounded as there: ``takeoff`` (SET_MODE GUIDED,
MAV_CMD_COMPONENT_ARM_DISARM, MAV_CMD_NAV_TAKEOFF: never before Start_Mission, MCP-BLK-4),
``mission`` (MISSION_COUNT, each requested item -- item 0 home -- until MISSION_ACK: mavlink.io's
mission protocol), ``forward`` (a Mav_Passthrough frame's bytes written once, MCP-PAY-8), ``rtl``
(MAV_CMD_NAV_RETURN_TO_LAUNCH, else SET_MODE RTL: MCP-BLK-7), ``arm`` (the sample node's faults,
:mod:`sim.mutants`) and ``noop``. Every message is built with pymavlink's dialect and packed by
``vehicle.codec.Encoder``; what arrives is read by ``vehicle.codec.Decoder``.

A job is a generator that yields ``(predicate, deadline)`` where the reference waits
(:class:`Steps` drives it, and the node model's own flow the same way).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Generator
from typing import Any

from pymavlink import mavutil

from mcp_conform.vehicle.codec import Decoder, Encoder

__all__ = ["AutopilotClient", "Steps", "Wait"]

_MAV = mavutil.mavlink
HEARTBEAT_PERIOD = 1.0  # reference_impl.autopilot.HEARTBEAT_PERIOD
_GUIDED = {v: k for k, v in mavutil.mode_mapping_acm.items()}["GUIDED"]
_RTL = {v: k for k, v in mavutil.mode_mapping_acm.items()}["RTL"]
FIX_3D = 3  # GPS_FIX_TYPE_3D_FIX
SET_MODE_ID = 11  # ArduPilot acknowledges SET_MODE with COMMAND_ACK command = its msgid

#: What a flow waits for: a predicate, and the (virtual) time it gives up at.
Wait = tuple[Callable[[], bool], float]
Flow = Generator[Wait, bool, Any]


class Steps:
    """Drives one generator flow: it runs until it yields a wait whose predicate is false
    before its deadline; :meth:`advance` re-checks it (after an input, or at the deadline) and
    sends the generator the predicate's value when it goes on."""

    def __init__(self, flow: Flow | None = None) -> None:
        self.flow = flow
        self.wait: Wait | None = None
        self.started = False

    @property
    def done(self) -> bool:
        return self.flow is None

    def deadline(self) -> float:
        return self.wait[1] if self.wait is not None else math.inf

    def advance(self, now: float) -> bool:
        """Run the flow as far as it goes now; True when it ended."""
        while self.flow is not None:
            if not self.started:
                self.started, value = True, False
            else:
                assert self.wait is not None
                pred, until = self.wait
                value = bool(pred())
                if not value and now < until:
                    return False
            try:
                self.wait = self.flow.send(value) if self.wait is not None else next(self.flow)
            except StopIteration:
                self.flow, self.wait = None, None
                return True
        return True


class AutopilotClient:
    """The reference drone's autopilot link (module docstring); ``addr``: its address;
    ``heartbeat_period`` None: no HEARTBEAT (the sample node's link, :mod:`sim.mutants`)."""

    def __init__(self, addr: tuple[str, int], *, sysid: int = 255, compid: int = 191,
                 step_timeout: float = 3.0, settle_timeout: float = 2.0,
                 heartbeat_period: float | None = HEARTBEAT_PERIOD) -> None:
        self.addr = addr
        self.heartbeat_period = heartbeat_period
        self.step_timeout, self.settle_timeout = step_timeout, settle_timeout
        self._mav = _MAV.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        self._enc = Encoder(sysid, compid)
        self._dec = Decoder()
        self._out: list[bytes] = []
        self.now = 0.0
        self.heartbeat = False
        self.fix = False
        self.armed = False
        self.arm_accepted = False
        self.custom_mode: int | None = None
        self.rel_alt = 0.0
        self.target_alt: float | None = None
        self.position: tuple[int, int, float] = (0, 0, 0.0)
        self.acks: dict[int, int] = {}
        self.mission_msgs: deque[Any] = deque(maxlen=64)
        self.mission_result: int | None = None
        self.forwarded = 0
        self.rtl_sent = False
        self.takeoff_sent = False
        self._sys, self._comp = 1, 1
        self._jobs: deque[tuple[str, Any]] = deque()
        self._job = Steps()
        self._next_heartbeat = 0.0 if heartbeat_period is not None else math.inf

    # ------------------------------------------------------------------ the model's side
    def start(self, now: float) -> None:
        self._run(now)

    def receive(self, data: bytes, now: float) -> None:
        msgs, _, _ = self._dec.feed(data, now)
        for msg in msgs:
            self._observe(msg)
        self._run(now)

    def timer(self) -> float:
        return min(self._next_heartbeat, self._job.deadline())

    def on_timer(self, now: float) -> None:
        self._run(now)

    def submit(self, kind: str, arg: Any, now: float) -> None:
        """Queue a job (``takeoff`` alt, ``mission`` items, ``forward`` frame, ``rtl``, ``arm``,
        ``noop``)."""
        self._jobs.append((kind, arg))
        self._run(now)

    def idle(self) -> bool:
        """Every job queued so far is done (the reference's ``noop`` job's done event)."""
        return self._job.done and not self._jobs

    def take_output(self) -> list[bytes]:
        """What goes to the vehicle now, one datagram each."""
        out, self._out = self._out, []
        return out

    # ------------------------------------------------------------------ the worker
    def _run(self, now: float) -> None:
        self.now = now
        if now >= self._next_heartbeat:
            self._next_heartbeat = now + (self.heartbeat_period or math.inf)
            self._send(self._mav.heartbeat_encode(_MAV.MAV_TYPE_ONBOARD_CONTROLLER, _MAV.MAV_AUTOPILOT_INVALID,
                                                  0, 0, _MAV.MAV_STATE_ACTIVE))
        while True:
            if not self._job.advance(now):
                return
            if not self._jobs:
                return
            kind, arg = self._jobs.popleft()
            self._job = Steps(getattr(self, "_job_" + kind)(arg))

    def _send(self, msg: Any) -> None:
        self._out.append(self._enc.encode(msg))

    def write(self, frame: bytes) -> None:
        """Raw bytes to the vehicle (pymavlink's ``conn.write``)."""
        self._out.append(bytes(frame))

    def _observe(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            if msg.type == _MAV.MAV_TYPE_GCS or msg.autopilot == _MAV.MAV_AUTOPILOT_INVALID:
                return
            self._sys, self._comp = msg.get_srcSystem(), msg.get_srcComponent()
            self.armed = bool(msg.base_mode & _MAV.MAV_MODE_FLAG_SAFETY_ARMED)
            self.custom_mode = msg.custom_mode
            self.heartbeat = True
        elif kind == "GPS_RAW_INT":
            if int(msg.fix_type) >= FIX_3D:
                self.fix = True
        elif kind == "GLOBAL_POSITION_INT":
            self.rel_alt = msg.relative_alt / 1000.0
            self.position = (msg.lat, msg.lon, msg.alt / 1000.0 - self.rel_alt)
            if self.target_alt is not None and self.rel_alt >= 0.95 * self.target_alt:
                self.target_alt = None
        elif kind in ("MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"):
            self.mission_msgs.append(msg)
        elif kind == "COMMAND_ACK":
            self.acks[int(msg.command)] = int(msg.result)

    def _until(self, pred: Callable[[], bool], timeout: float) -> Flow:
        return (yield (pred, self.now + timeout))

    def _command(self, command: int, *params: float) -> Flow:
        """COMMAND_LONG, resent once a second until COMMAND_ACK (bounded); True if accepted."""
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        for _ in range(max(1, int(self.step_timeout))):
            self.acks.pop(command, None)
            self._send(self._mav.command_long_encode(self._sys, self._comp, command, 0, *p))
            if (yield from self._until(lambda: command in self.acks, 1.0)):
                return self.acks[command] == _MAV.MAV_RESULT_ACCEPTED
        return False

    def _set_mode(self, custom: int) -> Flow:
        for _ in range(max(1, int(self.step_timeout))):
            self.acks.pop(SET_MODE_ID, None)
            self._send(self._mav.set_mode_encode(self._sys, _MAV.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, custom))
            if (yield from self._until(lambda: SET_MODE_ID in self.acks or self.custom_mode == custom, 1.0)):
                return self.custom_mode == custom or self.acks.get(SET_MODE_ID) == _MAV.MAV_RESULT_ACCEPTED
        return False

    # ------------------------------------------------------------------ jobs
    def _job_noop(self, _arg: Any) -> Flow:
        return
        yield  # a generator

    def _job_arm(self, _arg: Any) -> Flow:
        ok = yield from self._command(_MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)
        self.arm_accepted = self.arm_accepted or ok
        return ok

    def _job_takeoff(self, alt: float) -> Flow:
        """Start_Mission: GUIDED, arm (MCP-BLK-4 allows it now), take off to ``alt``."""
        if self.takeoff_sent:
            return
        yield from self._set_mode(_GUIDED)
        for _ in range(3):
            if (yield from self._command(_MAV.MAV_CMD_COMPONENT_ARM_DISARM, 1.0)):
                break
            yield from self._until(lambda: False, 0.5)
        else:
            return
        self.armed = self.arm_accepted = True
        self.takeoff_sent = True
        if (yield from self._command(_MAV.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt)):
            self.target_alt = alt

    def _mission_item(self, seq: int, wp: Any) -> None:
        if math.isfinite(wp.x) and math.isfinite(wp.y) and abs(wp.x) <= 90 and abs(wp.y) <= 180:
            self._send(self._mav.mission_item_int_encode(
                self._sys, self._comp, seq, wp.frame, wp.command, 0, 1, wp.param1, wp.param2, wp.param3,
                wp.param4, int(round(wp.x * 1e7)), int(round(wp.y * 1e7)), wp.z))
        else:
            self._send(self._mav.mission_item_encode(
                self._sys, self._comp, seq, wp.frame, wp.command, 0, 1, wp.param1, wp.param2, wp.param3,
                wp.param4, wp.x, wp.y, wp.z))

    def _job_mission(self, waypoints: tuple[Any, ...]) -> Flow:
        """WP_List: the waypoints as the vehicle's mission (item 0 home), with the handshake."""
        lat, lon, alt = self.position
        self.mission_msgs.clear()
        self._send(self._mav.mission_count_encode(self._sys, self._comp, len(waypoints) + 1))
        while True:
            if not (yield from self._until(lambda: bool(self.mission_msgs), self.step_timeout)):
                return
            m = self.mission_msgs.popleft()
            if m.get_type() == "MISSION_ACK":
                self.mission_result = int(m.type)
                return
            if m.seq == 0:
                self._send(self._mav.mission_item_int_encode(
                    self._sys, self._comp, 0, _MAV.MAV_FRAME_GLOBAL, _MAV.MAV_CMD_NAV_WAYPOINT, 0, 1,
                    0, 0, 0, 0, lat, lon, alt))
            elif m.seq <= len(waypoints):
                self._mission_item(m.seq, waypoints[m.seq - 1])

    def _job_forward(self, frame: bytes) -> Flow:
        """Mav_Passthrough: the frame's bytes written to the vehicle once (MCP-PAY-8)."""
        self.write(frame)
        self.forwarded += 1
        return
        yield  # a generator

    def _job_rtl(self, _arg: Any) -> Flow:
        """End_Mission: a climb in progress finishes (bounded), then RTL (MCP-BLK-7)."""
        if self.target_alt is not None:
            yield from self._until(lambda: self.target_alt is None, self.settle_timeout)
        self.rtl_sent = True
        if not (yield from self._command(_MAV.MAV_CMD_NAV_RETURN_TO_LAUNCH)):
            yield from self._set_mode(_RTL)

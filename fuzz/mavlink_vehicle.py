"""The vehicle under ``mcp-fuzz --protocol mavlink`` (issue 39 item 4).

A :class:`MavVehicle` is one vehicle process (spawned with ``--spawn CMD``, ``{target_host}``
``{target_port}`` and ``{mavlink}`` -- ``tcp:HOST:PORT`` -- filled in; the reference vehicle,
``mcp-vehicle``, when neither ``--spawn`` nor ``--target`` is given) or one reached at
``--target tcp:HOST:PORT``, and the fuzzer's TCP link to it, read synchronously: the fuzzer is
its ground station (system 255, MAV_COMP_ID_MISSIONPLANNER, a HEARTBEAT a second: MAV-HB-2).
The process, its end, the link read synchronously, the fuzzer's own keep-alive, the case
runner and the worker's spare are the shared core's (``fuzz.target_core``: ``LinkedTarget``,
``SyncLink.exchange``, ``SpareTarget``); MAVLink declares its framing
(``harness.mavlink_session.MavlinkFraming``), its ``{mavlink}`` placeholder, its beat (the
vehicle's HEARTBEAT, bounded by MAV-HB-1) and its probe.

Each case (``fuzz.mavlink_cases.Case``) is written with the probe right behind it: a
PARAM_REQUEST_READ by name of a parameter no case touches, which the vehicle answers with a
PARAM_VALUE of that name (MAV-PRM-4). A vehicle handles a link's frames in order, so the
frames before the probe's answer are the case's answers, and the oracles judge them:

- the probe is not answered within ``param_reply_max_s``: the vehicle died (the process
  exited, or closed the link: ``crash``), its HEARTBEAT stopped for ``heartbeat_gap_max_s``
  (``hang``, MAV-HB-1's bound), or it beats on but no longer answers (``unanswered``; MAV-HB-14
  after a malformed frame: "the next good frame is handled"); each named by the case's rule;
- its HEARTBEAT stops while it still answers (``hang``) (``fuzz.mavlink_oracles.lost``);
- an answer the case must get does not come, one it must not get comes, or two final
  COMMAND_ACKs answer one command: ``answer``, named by the expectation's rule
  (``fuzz.mavlink_oracles.judge_case``).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

from mcp_conform.fuzz import mavlink_oracles as oracles
from mcp_conform.fuzz.mavlink_cases import (
    GCS_COMPID,
    GCS_SYSID,
    Case,
    D,
    Expect,
    Vehicle,
    name_key,
    raw_fields,
)
from mcp_conform.fuzz.mavlink_oracles import Hit, Signature
from mcp_conform.fuzz.target_core import LinkedTarget, SpareTarget, SyncLink, TargetSpec
from mcp_conform.harness.errors import SetupError
from mcp_conform.harness.mavlink_session import MavlinkFraming, embedded_command, parse_address
from mcp_conform.spec import MAVLINK

__all__ = ["Hit", "MavTarget", "MavVehicle", "Signature", "VehicleSpec"]

P = MAVLINK.params
REPLY_S = float(P["param_reply_max_s"])
ACK_S = float(P["command_ack_max_s"])
GAP_S = float(P["heartbeat_gap_max_s"])
BEAT_S = float(P["heartbeat_period_s"])
LATE_S = 0.1  # s: an answer missing at the probe's answer, waited for while fuzzing (replays: the spec's bound)
LIST_S = 10.0  # s: the parameter list the cases are built from, read at the start for at most this long


@dataclass(frozen=True)
class VehicleSpec(TargetSpec):
    """How to reach a vehicle (``fuzz.target_core.TargetSpec``): a ``--spawn`` template (or the
    embedded one), or an address, over TCP."""

    @classmethod
    def of(cls, target: tuple[str, int] | None, spawn: str | None) -> VehicleSpec:
        if target is not None:
            transport, address = parse_address(*target)
            if transport != "tcp":
                raise SetupError(f"--target {target[0]}:{target[1]}: the MAVLink fuzzer reaches a vehicle over "
                                 "TCP only so far (tcp:HOST:PORT)")
            return cls(None, address)
        return cls(spawn or embedded_command("tcp"), None)


class MavVehicle(LinkedTarget):
    """One vehicle and the fuzzer's link to it (see the module's docstring): the shared
    core's process and link (``fuzz.target_core.LinkedTarget``), MAVLink's framing on it."""

    subject = "the vehicle"

    def __init__(self, how: VehicleSpec, info: Vehicle | None = None, log: list[Any] | None = None,
                 late: float | None = None) -> None:
        self.how = how
        #: how long an answer missing at the probe's answer is still waited for (None: the
        #: spec's bound, as replays wait; the campaign's own vehicle: a short while, its hits
        #: then confirmed, or not, by replays that wait the whole bound)
        self.late = late
        self.enc = D.MAVLink(None, srcSystem=GCS_SYSID, srcComponent=GCS_COMPID)
        sock = self.open(how, lambda host, port: {"mavlink": f"tcp:{host}:{port}"})
        self.link = SyncLink(sock, MavlinkFraming(), traffic=log,
                             beat=lambda r: r.name == "HEARTBEAT" and self._from_vehicle(r.msg))
        self._beat()
        hb = self._until(lambda f: f.get_type() == "HEARTBEAT", 10.0)
        if hb is None:
            self.close()
            raise SetupError(f"tcp:{self.address[0]}:{self.address[1]}: no HEARTBEAT from the vehicle within 10 s "
                             "(MAV-HB-1)")
        self.frames.clear()
        if info is None:
            info = self._learn(hb.get_srcSystem(), hb.get_srcComponent())
        self.info = info

    def _learn(self, sysid: int, compid: int) -> Vehicle:
        """The vehicle's IDs and parameter list (PARAM_REQUEST_LIST, read for at most LIST_S);
        the probe reads the first parameter of the list."""
        v = Vehicle(sysid, compid)
        self.send(self._pack(D.MAVLink_param_request_list_message(sysid, compid)))
        end, total, seen = time.monotonic() + LIST_S, None, 0
        while time.monotonic() < end and (total is None or len(v.params) < total):
            if self._until(lambda f: f.get_type() == "PARAM_VALUE", min(2.0, end - time.monotonic()), seen) is None:
                break
            for r in self.frames[seen:]:
                f = raw_fields(r.msg) if r.name == "PARAM_VALUE" else None
                if f is not None and f["param_index"] < f["param_count"]:
                    total = f["param_count"]
                    v.params.setdefault(name_key(f["param_id"]), (int(f["param_index"]), int(f["param_type"])))
            seen = len(self.frames)
        self.frames.clear()
        if not v.params:
            self.close()
            raise SetupError("the vehicle sent no PARAM_VALUE for PARAM_REQUEST_LIST within "
                             f"{LIST_S:g} s: the fuzzer has no probe (MAV-PRM-1)")
        v.probe = min(v.params, key=lambda n: v.params[n][0])
        return v

    # -- the link -----------------------------------------------------------------------------
    def _pack(self, msg: Any) -> bytes:
        data = bytes(msg.pack(self.enc))
        self.enc.seq = (self.enc.seq + 1) % 256
        return data

    def _beat(self) -> None:
        """The fuzzer's own HEARTBEAT, as a ground station's, once a second (MAV-HB-2)."""
        self.keepalive(BEAT_S, lambda: self._pack(D.MAVLink_heartbeat_message(
            D.MAV_TYPE_GCS, D.MAV_AUTOPILOT_INVALID, 0, 0, D.MAV_STATE_ACTIVE, 3)))

    def _from_vehicle(self, m: Any) -> bool:
        info = getattr(self, "info", None)
        return info is None or (m.get_srcSystem(), m.get_srcComponent()) == (info.sysid, info.compid)

    def _until(self, pred: Any, timeout: float, start: int = 0) -> Any:
        """The first message from ``start`` on that ``pred`` holds for, read for up to
        ``timeout`` s (None: none came, or the link closed)."""
        r = self.link.until(lambda r: pred(r.msg), timeout, start)
        return r.msg if r is not None else None

    # -- what the oracles read (``fuzz.mavlink_oracles.Observed``) ----------------------------
    @property
    def probe_name(self) -> str:
        return self.info.probe.decode(errors="replace")

    def wait_beat(self, since: float) -> bool:
        """Whether a HEARTBEAT comes after ``since`` before the gap since the last one passes
        ``heartbeat_gap_max_s``."""
        return self.link.wait_beat(since, GAP_S)

    def probe_answered(self, timeout: float) -> bool:
        return self._until(self._is_probe_answer, timeout) is not None

    # -- a case --------------------------------------------------------------------------------
    def _is_probe_answer(self, m: Any) -> bool:
        return m.get_type() == "PARAM_VALUE" and self._from_vehicle(m) and \
            name_key(raw_fields(m)["param_id"]) == self.info.probe

    def _exchange(self, cases: bytes, timeout: float) -> int | None:
        """``cases`` and the probe written (``SyncLink.exchange``); the probe's answer's index."""
        self._beat()
        probe = self._pack(D.MAVLink_param_request_read_message(self.info.sysid, self.info.compid,
                                                                self.info.probe, -1))
        return self.link.exchange(cases + probe, lambda r: self._is_probe_answer(r.msg), timeout)

    def run(self, case: Case) -> Hit | None:
        """Send ``case`` and the probe; judge what came (see the module's docstring)."""
        upto = self._exchange(case.wire(), REPLY_S)
        if upto is None:
            return oracles.lost(self, case)
        hit = oracles.judge_case(case, [r.msg for r in self.frames[:upto] if self._from_vehicle(r.msg)],
                         lambda e, wait: self._until(lambda m: self._from_vehicle(m) and bool(oracles.answers(e, [m])), wait,
                                                     start=upto + 1) is not None, self._late)
        if hit is None and time.monotonic() - self.last_beat > GAP_S:
            hit = oracles.lost(self, case, answered=True)
        del self.frames[:upto + 1]
        return hit

    def run_all(self, cases: list[Case]) -> bool:
        """Send ``cases`` back to back, then the probe (a stopped heartbeat's replays: no answer
        is judged, and thousands of suspects take one write); whether the probe was answered."""
        answered = self._exchange(b"".join(c.wire() for c in cases), REPLY_S + 0.002 * len(cases)) is not None
        self.frames.clear()
        return answered

    def watch(self, since: float) -> Hit | None:
        """After a replay: a HEARTBEAT after ``since`` (nothing), or a hang (``fuzz.mavlink_oracles.silent``)."""
        return oracles.silent(self, since)

    def beats_on(self) -> Hit | None:
        """With nothing sent: what the link holds read, then ``fuzz.mavlink_oracles.beats_on``."""
        self.link.drain()
        return oracles.beats_on(self)

    def _late(self, e: Expect) -> float:
        return self.late if self.late is not None else ACK_S if e.what == "ack" else REPLY_S


class MavTarget(SpareTarget):
    """A worker's vehicle as the loop sees a target (``fuzz.target_core.SpareTarget``; the
    profile's ``fuzz_target`` of the vehicle role): the one now fuzzed (``current``: a death
    replaces it), a spare started ahead, each built for the first one's cases (its IDs,
    parameters and probe); the campaign's own waits ``LATE_S`` for a late answer."""

    #: the engines that fuzz a vehicle (``fuzz.config.engines``): its cases are frames and
    #: handshakes, each judged by the probe behind it
    ENGINES = ("stateless",)

    current: MavVehicle

    def __init__(self, how: VehicleSpec) -> None:
        self.how = how
        first = MavVehicle(how, late=LATE_S)
        self.info = first.info
        super().__init__(first, lambda log: MavVehicle(self.how, self.info, log), MavVehicle.close,
                         attached=how.target is not None)

    def adopt(self, v: MavVehicle) -> MavVehicle:
        v.late = LATE_S
        return v

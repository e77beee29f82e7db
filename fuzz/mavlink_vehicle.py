"""The vehicle under ``mcp-fuzz --protocol mavlink`` (issue 39 item 4).

A :class:`MavVehicle` is one vehicle process (spawned with ``--spawn CMD``, ``{target_host}``
``{target_port}`` and ``{mavlink}`` -- ``tcp:HOST:PORT`` -- filled in; the reference vehicle,
``mcp-vehicle``, when neither ``--spawn`` nor ``--target`` is given) or one reached at
``--target tcp:HOST:PORT``, and the fuzzer's TCP link to it, read synchronously: the fuzzer is
its ground station (system 255, MAV_COMP_ID_MISSIONPLANNER, a HEARTBEAT a second: MAV-HB-2).
The process, its end, the link read synchronously, the fuzzer's own keep-alive, the case
runner (a case and the probe written, read to the probe's answer, judged) and the worker's
spare are the shared core's (``fuzz.target_core``: ``LinkedTarget``, ``SpareTarget``);
MAVLink declares its framing (``harness.mavlink_session.MavlinkFraming``), its ``{mavlink}``
placeholder, its beat (the vehicle's HEARTBEAT, bounded by MAV-HB-1), its keep-alive, its
probe, how a case's answers are judged and its liveness oracles (``fuzz.mavlink_oracles``).

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
from typing import Any

from mcp_conform.fuzz import mavlink_oracles as oracles
from mcp_conform.fuzz.mavlink_cases import (
    Case,
    D,
    Expect,
    Packer,
    Vehicle,
    name_key,
    raw_fields,
)
from mcp_conform.fuzz.mavlink_oracles import Hit, Signature
from mcp_conform.fuzz.target_core import LinkedTarget, SpareTarget, TargetSpec
from mcp_conform.harness.errors import SetupError
from mcp_conform.harness.mavlink_session import MavlinkFraming, embedded_command, parse_address
from mcp_conform.spec import MAVLINK

__all__ = ["Hit", "MavTarget", "MavVehicle", "Signature", "vehicle_spec"]

P = MAVLINK.params
REPLY_S = float(P["param_reply_max_s"])
ACK_S = float(P["command_ack_max_s"])
GAP_S = float(P["heartbeat_gap_max_s"])
BEAT_S = float(P["heartbeat_period_s"])
LATE_S = 0.1  # s: an answer missing at the probe's answer, waited for while fuzzing (replays: the spec's bound)
LIST_S = 10.0  # s: the parameter list the cases are built from, read at the start for at most this long


def vehicle_spec(target: tuple[str, int] | None, spawn: str | None) -> TargetSpec:
    """How to reach a vehicle (``fuzz.target_core.TargetSpec.of``): a ``--spawn`` template (or
    the embedded one), or an address, over TCP."""
    def tcp(host: str, port: int) -> tuple[str, int]:
        transport, address = parse_address(host, port)
        if transport != "tcp":
            raise SetupError(f"--target {host}:{port}: the MAVLink fuzzer reaches a vehicle over "
                             "TCP only so far (tcp:HOST:PORT)")
        return address
    return TargetSpec.of(target, spawn, lambda: embedded_command("tcp"), tcp)


class MavVehicle(LinkedTarget):
    """One vehicle and the fuzzer's link to it (see the module's docstring): the shared
    core's process, link and case runner (``fuzz.target_core.LinkedTarget``), MAVLink's
    framing, beat, keep-alive, probe and judgement on it."""

    subject = "the vehicle"
    BEAT_GAP_S = GAP_S
    KEEPALIVE_S = BEAT_S
    REPLY_S = REPLY_S
    BEAT = ("HEARTBEAT", "MAV-HB-1")
    oracles = oracles

    def __init__(self, how: TargetSpec, info: Vehicle | None = None, log: list[Any] | None = None,
                 late: float | None = None) -> None:
        self.how = how
        #: how long an answer missing at the probe's answer is still waited for (None: the
        #: spec's bound, as replays wait; the campaign's own vehicle: a short while, its hits
        #: then confirmed, or not, by replays that wait the whole bound)
        self.late = late
        self.pack = Packer().pack  # its keep-alive and probe (a sequence of their own)
        hb = self.connect(how, MavlinkFraming(), log, lambda host, port: {"mavlink": f"tcp:{host}:{port}"}).msg
        self.info = info if info is not None else self._learn(hb.get_srcSystem(), hb.get_srcComponent())

    def _learn(self, sysid: int, compid: int) -> Vehicle:
        """The vehicle's IDs and parameter list (PARAM_REQUEST_LIST, read for at most LIST_S);
        the probe reads the first parameter of the list."""
        v = Vehicle(sysid, compid)
        self.send(self.pack(D.MAVLink_param_request_list_message(sysid, compid)))
        end, total, seen = time.monotonic() + LIST_S, None, 0
        while time.monotonic() < end and (total is None or len(v.params) < total):
            if self.link.until(lambda r: r.name == "PARAM_VALUE", min(2.0, end - time.monotonic()), seen) is None:
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

    def _from_vehicle(self, m: Any) -> bool:
        info = getattr(self, "info", None)
        return info is None or (m.get_srcSystem(), m.get_srcComponent()) == (info.sysid, info.compid)

    # -- what the shared core's runner asks of MAVLink (``fuzz.target_core.LinkedTarget``) -----
    def is_beat(self, r: Any) -> bool:
        return r.name == "HEARTBEAT" and self._from_vehicle(r.msg)

    def keepalive_frame(self) -> bytes:
        """The fuzzer's own HEARTBEAT, as a ground station's, once a second (MAV-HB-2)."""
        return self.pack(D.MAVLink_heartbeat_message(D.MAV_TYPE_GCS, D.MAV_AUTOPILOT_INVALID, 0, 0,
                                                      D.MAV_STATE_ACTIVE, 3))

    def probe_frame(self) -> bytes:
        return self.pack(D.MAVLink_param_request_read_message(self.info.sysid, self.info.compid, self.info.probe, -1))

    def is_probe_answer(self, r: Any) -> bool:
        return r.name == "PARAM_VALUE" and self._from_vehicle(r.msg) and \
            name_key(raw_fields(r.msg)["param_id"]) == self.info.probe

    @property
    def probe_name(self) -> str:
        return self.info.probe.decode(errors="replace")

    def judge(self, case: Case, upto: int) -> Hit | None:
        """The answers before the probe's (``fuzz.mavlink_oracles.judge_case``), one missing
        waited for after it (``late``)."""
        def later(e: Expect, wait: float) -> bool:
            return self.link.until(lambda r: self._from_vehicle(r.msg) and bool(oracles.answers(e, [r.msg])), wait,
                                   upto + 1) is not None
        return oracles.judge_case(case, [r.msg for r in self.frames[:upto] if self._from_vehicle(r.msg)], later,
                                  lambda e: self.late if self.late is not None else ACK_S if e.what == "ack" else REPLY_S)


class MavTarget(SpareTarget):
    """A worker's vehicle as the loop sees a target (``fuzz.target_core.SpareTarget``; the
    profile's ``fuzz_target`` of the vehicle role): the one now fuzzed (``current``: a death
    replaces it), a spare started ahead, each built for the first one's cases (its IDs,
    parameters and probe); the campaign's own waits ``LATE_S`` for a late answer."""

    #: the engines that fuzz a vehicle (``fuzz.config.engines``): its cases are frames and
    #: handshakes, each judged by the probe behind it
    ENGINES = ("stateless",)

    current: MavVehicle

    def __init__(self, how: TargetSpec) -> None:
        self.how = how
        first = MavVehicle(how, late=LATE_S)
        self.info = first.info
        super().__init__(first, lambda log: MavVehicle(self.how, self.info, log), MavVehicle.close,
                         attached=how.attached)

    def adopt(self, v: MavVehicle) -> MavVehicle:
        v.late = LATE_S
        return v

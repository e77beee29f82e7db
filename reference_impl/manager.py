"""The Mission Manager role: the description's ``mission_manager.py``, in modern Python.

"This has the main() method that does the following making use of mcp module:
1. Waits for 'Mission Ready' messages from all UAVs 2. Sends 'Start Mission' message to each
UAV 3. Executes the challenge based on the challenge number." Then it ends the mission.

- It sends nothing to any drone before every configured drone's Mission_Ready has arrived
  (MCP-BLK-2); the ACKs of Mission_Ready are automatic (MCP-FLOW-2).
- Every command is unicast with ``send_unicast_message``, which blocks until ACKed, so no
  further command follows Start_Mission before its ACK (MCP-BLK-3) and only one message is
  ever in flight (MCP-BLK-1).
- Challenge 1: one WP_List of the mission's waypoints (MCP-FLOW-4); challenge 2: WP_On of
  each waypoint, then WP_Off, in turn (MCP-FLOW-5); challenge 3: one Obstacles_List
  (MCP-FLOW-6).
- End_Mission is the last command each drone gets (MCP-FLOW-3, MCP-BLK-6). A drone whose
  command runs out of retries is dropped from the rest of the mission (nothing more is sent
  to it) and the run ends with exit code 1.

Waypoints and obstacles come from QGC WPL 110 files (``spec.mission.load_waypoints``).
"""

from __future__ import annotations

import logging
import threading
import time
from dataclasses import dataclass
from typing import Any

from mcp_conform.reference_impl.api import Mcp, McpException
from mcp_conform.reference_impl.handler import MissionMessageHandlerBase
from mcp_conform.reference_impl.role import (
    EventLogger,
    RoleError,
    RoleNode,
    action_name,
    write_record,
)
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import BROADCAST_ID, MANAGER_ID, Action, Message

__all__ = ["CHALLENGES", "Manager", "ManagerConfig", "ManagerHandler"]

_PORTS = SPEC.protocol["ports"]
#: The challenges of the description, by number.
CHALLENGES = {1: "WP_List", 2: "WP_On/WP_Off", 3: "Obstacles_List"}


class _Stopped(Exception):
    """``Manager.stop()`` was called while a send was blocked."""


@dataclass
class ManagerConfig:
    """Settings of the Mission Manager; ports and addresses default to the spec's."""

    challenge: int
    drones: tuple[int, ...]
    waypoints: tuple[Any, ...] = ()
    obstacles: tuple[Any, ...] = ()
    bind_host: str = ""
    local_port: int = int(_PORTS["manager"])
    remote_host: str = str(SPEC.protocol["broadcast_address"])
    remote_port: int = int(_PORTS["drone"])
    rto: float | None = None
    retries: int | None = None
    reply_to_source: bool = False
    reuse_port: bool = False  # share the port with other nodes on this host (--reuse-port)
    record_path: str | None = None
    #: MCAP capture of the manager's MCP traffic (``--capture``)
    capture_path: str | None = None
    #: ``--live``: serve the capture's channels over the Foxglove WebSocket protocol (host, port)
    live: tuple[str, int] | None = None
    #: ``--impair``: this node's socket edge is a bad link (a ``harness.impair.ImpairSpec``)
    impair: Any = None
    #: Seconds a waypoint stays active between its WP_On and WP_Off (challenge 2).
    dwell: float = 0.0
    #: Longest wait for every Mission_Ready; None waits until stopped (the description's way).
    ready_timeout: float | None = None

    def __post_init__(self) -> None:
        if self.challenge not in CHALLENGES:
            raise RoleError(f"challenge must be one of {sorted(CHALLENGES)}: {self.challenge}")
        if not self.drones:
            raise RoleError("no drones given")
        if len(set(self.drones)) != len(self.drones):
            raise RoleError(f"drone IDs repeat: {list(self.drones)}")
        for d in self.drones:
            if not 0 < d < 0xFFFF or d in (MANAGER_ID, BROADCAST_ID):
                raise RoleError(f"drone ID must be 1..65534 (0 is the manager, {BROADCAST_ID} broadcast): {d}")
        if self.challenge in (1, 2) and not self.waypoints:
            raise RoleError(f"challenge {self.challenge} needs waypoints (--waypoints FILE)")
        if self.challenge == 3 and not self.obstacles:
            raise RoleError("challenge 3 needs obstacles (--obstacles FILE)")
        if self.dwell < 0:
            raise RoleError(f"dwell must be >= 0: {self.dwell}")


class ManagerHandler(MissionMessageHandlerBase):
    """The manager's only handler: Mission_Ready ("the only message that the mission planner
    is interested in"); ``all_uavs_ready()`` as in the description's mcp_handler_ground.py."""

    def __init__(self, drones: tuple[int, ...], log: logging.Logger) -> None:
        super().__init__(None)
        self.drones = drones
        self.log = log
        self.ready: list[int] = []
        self.cond = threading.Condition()

    def handle_mission_ready_message(self, buffer: Any = None, msg: Message | None = None) -> None:
        src = msg.src if msg is not None else buffer
        with self.cond:
            if src not in self.drones:
                self.log.info("Mission_Ready from drone %s, which is not in this mission: ignored", src)
            elif src in self.ready:
                self.log.info("Mission_Ready from drone %d again", src)
            else:
                self.ready.append(src)
                self.log.info("drone %d is mission ready (%d of %d)", src, len(self.ready), len(self.drones))
                self.cond.notify_all()

    def all_uavs_ready(self) -> bool:
        with self.cond:
            return set(self.ready) >= set(self.drones)


class Manager(RoleNode):
    """The Mission Manager node: ``Manager(cfg).run()`` returns the exit code.

    0 when every drone ACKed every command through End_Mission (or ``stop()`` was called),
    1 when a drone stopped ACKing or not every drone became ready within ``ready_timeout``.
    """

    def __init__(self, cfg: ManagerConfig, log: logging.Logger | None = None) -> None:
        super().__init__()
        self.cfg = cfg
        self.log = log or logging.getLogger("manager")
        self.handler = ManagerHandler(cfg.drones, self.log)
        self.sent: list[tuple[str, int]] = []
        self.failed: list[int] = []

    def _on_stop(self) -> None:
        with self.handler.cond:
            self.handler.cond.notify_all()

    def run(self) -> int:
        try:
            return self._run()
        except _Stopped:
            self.outcome = "stopped"
            self.log.info("stopped")
            return 0
        finally:
            self.close()

    def _run(self) -> int:
        cfg = self.cfg
        capture = self._open_capture(cfg.capture_path, "manager", MANAGER_ID, rto=cfg.rto, live=cfg.live,
                                     impair=cfg.impair.text() if cfg.impair is not None else None,
                                     challenge=cfg.challenge,
                                     drones=",".join(map(str, cfg.drones)),
                                     target=f"{cfg.remote_host}:{cfg.remote_port}")
        try:
            self.mcp = Mcp(self.handler, cfg.local_port, cfg.remote_port, cfg.remote_host, MANAGER_ID,
                           bind_host=cfg.bind_host, remote_host=cfg.remote_host, timeout=cfg.rto,
                           retries=cfg.retries, reply_to_source=cfg.reply_to_source,
                           reuse_port=cfg.reuse_port, on_event=EventLogger(self.log),
                           impairment=self._impairment(cfg.impair),
                           tap=None if capture is None else capture.datagram)
        except McpException as exc:
            raise RoleError(str(exc)) from None
        self._capture_bound()
        host, port = self.mcp.local_address
        self.log.info("manager listening on %s:%d, sending to %s:%d; challenge %d (%s) for drones %s",
                      host or "0.0.0.0", port, cfg.remote_host, cfg.remote_port, cfg.challenge,
                      CHALLENGES[cfg.challenge], ",".join(map(str, cfg.drones)))
        self.listening.set()
        if not self._wait_ready():
            missing = sorted(set(cfg.drones) - set(self.handler.ready))
            self.log.error("no Mission_Ready from drone(s) %s within %g s", missing, cfg.ready_timeout)
            self.outcome = "not_ready"
            return 1
        self.log.info("all %d drones are mission ready", len(cfg.drones))
        for d in cfg.drones:
            self._send(d, Action.START_MISSION)
        self._challenge()
        for d in cfg.drones:
            self._send(d, Action.END_MISSION)
        if self.failed:
            self.outcome = "drone_failed"
            self.log.error("mission ended without drone(s) %s", sorted(self.failed))
            return 1
        self.outcome = "end_mission"
        self.log.info("mission complete")
        return 0

    def _wait_ready(self) -> bool:
        """Block until every configured drone's Mission_Ready arrived (MCP-BLK-2)."""
        deadline = None if self.cfg.ready_timeout is None else time.monotonic() + self.cfg.ready_timeout
        with self.handler.cond:
            while not set(self.handler.ready) >= set(self.cfg.drones):
                if self._stop.is_set():
                    raise _Stopped
                left = 0.2 if deadline is None else min(0.2, deadline - time.monotonic())
                if left <= 0:
                    return False
                self.handler.cond.wait(left)
        return True

    def _challenge(self) -> None:
        cfg = self.cfg
        if cfg.challenge == 1:  # MCP-FLOW-4
            for d in cfg.drones:
                self._send(d, Action.WP_LIST, tuple(cfg.waypoints))
        elif cfg.challenge == 2:  # MCP-FLOW-5: "WP_Off follows a WP_On"
            for wp in cfg.waypoints:
                for d in cfg.drones:
                    self._send(d, Action.WP_ON, wp)
                if cfg.dwell and self._stop.wait(cfg.dwell):
                    raise _Stopped
                for d in cfg.drones:
                    self._send(d, Action.WP_OFF)
        else:  # MCP-FLOW-6
            for d in cfg.drones:
                self._send(d, Action.OBSTACLES_LIST, tuple(cfg.obstacles))

    def _send(self, dst: int, action: Action, payload: Any = None) -> None:
        """Unicast and block until ACKed; a drone that never ACKs gets nothing more."""
        if self._stop.is_set():
            raise _Stopped
        if dst in self.failed:
            return
        assert self.mcp is not None
        name = action_name(action)
        self.log.info("sending %s to drone %d", name, dst)
        try:
            self.mcp.send_unicast_message(action, payload, dst)
        except McpException as exc:
            if self._stop.is_set():
                raise _Stopped from None
            self.log.error("drone %d never ACKed %s (%s): dropped from the mission", dst, name, exc)
            self.failed.append(dst)
            return
        self.sent.append((name, dst))
        self.log.info("%s ACKed by drone %d", name, dst)

    def record(self) -> dict[str, Any]:
        return {
            "role": "manager",
            "challenge": self.cfg.challenge,
            "drones": list(self.cfg.drones),
            "outcome": self.outcome,
            "ready": list(self.handler.ready),
            "sent": [list(s) for s in self.sent],
            "failed": list(self.failed),
        }

    def close(self) -> None:
        if self.mcp is not None:
            self.mcp.close()
        self._close_capture()
        if self.cfg.record_path:
            write_record(self.cfg.record_path, self.record(), self.log)

#!/usr/bin/env python3
"""A CentMesh drone application written with DroneKit-Python (dronekit2 3.x).

It speaks MCP through the project's CentMesh API (:class:`reference_impl.api.Mcp` with a
``MissionMessageHandlerBase`` subclass, as the protocol description's drone example does) and
flies the mission the way DroneKit's own examples fly one::

    python examples/apps/dronekit_drone.py --id 1 --listen 7890 --manager 127.0.0.1:7889 \\
        --autopilot tcp:127.0.0.1:5760

What it does, with the MCP rule each step keeps (docs: /work/shared/MCP-REQUIREMENTS.md):

1. ``connect(url, wait_ready=True)`` (DroneKit's "Connecting to a Vehicle"); ``url`` is a
   pymavlink URL, which is DroneKit's own connection string (``tcp:``, ``udp:``/``udpin:`` to
   listen, ``udpout:``, a serial device);
2. opens the MCP node, then waits ``while not vehicle.is_armable`` (DroneKit's "Taking off"
   guide: mode not INITIALISING, a GPS fix, the EKF's pre-arm position estimate) and only then
   sends Mission_Ready to the manager, ID 0, blocking until ACKed — MCP-BLK-5 ("The drone sends
   Mission_Ready only once it is ready to fly"), MCP-FLOW-1, MCP-PAY-2;
3. on Start_Mission, and never before it (MCP-BLK-4), sets GUIDED, arms
   (``vehicle.armed = True``), ``simple_takeoff`` and waits for the altitude ("ARM the UAV and
   station keep at 10 metres");
4. WP_List: uploads the waypoints with DroneKit's mission API (``vehicle.commands``:
   ``download``, ``clear``, ``add(Command(...))``, ``upload``) and flies them in AUTO once
   airborne; WP_On: ``simple_goto`` to the waypoint in GUIDED; WP_Off, Obstacles_List: logged;
5. Mav_Passthrough: the delivered MAVLink frame is written to the autopilot link once, as it
   came (MCP-PAY-8), through DroneKit's writer queue (``vehicle._handler.out_queue``, the queue
   DroneKit's own ``MAVConnection.pipe``/``forward_message`` put raw frames on): one writer
   thread owns the link, so a frame never interleaves with DroneKit's own messages on TCP;
6. End_Mission: the flight work already queued finishes (a climb in progress gets at most
   ``END_GRACE`` more seconds), then ``vehicle.mode = VehicleMode("RTL")`` (MCP-BLK-7); the
   node keeps ACKing retransmitted copies for 2 x its timeout, then exits 0.

Threads: ``Mcp`` ACKs in its network thread and calls the handlers in its handler thread
(``reference_impl.api``); the handlers only queue flight jobs (so a climb never delays an ACK
or a forwarded frame); the main thread runs the jobs in order with DroneKit's blocking idioms.
SIGTERM or SIGINT ends it at any point with exit 0; bad arguments give one line and exit 2.
"""

from __future__ import annotations

import argparse
import logging
import math
import queue
import signal
import sys
import time
from typing import Any

try:
    from dronekit import APIException, Command, LocationGlobalRelative, VehicleMode, connect
    from dronekit import TimeoutError as DronekitTimeout
except ImportError as _exc:  # pragma: no cover - depends on the environment
    sys.exit(f"dronekit_drone.py: error: DroneKit is not installed ({_exc}): pip install dronekit2")

from mcp_conform.reference_impl import Action, Mcp, McpException, MissionMessageHandlerBase

log = logging.getLogger("dronekit_drone")

#: The Mission Manager's MCP ID: Mission_Ready is unicast to it (MCP-PAY-2).
MANAGER_ID = 0
#: Seconds a flight job may still wait after End_Mission before the RTL goes out (MCP-BLK-7:
#: "complete carrying out all currently pending actions ..., then execute an RTL").
END_GRACE = 1.0
#: Bounds of DroneKit's blocking waits (its own examples loop forever).
ARM_TIMEOUT = 5.0
CLIMB_TIMEOUT = 30.0
UPLOAD_TIMEOUT = 5.0


class Stopped(Exception):
    """SIGTERM or SIGINT: raised in the main thread to leave whatever it waits on."""


# ---------------------------------------------------------------------- MCP handlers
class DronekitMissionHandler(MissionMessageHandlerBase):
    """The MCP handlers (called in delivery order in ``Mcp``'s handler thread): they queue
    flight jobs for the main thread and forward passthrough frames at once."""

    def __init__(self, vehicle: Any) -> None:
        super().__init__(vehicle)
        self.vehicle = vehicle
        self.jobs: queue.Queue[tuple[str, Any]] = queue.Queue()
        self.started = False
        self.end_at: float | None = None  # monotonic time End_Mission was delivered
        self.forwarded = 0

    def handle_start_mission_message(self, buffer: Any = None) -> None:
        if self.end_at is not None or self.started:
            log.info("Start_Mission %s: not acted on",
                     "after End_Mission" if self.end_at else "again")
            return
        self.started = True
        log.info("Start_Mission: arming and taking off")
        self.jobs.put(("takeoff", None))

    def handle_wp_list_message(self, buffer: Any = None) -> None:
        waypoints = tuple(buffer or ())
        log.info("WP_List: %d waypoints", len(waypoints))
        if waypoints and self.end_at is None:
            self.jobs.put(("mission", waypoints))

    def handle_wp_on_message(self, buffer: Any = None) -> None:
        log.info("WP_On: %s", _describe(buffer))
        if buffer is not None and self.end_at is None:
            self.jobs.put(("goto", buffer))

    def handle_wp_off_message(self, buffer: Any = None) -> None:
        log.info("WP_Off: the active waypoint is inactive")

    def handle_obstacle_list_message(self, buffer: Any = None) -> None:
        log.info("Obstacles_List: %d obstacles", len(buffer or ()))

    def handle_mav_passthrough_message(self, buffer: Any = None) -> None:
        """MCP-PAY-8: the frame, once, as it came, on DroneKit's writer queue."""
        if isinstance(buffer, (bytes, bytearray)):
            self.vehicle._handler.out_queue.put(bytes(buffer))
            self.forwarded += 1
            log.info("Mav_Passthrough: forwarded a %d-byte frame to the autopilot", len(buffer))

    def handle_end_mission_message(self, buffer: Any = None) -> None:
        if self.end_at is not None:
            return
        self.end_at = time.monotonic()
        log.info("End_Mission: finishing pending flight work, then RTL")
        self.jobs.put(("rtl", None))


def _describe(wp: Any) -> str:
    try:
        return f"#{wp.seq} {wp.x:.6f},{wp.y:.6f} {wp.z:.1f} m"
    except (AttributeError, TypeError, ValueError):
        return repr(wp)


def _is_position(wp: Any) -> bool:
    """A waypoint a GUIDED goto can fly to: finite, latitude and longitude in range (E-2)."""
    return (all(math.isfinite(v) for v in (wp.x, wp.y, wp.z))
            and abs(wp.x) <= 90 and abs(wp.y) <= 180)


# ---------------------------------------------------------------------- flight (main thread)
class Flight:
    """The flight jobs, run one after another in the main thread with DroneKit's idioms."""

    def __init__(self, vehicle: Any, handler: DronekitMissionHandler, alt: float) -> None:
        self.vehicle = vehicle
        self.handler = handler
        self.alt = alt
        self.airborne = False

    def wait(self, done: Any, timeout: float) -> bool:
        """Poll ``done()`` every 0.1 s for at most ``timeout`` s, and at most ``END_GRACE`` s
        after End_Mission (the RTL must not wait on a climb for long)."""
        deadline = time.monotonic() + timeout
        while not done():
            end_at = self.handler.end_at
            now = time.monotonic()
            if now >= deadline or (end_at is not None and now >= end_at + END_GRACE):
                return False
            time.sleep(0.1)
        return True

    def run(self) -> None:
        """Run jobs until the RTL has been commanded."""
        while True:
            kind, arg = self.handler.jobs.get()
            getattr(self, f"job_{kind}")(arg)
            if kind == "rtl":
                return

    def job_takeoff(self, _arg: Any) -> None:
        """DroneKit's ``arm_and_takeoff``: GUIDED, arm, ``simple_takeoff``, wait for the
        altitude."""
        v = self.vehicle
        log.info("arming %s", v.version)  # from AUTOPILOT_VERSION, which DroneKit asks for itself
        v.mode = VehicleMode("GUIDED")
        for _ in range(3):
            v.armed = True
            if self.wait(lambda: v.armed, ARM_TIMEOUT / 3):
                break
        else:
            log.warning("the autopilot did not arm (mode %s)", v.mode.name)
            return
        log.info("armed; taking off to %.1f m", self.alt)
        v.simple_takeoff(self.alt)
        self.airborne = True
        if self.wait(lambda: (v.location.global_relative_frame.alt or 0.0) >= 0.95 * self.alt,
                     CLIMB_TIMEOUT):
            log.info("reached %.1f m", v.location.global_relative_frame.alt)
        else:
            log.info("climb not finished (%.1f m) when the next job came",
                     v.location.global_relative_frame.alt or 0.0)

    def job_mission(self, waypoints: tuple[Any, ...]) -> None:
        """WP_List with DroneKit's mission API; flown in AUTO once airborne."""
        cmds = self.vehicle.commands
        try:
            cmds.download()
            cmds.wait_ready(timeout=UPLOAD_TIMEOUT)
            cmds.clear()
            for wp in waypoints:
                cmds.add(Command(0, 0, 0, wp.frame, wp.command, 0, wp.autocontinue, wp.param1,
                                 wp.param2, wp.param3, wp.param4, wp.x, wp.y, wp.z))
            cmds.upload(timeout=UPLOAD_TIMEOUT)
        except (DronekitTimeout, APIException) as exc:
            log.warning("mission upload failed: %s", exc or type(exc).__name__)
            return
        log.info("mission of %d waypoints uploaded", len(waypoints))
        if self.airborne and self.handler.end_at is None:
            self.vehicle.mode = VehicleMode("AUTO")
            log.info("flying the mission in AUTO")

    def job_goto(self, wp: Any) -> None:
        """WP_On: ``simple_goto`` the active waypoint in GUIDED."""
        if not self.airborne or not _is_position(wp):
            log.info("WP_On %s: not flown (%s)", _describe(wp),
                     "not airborne" if not self.airborne else "not a position")
            return
        self.vehicle.mode = VehicleMode("GUIDED")
        self.vehicle.simple_goto(LocationGlobalRelative(wp.x, wp.y, wp.z))
        log.info("going to %s", _describe(wp))

    def job_rtl(self, _arg: Any) -> None:
        """End_Mission: every job queued before it has run; now RTL (MCP-BLK-7)."""
        self.vehicle.mode = VehicleMode("RTL")
        log.info("RTL commanded")
        if self.wait(lambda: self.vehicle.mode.name == "RTL", 2.0):
            log.info("mode RTL")


# ---------------------------------------------------------------------- command line
class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, not usage + line
        self.exit(2, f"{self.prog}: error: {message}\n")


def _port(text: str) -> int:
    try:
        port = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a port number: {text!r}") from None
    if not 1 <= port <= 65535:
        raise argparse.ArgumentTypeError(f"port must be 1..65535: {port}")
    return port


def _host_port(text: str) -> tuple[str, int]:
    host, sep, port = text.rpartition(":")
    if not sep or not host:
        raise argparse.ArgumentTypeError(f"expected HOST:PORT: {text!r}")
    return host, _port(port)


def _drone_id(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not 1 <= value <= 65534:
        raise argparse.ArgumentTypeError(f"drone ID must be 1..65534 (0 is the manager): {value}")
    return value


def _positive(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number: {text}")
    return value


def _autopilot(text: str) -> str:
    """A pymavlink URL, DroneKit's connection string: tcp:, udp:, udpin:, udpout:, a device."""
    scheme = text.split(":", 1)[0]
    if ":" in text and scheme in ("tcp", "udp", "udpin", "udpout"):
        _host_port(text.split(":", 1)[1])
        return text
    if text.startswith("/dev/") or text.upper().startswith("COM"):
        return text
    raise argparse.ArgumentTypeError(
        "expected tcp:HOST:PORT, udp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT or a serial "
        f"device: {text!r}")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = _Parser(prog="dronekit_drone.py",
                description="A CentMesh MCP drone application on DroneKit-Python.")
    p.add_argument("--id", type=_drone_id, required=True, help="this drone's MCP ID (1..65534)")
    p.add_argument("--listen", type=_port, required=True, help="UDP port the node listens on")
    p.add_argument("--manager", type=_host_port, required=True, metavar="HOST:PORT",
                   help="where the Mission Manager listens")
    p.add_argument("--autopilot", type=_autopilot, required=True, metavar="URL",
                   help="the autopilot, as DroneKit (pymavlink) spells it: tcp:127.0.0.1:5760, "
                        "udp:127.0.0.1:14550 (listen), udpout:HOST:PORT")
    p.add_argument("--rto", type=_positive, default=5.0, metavar="S",
                   help="MCP retransmission timeout (default: the description's 5 s)")
    p.add_argument("--alt", type=_positive, default=10.0, metavar="M",
                   help="take-off altitude (default 10 m)")
    p.add_argument("--ready-timeout", type=_positive, default=60.0, metavar="S",
                   help="how long connect(wait_ready=True) may take (default 60 s)")
    return p.parse_args(argv)


def _on_signal(signum: int, _frame: Any) -> None:
    signal.signal(signal.SIGTERM, signal.SIG_IGN)  # one Stopped; later signals while
    signal.signal(signal.SIGINT, signal.SIG_IGN)   # closing are ignored
    raise Stopped(signal.Signals(signum).name)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    signal.signal(signal.SIGTERM, _on_signal)
    signal.signal(signal.SIGINT, _on_signal)
    vehicle = mcp = None
    try:
        log.info("connecting to the autopilot at %s", args.autopilot)
        vehicle = connect(args.autopilot, wait_ready=True, timeout=args.ready_timeout,
                          heartbeat_timeout=args.ready_timeout)
        log.info("connected: mode %s", vehicle.mode.name)
        handler = DronekitMissionHandler(vehicle)
        host, port = args.manager
        mcp = Mcp(handler, args.listen, port, host, args.id, remote_host=host, timeout=args.rto)
        log.info("drone %d listening on UDP %d, manager at %s:%d", args.id, args.listen, host, port)
        last = 0.0
        while not vehicle.is_armable:  # MCP-BLK-5
            if time.monotonic() - last >= 5.0:
                last = time.monotonic()
                log.info("waiting for the vehicle to be armable (GPS fix %s, EKF ok %s, mode %s)",
                         vehicle.gps_0.fix_type, vehicle.ekf_ok, vehicle.mode.name)
            time.sleep(0.2)
        log.info("armable: sending Mission_Ready")
        mcp.send_unicast_message(Action.MISSION_READY, None, MANAGER_ID)
        log.info("Mission_Ready ACKed; waiting for Start_Mission")
        Flight(vehicle, handler, args.alt).run()
        linger = 2 * args.rto
        log.info("mission over (%d frames forwarded); still ACKing for %.1f s",
                 handler.forwarded, linger)
        time.sleep(linger)
        return 0
    except Stopped as why:
        log.info("stopped by %s", why)
        return 0
    except McpException as exc:
        print(f"dronekit_drone.py: error: {exc}", file=sys.stderr)
        return 1
    except (APIException, DronekitTimeout) as exc:
        print(f"dronekit_drone.py: error: autopilot at {args.autopilot}: "
              f"{exc or type(exc).__name__}", file=sys.stderr)
        return 1
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        if mcp is not None:
            mcp.close()
        if vehicle is not None:
            vehicle.close()


if __name__ == "__main__":
    sys.exit(main())

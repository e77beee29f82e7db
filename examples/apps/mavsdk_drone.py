#!/usr/bin/env python3
"""A CentMesh drone application written with MAVSDK (``mavsdk`` 4.x, the native binding over
the MAVSDK C++ core, its asyncio API).

It speaks MCP through the project's CentMesh API (:class:`reference_impl.api.Mcp` with a
``MissionMessageHandlerBase`` subclass) and flies the mission the way MAVSDK's examples do::

    python examples/apps/mavsdk_drone.py --id 1 --listen 7890 --manager 127.0.0.1:7889 \\
        --autopilot tcp:127.0.0.1:5760

What it does, with the MCP rule each step keeps (docs: /work/shared/MCP-REQUIREMENTS.md):

1. ``Mavsdk.add_any_connection`` and ``first_autopilot``; ``--autopilot`` takes a pymavlink URL
   (what the conformance runner's ``{mavlink}`` gives) and translates it to MAVSDK's
   (``tcp:H:P`` -> ``tcpout://H:P``, ``udp:``/``udpin:H:P`` -> ``udpin://H:P``, ``udpout:H:P`` ->
   ``udpout://H:P``, a device -> ``serial://DEV:BAUD``);
2. opens the MCP node, then waits on ``telemetry.subscribe_health()`` until
   ``is_global_position_ok and is_home_position_ok`` (MAVSDK's takeoff example) and only then
   sends Mission_Ready to the manager, ID 0, blocking until ACKed — MCP-BLK-5, MCP-FLOW-1,
   MCP-PAY-2;
3. on Start_Mission, and never before it (MCP-BLK-4): ``action.set_takeoff_altitude``,
   ``action.arm()``, ``action.takeoff()``, then waits for ``in_air`` and the altitude;
4. WP_List: ``mission_raw.upload_mission`` (item 0 home, as ArduPilot numbers a mission) and
   ``start_mission`` once airborne; WP_On: ``action.goto_location`` (MAV_CMD_DO_REPOSITION);
   WP_Off, Obstacles_List: logged;
5. Mav_Passthrough (MCP-PAY-8): MAVSDK's native API has no call that writes raw bytes to a
   connection (its ``raw://`` connection type would make the application the owner of the
   whole transport); its ``MavlinkDirect`` plugin sends any MAVLink message by name and fields.
   So the frame is decoded with pymavlink (ardupilotmega dialect, v1 or v2) and sent once with
   ``MavlinkDirect.send_message``: MAVSDK frames it again with its own system ID, component ID
   and sequence number, the fields unchanged (NaN as JSON ``null``). A frame that does not
   decode, a field of +-infinity, or a message MAVSDK's dialect does not know, is logged and
   not forwarded;
6. End_Mission: the flight work already queued finishes (a climb in progress gets at most
   ``END_GRACE`` more seconds), then ``action.return_to_launch()`` (MCP-BLK-7); the node keeps
   ACKing retransmitted copies for 2 x its timeout, then exits 0.

Threads: ``Mcp`` ACKs in its network thread and calls the handlers in its handler thread; the
handlers hand flight jobs to the asyncio loop (``call_soon_threadsafe``), which runs them in
order, and send passthrough frames through the loop at once. SIGTERM or SIGINT cancels the main
task at any point, exit 0; bad arguments give one line and exit 2.
"""

from __future__ import annotations

import argparse
import asyncio
import json
import logging
import math
import signal
import sys
import time
from typing import Any

try:
    from mavsdk import LogLevel, log_subscribe
    from mavsdk.asyncio import ComponentType, Configuration, Mavsdk, MavsdkConnectionError
    from mavsdk.asyncio.plugins.action import ActionAsync, ActionError
    from mavsdk.asyncio.plugins.mavlink_direct import (
        MavlinkDirectAsync,
        MavlinkDirectError,
        MavlinkMessage,
    )
    from mavsdk.asyncio.plugins.mission_raw import MissionItem, MissionRawAsync, MissionRawError
    from mavsdk.asyncio.plugins.telemetry import TelemetryAsync
except ImportError as _exc:  # pragma: no cover - depends on the environment
    sys.exit(f"mavsdk_drone.py: error: MAVSDK 4.x is not installed ({_exc}): "
             "pip install 'mavsdk>=4'")

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from mcp_conform.reference_impl import Action, Mcp, McpException, MissionMessageHandlerBase

log = logging.getLogger("mavsdk_drone")

#: The Mission Manager's MCP ID: Mission_Ready is unicast to it (MCP-PAY-2).
MANAGER_ID = 0
#: Seconds a flight job may still wait after End_Mission before the RTL goes out (MCP-BLK-7).
END_GRACE = 1.0
CLIMB_TIMEOUT = 30.0
#: MAV_FRAMEs whose x/y are latitude/longitude: MISSION_ITEM_INT carries them as degrees x 1e7.
_GLOBAL_FRAMES = frozenset(
    getattr(mavlink2, name) for name in (
        "MAV_FRAME_GLOBAL", "MAV_FRAME_GLOBAL_RELATIVE_ALT", "MAV_FRAME_GLOBAL_INT",
        "MAV_FRAME_GLOBAL_RELATIVE_ALT_INT", "MAV_FRAME_GLOBAL_TERRAIN_ALT",
        "MAV_FRAME_GLOBAL_TERRAIN_ALT_INT"))


class AppError(Exception):
    """A setup failure reported in one line (exit 1)."""


# ---------------------------------------------------------------------- MCP handlers
class MavsdkMissionHandler(MissionMessageHandlerBase):
    """The MCP handlers (``Mcp``'s handler thread, in delivery order): flight jobs go to the
    asyncio loop's queue; passthrough frames go out through ``MavlinkDirect`` at once."""

    def __init__(self, loop: asyncio.AbstractEventLoop, direct: MavlinkDirectAsync) -> None:
        super().__init__(None)
        self.loop = loop
        self.direct = direct
        self.jobs: asyncio.Queue[tuple[str, Any]] = asyncio.Queue()
        self.started = False
        self.end_at: float | None = None  # monotonic time End_Mission was delivered
        self.forwarded = 0
        self._parser = mavlink2.MAVLink(None)

    def _job(self, kind: str, arg: Any = None) -> None:
        self.loop.call_soon_threadsafe(self.jobs.put_nowait, (kind, arg))

    def handle_start_mission_message(self, buffer: Any = None) -> None:
        if self.end_at is not None or self.started:
            log.info("Start_Mission %s: not acted on",
                     "after End_Mission" if self.end_at else "again")
            return
        self.started = True
        log.info("Start_Mission: arming and taking off")
        self._job("takeoff")

    def handle_wp_list_message(self, buffer: Any = None) -> None:
        waypoints = tuple(buffer or ())
        log.info("WP_List: %d waypoints", len(waypoints))
        if waypoints and self.end_at is None:
            self._job("mission", waypoints)

    def handle_wp_on_message(self, buffer: Any = None) -> None:
        log.info("WP_On: %s", _describe(buffer))
        if buffer is not None and self.end_at is None:
            self._job("goto", buffer)

    def handle_wp_off_message(self, buffer: Any = None) -> None:
        log.info("WP_Off: the active waypoint is inactive")

    def handle_obstacle_list_message(self, buffer: Any = None) -> None:
        log.info("Obstacles_List: %d obstacles", len(buffer or ()))

    def handle_mav_passthrough_message(self, buffer: Any = None) -> None:
        """MCP-PAY-8: decode the frame, send it once with ``MavlinkDirect.send_message``."""
        if not isinstance(buffer, (bytes, bytearray)):
            return
        try:
            msgs = self._parser.parse_buffer(bytes(buffer)) or []
        except mavlink2.MAVError as exc:
            log.warning("Mav_Passthrough: not a MAVLink frame (%s): not forwarded", exc)
            return
        for msg in msgs:
            direct_msg = _direct_message(msg)
            future = asyncio.run_coroutine_threadsafe(self.direct.send_message(direct_msg),
                                                      self.loop)
            try:
                future.result(timeout=5.0)
            except MavlinkDirectError as exc:
                log.warning("Mav_Passthrough: MAVSDK did not send %s: %s", msg.get_type(), exc)
                continue
            except Exception as exc:  # noqa: BLE001 - the loop closing, a timeout: say which
                log.warning("Mav_Passthrough: %s not sent: %s", msg.get_type(),
                            exc or type(exc).__name__)
                continue
            self.forwarded += 1
            log.info("Mav_Passthrough: forwarded %s to the autopilot", msg.get_type())

    def handle_end_mission_message(self, buffer: Any = None) -> None:
        if self.end_at is not None:
            return
        self.end_at = time.monotonic()
        log.info("End_Mission: finishing pending flight work, then RTL")
        self._job("rtl")


def _json_value(value: Any) -> Any:
    """A field value as MavlinkDirect's JSON takes it: NaN as ``null`` (which MAVSDK encodes
    as NaN; JSON has no NaN), byte arrays as lists of numbers."""
    if isinstance(value, float) and math.isnan(value):
        return None
    if isinstance(value, (bytes, bytearray)):
        return list(value)
    if isinstance(value, list):
        return [_json_value(v) for v in value]
    return value


def _direct_message(msg: Any) -> MavlinkMessage:
    """A pymavlink message as MAVSDK's ``MavlinkMessage``: its name and its fields as JSON
    (char arrays as strings, arrays as lists, as pymavlink decoded them)."""
    fields = {name: _json_value(getattr(msg, name)) for name in msg.get_fieldnames()}
    return MavlinkMessage(message_name=msg.get_type(),
                          target_system_id=int(fields.get("target_system", 0) or 0),
                          target_component_id=int(fields.get("target_component", 0) or 0),
                          fields_json=json.dumps(fields))


def _describe(wp: Any) -> str:
    try:
        return f"#{wp.seq} {wp.x:.6f},{wp.y:.6f} {wp.z:.1f} m"
    except (AttributeError, TypeError, ValueError):
        return repr(wp)


def _is_position(wp: Any) -> bool:
    """A waypoint with a finite latitude, longitude and altitude in range (E-2)."""
    return (all(math.isfinite(v) for v in (wp.x, wp.y, wp.z))
            and abs(wp.x) <= 90 and abs(wp.y) <= 180)


# ---------------------------------------------------------------------- flight (asyncio)
class Flight:
    """The flight jobs, run one after another on the asyncio loop with MAVSDK's plugins."""

    def __init__(self, drone: Any, handler: MavsdkMissionHandler, alt: float) -> None:
        self.action = ActionAsync(drone)
        self.telemetry = TelemetryAsync(drone)
        self.mission_raw = MissionRawAsync(drone)
        self.handler = handler
        self.alt = alt
        self.airborne = False

    async def wait(self, done: Any, timeout: float) -> bool:
        """Poll ``await done()`` every 0.1 s for at most ``timeout`` s, and at most
        ``END_GRACE`` s after End_Mission (the RTL must not wait on a climb for long)."""
        deadline = time.monotonic() + timeout
        while not await done():
            end_at = self.handler.end_at
            now = time.monotonic()
            if now >= deadline or (end_at is not None and now >= end_at + END_GRACE):
                return False
            await asyncio.sleep(0.1)
        return True

    async def run(self) -> None:
        """Run jobs until the RTL has been commanded."""
        while True:
            kind, arg = await self.handler.jobs.get()
            await getattr(self, f"job_{kind}")(arg)
            if kind == "rtl":
                return

    async def job_takeoff(self, _arg: Any) -> None:
        """MAVSDK's takeoff example: arm, takeoff, wait until in the air at the altitude."""
        await self.action.set_takeoff_altitude(self.alt)
        for attempt in range(3):
            try:
                await self.action.arm()
                break
            except ActionError as exc:
                log.info("arm refused (%s)%s", exc.result.name, ", retrying" if attempt < 2 else "")
                await asyncio.sleep(0.5)
        else:
            log.warning("the autopilot did not arm")
            return
        log.info("armed; taking off to %.1f m", self.alt)
        try:
            await self.action.takeoff()
        except ActionError as exc:
            log.warning("takeoff refused: %s", exc.result.name)
            return
        self.airborne = True

        async def up() -> bool:
            return (await self.telemetry.in_air()
                    and (await self.telemetry.position()).relative_altitude_m >= 0.95 * self.alt)
        if await self.wait(up, CLIMB_TIMEOUT):
            log.info("in the air at %.1f m", self.alt)
        else:
            log.info("climb not finished when the next job came")

    async def job_mission(self, waypoints: tuple[Any, ...]) -> None:
        """WP_List with MAVSDK's raw mission API (item 0 home, as ArduPilot numbers it; MAVSDK
        wants exactly one item marked current: home)."""
        if not all(_is_position(wp) for wp in waypoints):
            log.warning("WP_List holds an item that is not a position: not uploaded")
            return
        home = await self.telemetry.home()
        items = [MissionItem(0, mavlink2.MAV_FRAME_GLOBAL_INT, mavlink2.MAV_CMD_NAV_WAYPOINT, 1, 1,
                             0, 0, 0, 0, round(home.latitude_deg * 1e7),
                             round(home.longitude_deg * 1e7), home.absolute_altitude_m, 0)]
        for seq, wp in enumerate(waypoints, start=1):
            scale = 1e7 if wp.frame in _GLOBAL_FRAMES else 1e4
            items.append(MissionItem(seq, wp.frame, wp.command, 0, wp.autocontinue, wp.param1,
                                     wp.param2, wp.param3, wp.param4, round(wp.x * scale),
                                     round(wp.y * scale), wp.z, 0))
        try:
            await self.mission_raw.upload_mission(items)
        except MissionRawError as exc:
            log.warning("mission upload failed: %s", exc.result.name)
            return
        log.info("mission of %d waypoints uploaded", len(waypoints))
        if self.airborne and self.handler.end_at is None:
            try:
                await self.mission_raw.start_mission()
                log.info("flying the mission")
            except MissionRawError as exc:
                log.warning("mission start refused: %s", exc.result.name)

    async def job_goto(self, wp: Any) -> None:
        """WP_On: ``goto_location`` the active waypoint (its altitude relative to home)."""
        if not self.airborne or not _is_position(wp):
            log.info("WP_On %s: not flown (%s)", _describe(wp),
                     "not airborne" if not self.airborne else "not a position")
            return
        home = await self.telemetry.home()
        try:
            await self.action.goto_location(wp.x, wp.y, home.absolute_altitude_m + wp.z, math.nan)
            log.info("going to %s", _describe(wp))
        except ActionError as exc:
            log.warning("goto refused: %s", exc.result.name)

    async def job_rtl(self, _arg: Any) -> None:
        """End_Mission: every job queued before it has run; now RTL (MCP-BLK-7)."""
        try:
            await self.action.return_to_launch()
            log.info("RTL commanded and accepted")
        except ActionError as exc:
            log.warning("RTL refused: %s", exc.result.name)


# ---------------------------------------------------------------------- the node
async def wait_until_ready(telemetry: TelemetryAsync) -> None:
    """MCP-BLK-5 with MAVSDK's readiness idiom: a global position and a home position."""
    last = 0.0
    async for health in telemetry.subscribe_health():
        if health.is_global_position_ok and health.is_home_position_ok:
            return
        if time.monotonic() - last >= 5.0:
            last = time.monotonic()
            log.info("waiting for the vehicle: global position ok %s, home position ok %s",
                     health.is_global_position_ok, health.is_home_position_ok)


async def run(args: argparse.Namespace) -> int:
    loop = asyncio.get_running_loop()
    url = mavsdk_url(args.autopilot)
    config = Configuration.create_with_component_type(ComponentType.GROUND_STATION)
    async with Mavsdk(config) as sdk:
        log.info("connecting to the autopilot at %s (%s)", url, args.autopilot)
        try:
            await sdk.add_any_connection(url)
        except MavsdkConnectionError as exc:
            raise AppError(f"cannot connect to the autopilot at {url}: {exc}") from None
        drone = await sdk.first_autopilot(timeout_s=args.ready_timeout)
        if drone is None:
            raise AppError(f"no autopilot at {url} within {args.ready_timeout:g} s")
        direct = MavlinkDirectAsync(drone)
        handler = MavsdkMissionHandler(loop, direct)
        host, port = args.manager
        try:
            mcp = Mcp(handler, args.listen, port, host, args.id, remote_host=host, timeout=args.rto)
        except McpException as exc:
            raise AppError(str(exc)) from None
        try:
            log.info("drone %d listening on UDP %d, manager at %s:%d", args.id, args.listen,
                     host, port)
            await wait_until_ready(TelemetryAsync(drone))
            log.info("global and home position ok: sending Mission_Ready")
            await loop.run_in_executor(None, mcp.send_unicast_message, Action.MISSION_READY, None,
                                       MANAGER_ID)
            log.info("Mission_Ready ACKed; waiting for Start_Mission")
            await Flight(drone, handler, args.alt).run()
            linger = 2 * args.rto
            log.info("mission over (%d frames forwarded); still ACKing for %.1f s",
                     handler.forwarded, linger)
            await asyncio.sleep(linger)
            return 0
        finally:
            mcp.close()
            direct.destroy()


def mavsdk_url(url: str) -> str:
    """A pymavlink URL (the runner's ``{mavlink}``) in MAVSDK's connection-URL form."""
    scheme, _, rest = url.partition(":")
    if scheme == "tcp":
        return f"tcpout://{rest}"
    if scheme in ("udp", "udpin"):
        return f"udpin://{rest}"
    if scheme == "udpout":
        return f"udpout://{rest}"
    device, _, baud = url.partition(",")
    return f"serial://{device}:{baud or 57600}"


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
    """A pymavlink URL: tcp:, udp:, udpin:, udpout: HOST:PORT, or a serial device[,baud]."""
    scheme = text.split(":", 1)[0]
    if ":" in text and scheme in ("tcp", "udp", "udpin", "udpout"):
        _host_port(text.split(":", 1)[1])
        return text
    if text.startswith("/dev/"):
        return text
    raise argparse.ArgumentTypeError(
        "expected tcp:HOST:PORT, udp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT or "
        f"/dev/DEVICE[,BAUD]: {text!r}")


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    p = _Parser(prog="mavsdk_drone.py", description="A CentMesh MCP drone application on MAVSDK.")
    p.add_argument("--id", type=_drone_id, required=True, help="this drone's MCP ID (1..65534)")
    p.add_argument("--listen", type=_port, required=True, help="UDP port the node listens on")
    p.add_argument("--manager", type=_host_port, required=True, metavar="HOST:PORT",
                   help="where the Mission Manager listens")
    p.add_argument("--autopilot", type=_autopilot, required=True, metavar="URL",
                   help="the autopilot as a pymavlink URL (translated to MAVSDK's): "
                        "tcp:127.0.0.1:5760, udp:127.0.0.1:14550 (listen), udpout:HOST:PORT")
    p.add_argument("--rto", type=_positive, default=5.0, metavar="S",
                   help="MCP retransmission timeout (default: the description's 5 s)")
    p.add_argument("--alt", type=_positive, default=10.0, metavar="M",
                   help="take-off altitude (default 10 m)")
    p.add_argument("--ready-timeout", type=_positive, default=60.0, metavar="S",
                   help="how long to wait for the autopilot's first heartbeat (default 60 s)")
    return p.parse_args(argv)


def _mavsdk_log(level: LogLevel, message: str, _file: str | None, _line: int) -> bool:
    """MAVSDK's own log lines into ours (stderr), not onto stdout."""
    logging.getLogger("mavsdk").log(
        logging.WARNING if level >= LogLevel.WARN else logging.DEBUG, "%s", message)
    return True


async def _main(args: argparse.Namespace) -> int:
    task = asyncio.current_task()
    assert task is not None
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, task.cancel)
    try:
        return await run(args)
    except asyncio.CancelledError:
        log.info("stopped by a signal")
        return 0
    finally:
        for sig in (signal.SIGTERM, signal.SIGINT):
            loop.remove_signal_handler(sig)
            signal.signal(sig, signal.SIG_IGN)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    logging.basicConfig(level=logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(name)s %(levelname)s %(message)s")
    log_subscribe(_mavsdk_log)
    try:
        return asyncio.run(_main(args))
    except AppError as exc:
        print(f"mavsdk_drone.py: error: {exc}", file=sys.stderr)
        return 1
    except McpException as exc:
        print(f"mavsdk_drone.py: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())

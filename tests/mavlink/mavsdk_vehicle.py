"""A vehicle no one here wrote: MAVSDK's server side (``mavsdk`` 4.x, the native binding over
the MAVSDK C++ core; no ``mavsdk_server`` process since 4.0), written the way MAVSDK's
``examples/autopilot_server`` does it, for ``mcp-conform --protocol mavlink`` to judge.

    python tests/mavlink/mavsdk_vehicle.py --mavlink tcp:HOST:PORT [--duration S]

``--mavlink`` is the runner's side of the link as pymavlink names it, the way ``--spawn``'s
transports read (docs/guide/mavlink-vehicle.md): ``tcp:H:P`` (the runner connects, so MAVSDK
serves ``tcpin://H:P``), ``udpin:H:P`` or ``udp:H:P`` (the runner listens: ``udpout://H:P``),
``udpout:H:P`` (the runner sends to the vehicle: ``udpin://H:P``).

What it is, in MAVSDK's idioms only: ``Configuration.create_with_component_type(AUTOPILOT)``
(system 1, ``MAV_COMP_ID_AUTOPILOT1``, a HEARTBEAT a second from the core),
``server_component()``, and the server plugins of the example: ``ParamServer`` with two
integers and two floats (``provide_param_int``/``provide_param_float``), ``MissionRawServer``
(the core answers the mission protocol; incoming plans are logged), ``ActionServer`` (armable,
takeoff allowed, the example's flight modes) and ``TelemetryServer`` publishing position, home,
raw GPS and battery once a second. Commands the plugins do not claim are answered, or not, by
the core itself. Nothing of ours is in the loop. SIGTERM/SIGINT or ``--duration`` end it,
exit 0; a bad argument is one line, exit 2.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading

#: the runner's transport (pymavlink's scheme) -> MAVSDK's connection scheme on the vehicle
SCHEMES = {"tcp": "tcpin", "udp": "udpout", "udpin": "udpout", "udpout": "udpin"}
HOME = (47.397742, 8.545594, 488.0)  # the SITL field the reference vehicle uses too
#: the parameters the vehicle provides: name -> value (int or float, MAV_PARAM_TYPE by kind)
PARAMS: dict[str, int | float] = {"MY_INT": 7, "SYS_HITL": 0, "MY_FLOAT": 1.5, "MIS_TAKEOFF_ALT": 2.5}


def mavsdk_url(url: str) -> str:
    """A pymavlink URL (the runner's side) -> MAVSDK's connection URL for the vehicle's side."""
    scheme, _, rest = url.partition(":")
    host, sep, port = rest.rpartition(":")
    if scheme not in SCHEMES or not sep or not port.isdigit():
        raise ValueError(f"--mavlink {url!r}: want tcp:HOST:PORT, udp:HOST:PORT or udpout:HOST:PORT")
    return f"{SCHEMES[scheme]}://{host or '127.0.0.1'}:{port}"


def serve(url: str, stop: threading.Event) -> int:
    """Be the vehicle on ``url`` (MAVSDK's form) until ``stop`` is set."""
    from mavsdk import ComponentType, Configuration, ConnectionResult, Mavsdk
    from mavsdk.plugins.action_server import ActionServer, AllowableFlightModes
    from mavsdk.plugins.mission_raw_server import MissionRawServer
    from mavsdk.plugins.param_server import ParamServer
    from mavsdk.plugins.telemetry_server import (
        Battery,
        FixType,
        GpsInfo,
        Heading,
        Position,
        RawGps,
        TelemetryServer,
        VelocityNed,
    )

    mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.AUTOPILOT))
    result = mavsdk.add_any_connection(url)
    if result != ConnectionResult.SUCCESS:
        print(f"mavsdk_vehicle: {url}: {result.name}", file=sys.stderr)
        return 2
    component = mavsdk.server_component()
    params = ParamServer(component)
    for name, value in PARAMS.items():
        if isinstance(value, int):
            params.provide_param_int(name, value)
        else:
            params.provide_param_float(name, value)
    action = ActionServer(component)
    action.set_allowable_flight_modes(AllowableFlightModes(True, True, True))
    action.set_allow_takeoff(True)
    action.set_armable(True, True)
    missions = MissionRawServer(component)
    missions.subscribe_incoming_mission(
        lambda res, plan: print(f"mavsdk_vehicle: mission {res}: {len(plan.mission_items)} items",
                                file=sys.stderr, flush=True))
    telemetry = TelemetryServer(component)
    lat, lon, alt = HOME
    position = Position(lat, lon, alt, 0.0)
    raw_gps = RawGps(0, lat, lon, alt, float("nan"), float("nan"), 0.0, float("nan"), 0.0,
                     0.0, 0.0, 0.0, 0.0, 0.0)
    print(f"mavsdk_vehicle: MAVSDK {mavsdk.version()} serving {url}", file=sys.stderr, flush=True)
    try:
        while not stop.wait(1.0):
            telemetry.publish_position(position, VelocityNed(0.0, 0.0, 0.0), Heading(0.0))
            telemetry.publish_home(position)
            telemetry.publish_raw_gps(raw_gps, GpsInfo(12, FixType.FIX_3D))
            telemetry.publish_battery(Battery(12.6, 100.0))
    finally:
        mavsdk.destroy()
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mavlink", required=True, help="tcp:HOST:PORT, udp:HOST:PORT or udpout:HOST:PORT")
    ap.add_argument("--duration", type=float, default=600.0, help="seconds before it exits (600)")
    args = ap.parse_args(argv)
    try:
        url = mavsdk_url(args.mavlink)
    except ValueError as exc:
        ap.exit(2, f"mavsdk_vehicle: {exc}\n")
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    timer = threading.Timer(args.duration, stop.set)
    timer.daemon = True
    timer.start()
    try:
        return serve(url, stop)
    finally:
        stop.set()


if __name__ == "__main__":
    sys.exit(main())

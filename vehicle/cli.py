"""Command line: serve a simulated vehicle and print one line per recorded event.

``python -m vehicle --port 5760 --fix-delay 3`` listens like ArduPilot SITL on TCP until
Ctrl-C (or SIGTERM). Received frames are printed only with ``--frames``.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

from .records import Event
from .server import SimVehicle


class _OneLineParser(argparse.ArgumentParser):
    """argparse that reports a usage error on one line and exits with status 2."""

    def error(self, message: str) -> Any:
        self.exit(2, f"{self.prog}: error: {message}\n")


def _positive(text: str) -> float:
    value = float(text)
    if not value > 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be a positive number: {text}")
    return value


def _non_negative(text: str) -> float:
    value = float(text)
    if not value >= 0 or value == float("inf"):
        raise argparse.ArgumentTypeError(f"must be >= 0: {text}")
    return value


def build_parser() -> argparse.ArgumentParser:
    p = _OneLineParser(prog="python -m vehicle",
                       description="Simulated ArduCopter autopilot on TCP (like SITL).")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (127.0.0.1)")
    p.add_argument("--port", type=int, default=5760, help="TCP port, 0 picks one (5760)")
    p.add_argument("--sysid", type=int, default=1, help="MAVLink system id (1)")
    p.add_argument("--fix-delay", type=_non_negative, default=0.0, metavar="S",
                   help="seconds before the GPS reports a fix (0)")
    p.add_argument("--no-fix", action="store_true", help="never report a GPS fix")
    p.add_argument("--climb-rate", type=_positive, default=20.0, metavar="M_S")
    p.add_argument("--descent-rate", type=_positive, default=20.0, metavar="M_S")
    p.add_argument("--telemetry-hz", type=_positive, default=4.0, metavar="HZ")
    p.add_argument("--home", default="35.771332,-78.674421,0", metavar="LAT,LON[,ALT]",
                   help="home position (the description's Raleigh sample)")
    p.add_argument("--frames", action="store_true", help="also print every received frame")
    return p


def format_event(event: Event, t0: float) -> str:
    """One printable line for ``event`` (time relative to ``t0``)."""
    detail = " ".join(f"{k}={v}" for k, v in event.detail.items())
    return f"{event.t - t0:9.3f} {event.kind:<10} {detail}".rstrip()


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        parts = [float(x) for x in args.home.split(",")]
        if len(parts) not in (2, 3):
            raise ValueError
    except ValueError:
        parser.error(f"--home must be LAT,LON[,ALT]: {args.home}")
    if not 0 <= args.port <= 65535:
        parser.error(f"--port must be 0..65535: {args.port}")
    t0 = time.monotonic()

    def show(event: Event) -> None:
        if event.kind != "frame" or args.frames:
            print(format_event(event, t0), flush=True)

    try:
        vehicle = SimVehicle(
            on_event=show, sysid=args.sysid, gps_fix_delay=args.fix_delay,
            fix_withheld=args.no_fix, climb_rate=args.climb_rate,
            descent_rate=args.descent_rate, telemetry_hz=args.telemetry_hz,
            home_lat=parts[0], home_lon=parts[1], home_alt=parts[2] if len(parts) > 2 else 0.0,
        )
        vehicle.start(args.host, args.port)
    except (ValueError, OSError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    print(f"vehicle sysid {args.sysid} listening on {vehicle.url}", flush=True)
    done = threading.Event()
    if threading.current_thread() is threading.main_thread():
        signal.signal(signal.SIGTERM, lambda *_: done.set())
    try:
        while not done.wait(0.2):
            pass
    except KeyboardInterrupt:
        pass
    finally:
        vehicle.close()
    return 0

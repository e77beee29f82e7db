"""Command line: serve a simulated vehicle and print one line per recorded event.

``mcp-vehicle --listen 127.0.0.1:5760 --fix-delay 3`` listens like ArduPilot SITL on
TCP until ``--duration`` (exit 0) or Ctrl-C or SIGTERM (exit 130 or 143: 128 + the signal's
number, the tools' one convention, docs/grammar.md); ``--udp-out 127.0.0.1:14550`` also
sends telemetry there over UDP (SITL's ``--out``), ``--udp-in 127.0.0.1:14551`` listens on
UDP; ``--record FILE`` writes one JSON line per request with the vehicle's answer. Received
frames are printed only with ``-v``; ``-q`` prints none of the events. ``--help`` lists where
the vehicle differs from ArduCopter.

The options follow the tools' one grammar (docs/grammar.md); this package imports nothing of
the project's, so the grammar's pieces (``traceio.grammar``) are repeated here, and
tests/tools/test_grammar.py holds them to the same table. ``--host``, ``--port`` and
``--frames`` are kept as hidden aliases that warn once.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

from .recordfile import RecordFile
from .records import Event
from .server import SimVehicle
from .udp import parse_hostport

DIFFERENCES = """\
How it answers, as ArduCopter 4.x (ArduPilot's GCS_MAVLink and AP_Mission sources):
  - mission upload: MISSION_COUNT, then the vehicle asks for each item with MISSION_REQUEST
    (as ArduPilot does; --mission-request-int asks with MISSION_REQUEST_INT), accepts
    MISSION_ITEM or MISSION_ITEM_INT, ends with MISSION_ACK. A MISSION_ITEM whose latitude
    is not in degrees (a degE7 integer sent as degrees) gets MAV_MISSION_INVALID_PARAM5_X
    and the same item is asked for again; a bad MISSION_ITEM_INT ends the upload with its
    code; a wrong seq gets MAV_MISSION_INVALID_SEQUENCE; 1 s without the item: asked again;
    8 s: MAV_MISSION_OPERATION_CANCELLED. Unrequested items are REFUSED (MISSION_ACK
    MAV_MISSION_ERROR), as ArduCopter refuses them.
  - download: MISSION_REQUEST_LIST / MISSION_REQUEST_INT / MISSION_REQUEST; item 0 is home.
  - MAV_CMD_MISSION_START or mode AUTO flies the mission (needs a NAV_TAKEOFF first when
    armed on the ground), with MISSION_CURRENT and MISSION_ITEM_REACHED.
  - readiness: HOME_POSITION (at the first fix, every 5 s, on request), AUTOPILOT_VERSION
    (4.5.7), EKF_STATUS_REPORT and SYS_STATUS pre-arm/GPS health only with a 3D fix,
    EXTENDED_SYS_STATE; SET_MESSAGE_INTERVAL and REQUEST_DATA_STREAM set the rates.
  - GUIDED: SET_POSITION_TARGET_LOCAL_NED / GLOBAL_INT (position or velocity; ignored
    outside GUIDED), DO_REPOSITION, CONDITION_YAW, DO_CHANGE_SPEED.
  - parameters: a subset of ArduCopter's table with its types; PARAM_SET of an unknown name
    is ignored (no PARAM_VALUE). Commands it does not handle: MAV_RESULT_UNSUPPORTED.
Where it differs from ArduCopter:
  - arming needs only a 3D fix and a mode other than AUTO/RTL/LAND; no other pre-arm check.
  - climb, descent and horizontal speeds are fast by default (20, 20, 50 m/s); RTL flies
    home at the current altitude (no RTL_ALT climb) and lands.
  - only the MISSION mission type is stored (fence and rally get MAV_MISSION_UNSUPPORTED);
    CONDITION_* and NAV_DELAY items complete at once; at most 700 items.
  - a peer that speaks only MAVLink 1 is answered in MAVLink 1 (ArduPilot sends what
    SERIALn_PROTOCOL says); --mavlink1 starts every link in MAVLink 1.
  - over UDP a peer is known once it has sent a frame (--udp-out destinations get
    telemetry from the start).
  - every stream runs at --telemetry-hz from the start (as if SRn_* were set), and rates are
    the vehicle's, not per link; attitude is level, yaw turns at once.
  - MAVFTP: every request gets a NAK (no files, not even @PARAM/param.pck), so clients fall
    back to PARAM_REQUEST_LIST; FTP, fence, rally and attitude targets are not advertised.
  - 32 parameters, of which only GUID_TIMEOUT changes how it flies.
"""


#: traceio.grammar.EXIT_CODES, repeated (vehicle imports nothing of ours; the grammar test compares them)
EXIT_CODES = ("exit codes: 0 ok, 1 findings or failures, 2 usage or setup error (one line on stderr),\n"
              "  130 interrupted (128 + the signal's number: 143 for SIGTERM)")


def _version() -> str:
    """``spec.about.__version__``, read from its file beside this package (the vehicle imports
    nothing of ours; the installed distribution's metadata would name another checkout's
    version under PYTHONPATH, or none from an unpacked sdist)."""
    import ast
    from pathlib import Path

    try:
        tree = ast.parse((Path(__file__).resolve().parents[1] / "spec" / "about.py").read_text(encoding="utf-8"))
    except (OSError, SyntaxError):
        return "0+unknown"
    for node in tree.body:
        if isinstance(node, ast.Assign) and any(getattr(t, "id", "") == "__version__" for t in node.targets):
            return str(ast.literal_eval(node.value))
    return "0+unknown"


class _Deprecated(argparse.Action):
    """An old spelling (traceio.grammar's, repeated): sets the value, warns once on stderr."""

    def __init__(self, option_strings: Any, dest: str, new: str = "", **kw: Any) -> None:
        self.new = new
        super().__init__(option_strings, dest, **kw)

    def __call__(self, parser: argparse.ArgumentParser, ns: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        print(f"{parser.prog}: warning: {option_string} is deprecated; use {self.new}", file=sys.stderr)
        setattr(ns, self.dest, self.const if self.nargs == 0 else values)


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


def _hostport(text: str) -> tuple[str, int]:
    try:
        return parse_hostport(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def build_parser() -> argparse.ArgumentParser:
    prog = "mcp-vehicle"  # also under python -m mcp_conform.vehicle: one name for one tool
    p = _OneLineParser(prog=prog,
                       description="Simulated ArduCopter autopilot on TCP and UDP (like SITL).",
                       epilog=DIFFERENCES + "--duration is its normal end (exit 0); Ctrl-C or SIGTERM stops it "
                       "too: exit 130 or 143.\n"
                       + EXIT_CODES, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"{prog} {_version()}",
                   help="print the version and exit")
    p.add_argument("--listen", type=_hostport, default=("127.0.0.1", 5760), metavar="HOST:PORT",
                   help="where to listen on TCP; port 0 picks one (127.0.0.1:5760)")
    p.add_argument("--host", action=_Deprecated, new="--listen HOST:PORT", default=argparse.SUPPRESS,
                   help=argparse.SUPPRESS)
    p.add_argument("--port", action=_Deprecated, new="--listen HOST:PORT", type=int, default=argparse.SUPPRESS,
                   help=argparse.SUPPRESS)
    p.add_argument("--no-tcp", action="store_true", help="do not listen on TCP")
    p.add_argument("--udp-out", action="append", default=[], type=_hostport,
                   metavar="HOST:PORT",
                   help="send telemetry there over UDP from one socket that answers whoever "
                        "writes to it, as SITL's --out (repeatable); a ground station "
                        "listens with udpin:HOST:PORT")
    p.add_argument("--udp-in", type=_hostport, metavar="HOST:PORT",
                   help="listen on UDP and answer each sender; a ground station sends with "
                        "udpout:HOST:PORT")
    p.add_argument("--record", metavar="FILE",
                   help="write one JSON line per request (command, mode, mission item...) "
                        "with the vehicle's answer and why")
    p.add_argument("--mavlink1", action="store_true",
                   help="speak MAVLink 1 on every link from the start")
    p.add_argument("--frame-per-datagram", action="store_true",
                   help="over UDP, one MAVLink frame per datagram (default: a turn's frames "
                        "together, as SITL sends them); for ground stations that read one frame "
                        "per datagram, like seed 001's programs")
    p.add_argument("--mission-request-int", action="store_true",
                   help="ask for mission items with MISSION_REQUEST_INT, not MISSION_REQUEST")
    p.add_argument("--sysid", type=int, default=1, help="MAVLink system id (1)")
    p.add_argument("--fix-delay", type=_non_negative, default=0.0, metavar="S",
                   help="seconds before the GPS reports a fix (0)")
    p.add_argument("--no-fix", action="store_true", help="never report a GPS fix")
    p.add_argument("--climb-rate", type=_positive, default=20.0, metavar="M_S")
    p.add_argument("--descent-rate", type=_positive, default=20.0, metavar="M_S")
    p.add_argument("--telemetry-hz", type=_positive, default=4.0, metavar="HZ")
    p.add_argument("--home", default="35.771332,-78.674421,96", metavar="LAT,LON[,ALT]",
                   help="home position, ALT in m above mean sea level (the description's "
                        "Raleigh sample, 96 m)")
    p.add_argument("--duration", type=_positive, metavar="S", help="stop after S seconds (default: at Ctrl-C)")
    verbosity = p.add_mutually_exclusive_group()
    verbosity.add_argument("-v", "--verbose", action="store_true", help="also print every received frame")
    verbosity.add_argument("-q", "--quiet", action="store_true", help="print no events, only where it listens")
    p.add_argument("--frames", action=_Deprecated, new="-v", dest="verbose", nargs=0, const=True,
                   default=argparse.SUPPRESS, help=argparse.SUPPRESS)
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
    host, port = args.listen
    host, port = getattr(args, "host", host), getattr(args, "port", port)
    if not 0 <= port <= 65535:
        parser.error(f"--port must be 0..65535: {port}")
    if args.no_tcp and not (args.udp_out or args.udp_in):
        parser.error("--no-tcp needs --udp-out or --udp-in")
    t0 = time.monotonic()
    try:
        record = open(args.record, "w", encoding="utf-8") if args.record else None  # noqa: SIM115
    except OSError as exc:
        print(f"{parser.prog}: error: cannot write --record {args.record}: {exc.strerror}",
              file=sys.stderr)
        return 2
    writer = RecordFile(record, t0) if record is not None else None

    def show(event: Event) -> None:
        if writer is not None:
            writer(event)
        if args.quiet:
            return
        if event.kind != "frame" or args.verbose:
            print(format_event(event, t0), flush=True)

    stop: list[int] = []  # a flag the handler appends to: a signal handler takes no lock
    if threading.current_thread() is threading.main_thread():
        # SIGINT too, explicitly: a process started in the background by a non-interactive
        # shell inherits SIGINT ignored, and Ctrl-C must still stop it. Before the vehicle starts:
        # once it beats a peer may act and stop it (a loaded CI host's SIGTERM came before the
        # handlers were in place: exit -15); from then on a signal is an exit 130 or 143
        for sig in (signal.SIGTERM, signal.SIGINT):
            signal.signal(sig, lambda signum, _frame: stop.append(signum))
    try:
        vehicle = SimVehicle(
            on_event=show, sysid=args.sysid, gps_fix_delay=args.fix_delay,
            fix_withheld=args.no_fix, climb_rate=args.climb_rate,
            descent_rate=args.descent_rate, telemetry_hz=args.telemetry_hz,
            home_lat=parts[0], home_lon=parts[1], home_alt=parts[2] if len(parts) > 2 else 0.0,
            mission_request_int=args.mission_request_int,
        )
        vehicle.start(host, None if args.no_tcp else port, udp_out=args.udp_out,
                      udp_in=args.udp_in, mavlink1=args.mavlink1,
                      frame_per_datagram=args.frame_per_datagram)
    except (ValueError, OSError) as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        if record is not None:
            record.close()
        return 2
    where = [] if args.no_tcp else [vehicle.url]
    if vehicle.udp_out_port is not None:
        where += [f"udp-out {h}:{p} (from port {vehicle.udp_out_port})" for h, p in args.udp_out]
    if args.udp_in is not None:
        where.append(f"udp-in {vehicle.udp_in_url.removeprefix('udpout:')}")
    print(f"vehicle sysid {args.sysid} listening on {', '.join(where)}", flush=True)
    deadline = None if args.duration is None else time.monotonic() + args.duration
    try:
        while not stop and (deadline is None or time.monotonic() < deadline):
            time.sleep(0.1)
    except KeyboardInterrupt:  # SIGINT as Python's own exception: an interrupt all the same
        stop.append(signal.SIGINT)
    finally:
        vehicle.close()
        if record is not None:
            record.close()
    return 128 + int(stop[0]) if stop else 0

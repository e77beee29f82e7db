"""The reference ground station of ``--protocol mavlink --role gcs``: a small pymavlink program
that does what a ground station does, once, as mavlink.io's microservice pages say.

    mcp-node --protocol mavlink gcs URL [--mission FILE] [--param NAME=VALUE]
             [--command ID[,P1,...,P7]] [--linger S]

``URL`` is pymavlink's (``tcp:HOST:PORT``, ``udpin:HOST:PORT``, ``udpout:HOST:PORT``: the
runner's ``{mavlink}``). In order, it

1. sends its HEARTBEAT every second from the start (MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID;
   system 255, component MAV_COMP_ID_MISSIONPLANNER: MAV-HB-2, -4, -5, -7) and waits for a
   vehicle's (its target: MAV-CMD-16);
2. uploads the mission of ``--mission`` (a QGC WPL 110 file; default: home, takeoff and two
   waypoints around the vehicle) with the handshake of https://mavlink.io/en/services/mission.html:
   MISSION_COUNT, each MISSION_ITEM_INT (degE7) the vehicle requests, until its MISSION_ACK
   (but MAV_MISSION_INVALID_SEQUENCE, ArduPilot's recoverable NACK of an item out of
   sequence: the vehicle's requests still answered, E-1); the message awaiting an answer
   resent after 1.5 s, at most 5 times ("Timeout (default): 1500 ms", "Retries (max): 5";
   MAV-MIS-20..24, -26);
3. reads every parameter (PARAM_REQUEST_LIST; the indices that did not come read by index:
   MAV-PRM-14, -15), reads the parameter by name, then writes it with PARAM_SET of the type
   the vehicle gave, resent until the PARAM_VALUE comes
   (https://mavlink.io/en/services/parameter.html; MAV-PRM-16, -17);
4. sends the command as COMMAND_LONG (default MAV_CMD_REQUEST_MESSAGE for AUTOPILOT_VERSION),
   resent with ``confirmation`` 1, 2, ... until a COMMAND_ACK for it, at most 5 times, and
   after MAV_RESULT_IN_PROGRESS waits for the final result without resending
   (https://mavlink.io/en/services/command.html; MAV-CMD-6..10, -17); then a COMMAND_INT
   with a position in degE7 (MAV_CMD_DO_SET_ROI_LOCATION at the vehicle: MAV-CMD-18);
5. downloads the mission (MISSION_REQUEST_LIST, MISSION_REQUEST_INT per seq, MISSION_ACK:
   MAV-MIS-25);
6. stays on the link, heartbeating, ``--linger`` seconds (default 5), and exits 0.

Each step's outcome is one line on stderr. The faulty ground stations of the tests
(tests/mavlink/faulty_gcs.py) are this class with one thing changed.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import threading
import time
from collections.abc import Sequence
from typing import Any

from pymavlink import mavutil

from mcp_conform.spec import MAVLINK
from mcp_conform.spec.mission import WaypointFileError, load_waypoints

__all__ = ["ReferenceGcs", "build_parser", "main"]

mav: Any = MAVLINK.dialect
PROG = "mcp-node --protocol mavlink gcs"
#: message types of the vehicle each step waits for
UPLOAD_REPLIES = ["MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_ACK"]


class ReferenceGcs:
    """One ground station's session with one vehicle (see the module docstring)."""

    #: seconds before a mission message is resent, and how many times (mavlink.io's recommendation)
    mission_timeout, mission_retries = 1.5, 5
    #: the same for a command and for a parameter write (mavlink.io leaves them to the GCS)
    command_timeout, command_retries = 1.0, 5
    param_timeout, param_retries = 1.0, 5
    #: how long after MAV_RESULT_IN_PROGRESS the final result is awaited (no resend meanwhile)
    in_progress_timeout = 30.0
    #: MAVLink 2 from the first frame (see ``__init__``)
    mavlink2_first = True

    def __init__(self, url: str, log: Any = None) -> None:
        # MAVLink 2 from the first frame: pymavlink starts in MAVLink 1 and, on the first
        # MAVLink 2 frame it hears, replaces its encoder, whose sequence numbers start again
        # at 0 (mavutil.mavfile.auto_mavlink_version; MAV-HB-11 sees the jump)
        if self.mavlink2_first:
            os.environ["MAVLINK20"] = "1"
        else:
            os.environ.pop("MAVLINK20", None)
        mavutil.set_dialect("ardupilotmega")
        self.conn = mavutil.mavlink_connection(url, source_system=255, source_component=mav.MAV_COMP_ID_MISSIONPLANNER,
                                               autoreconnect=False)
        self.log = log or (lambda text: print(text, file=sys.stderr, flush=True))
        self.target = (0, 0)
        self.position = (0, 0)  # the vehicle's GLOBAL_POSITION_INT lat, lon (degE7)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._beater = threading.Thread(target=self._beat, daemon=True)

    # -- hooks a faulty ground station changes ----------------------------------------------
    def heartbeat(self) -> Any | None:
        return self.conn.mav.heartbeat_encode(mav.MAV_TYPE_GCS, mav.MAV_AUTOPILOT_INVALID, 0, 0, mav.MAV_STATE_ACTIVE)

    def item_for(self, seq: int, items: list[Any]) -> Any:
        """The item that answers a request for ``seq``."""
        return items[seq]

    def confirmation(self, transmission: int) -> int:
        return min(transmission, 255)

    def answers(self, ack: Any, command: int) -> bool:
        """A COMMAND_ACK that answers ``command``."""
        return bool(ack.command == command)

    def to_read(self, got: dict[int, Any], count: int, order: list[int]) -> list[int]:
        """The indices to read one by one after a list (``order``: as they came): the missing."""
        return sorted(set(range(count)) - set(got))

    def ends_upload(self, ack: Any) -> bool:
        """A MISSION_ACK ends the upload, whatever its result (MAV-MIS-24: "An error can be
        signaled in response to any request using a MISSION_ACK ... This must cancel the
        operation"), but MAV_MISSION_INVALID_SEQUENCE: an item out of sequence is recoverable
        ("Out-of-sequence messages in mission upload/download are recoverable, and are not
        treated as errors", https://mavlink.io/en/services/mission.html), ArduPilot's answer to
        one (a copy of an item that came late) before it re-requests the item it expects, the
        upload going on ("A MISSION_ACK returning an error value (NACK) does not terminate the
        upload", the same page's ArduPilot section; the spec's erratum E-1). Ended there, the
        ground station would leave the vehicle mid-upload, re-requesting an item no one sends."""
        return bool(ack.type != mav.MAV_MISSION_INVALID_SEQUENCE)

    # -- the link -----------------------------------------------------------------------------
    def send(self, msg: Any) -> None:
        with self._lock:
            self.conn.mav.send(msg)

    def _beat(self) -> None:
        while not self._stop.is_set():
            hb = self.heartbeat()
            if hb is not None:
                self.send(hb)
            self._stop.wait(1.0)

    def now(self) -> float:
        """The clock of its timeouts (the simulator's seam: ``sim.gcs.SimGcsSeam``)."""
        return time.monotonic()

    def recv(self, types: list[str], timeout: float, where: Any = None) -> Any | None:
        """The next message of ``types`` from the vehicle (and ``where(msg)``) within ``timeout`` s."""
        end = self.now() + timeout
        while (left := end - self.now()) > 0:
            msg = self.conn.recv_match(type=types, blocking=True, timeout=min(left, 0.2))
            if msg is None or (self.target[0] and msg.get_srcSystem() != self.target[0]):
                continue
            if where is None or where(msg):
                return msg
        return None

    def encode(self, name: str, **fields: Any) -> Any:
        """The message ``name`` to the vehicle, in the dialect the link speaks now. A MAVLink 1
        link (pymavlink stays in MAVLink 1 while the vehicle never sends MAVLink 2) carries no
        extension fields: they are left out (``mission_type``: MAVLink 1 implies MISSION)."""
        link = sys.modules[type(self.conn.mav).__module__]
        if link is not mav:
            kind = f"MAVLink_{name.lower()}_message"
            carried = set(getattr(link, kind).fieldnames)
            extensions = set(getattr(mav, kind).fieldnames) - carried
            fields = {k: v for k, v in fields.items() if k not in extensions}
        return getattr(self.conn.mav, name.lower() + "_encode")(*self.target, **fields)

    # -- the steps ----------------------------------------------------------------------------
    def connect(self, timeout: float = 10.0) -> bool:
        self._beater.start()
        hb = self.recv(["HEARTBEAT"], timeout, lambda m: m.type != mav.MAV_TYPE_GCS)
        if hb is None:
            self.log("no vehicle HEARTBEAT")
            return False
        self.target = (hb.get_srcSystem(), hb.get_srcComponent())
        pos = self.recv(["GLOBAL_POSITION_INT"], 3.0)
        self.position = (pos.lat, pos.lon) if pos is not None else (0, 0)
        self.log(f"vehicle {self.target[0]}/{self.target[1]}")
        return True

    def plan(self, path: str | None) -> list[Any]:
        """The mission's MISSION_ITEM_INTs: from a QGC WPL 110 file (degrees to degE7), or home,
        takeoff and two waypoints 20 m apart around the vehicle."""
        if path is not None:
            rows = [(w.frame, w.command, w.param1, w.param2, w.param3, w.param4, w.x, w.y, w.z)
                    for w in load_waypoints(path)]
        else:
            lat, lon = (self.position[0] / 1e7, self.position[1] / 1e7) if any(self.position) else (35.7713, -78.6744)
            rel = mav.MAV_FRAME_GLOBAL_RELATIVE_ALT
            rows = [(mav.MAV_FRAME_GLOBAL, mav.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, lat, lon, 0),
                    (rel, mav.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, 10),
                    (rel, mav.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, lat + 0.00018, lon, 10),
                    (rel, mav.MAV_CMD_NAV_WAYPOINT, 0, 0, 0, 0, lat + 0.00018, lon + 0.00022, 10)]
        return [self.encode("MISSION_ITEM_INT", seq=seq, frame=f, command=c, current=0, autocontinue=1, param1=p1,
                            param2=p2, param3=p3, param4=p4, x=round(x * 1e7), y=round(y * 1e7), z=z,
                            mission_type=mav.MAV_MISSION_TYPE_MISSION)
                for seq, (f, c, p1, p2, p3, p4, x, y, z) in enumerate(rows)]

    def upload(self, items: list[Any]) -> bool:
        """MISSION_COUNT, then each requested item, until the vehicle's MISSION_ACK (resends bounded)."""
        last = self.encode("MISSION_COUNT", count=len(items), mission_type=mav.MAV_MISSION_TYPE_MISSION)
        self.send(last)
        resends = 0
        for _ in range(4 * len(items) + 4 * self.mission_retries + 4):
            msg = self.recv(UPLOAD_REPLIES, self.mission_timeout)
            if msg is None:
                if resends >= self.mission_retries:
                    self.log(f"upload: no answer after {resends} resends: given up")
                    return False
                resends += 1
                self.send(last)
                continue
            if msg.get_type() == "MISSION_ACK":
                ok = msg.type == mav.MAV_MISSION_ACCEPTED
                if self.ends_upload(msg):
                    self.log(f"upload: MISSION_ACK {mav.enums['MAV_MISSION_RESULT'][msg.type].name}")
                    return ok
                continue
            if 0 <= msg.seq < len(items):
                last, resends = self.item_for(msg.seq, items), 0
                self.send(last)
        self.log("upload: too many exchanges: given up")
        return False

    def fetch_params(self) -> dict[int, Any]:
        """PARAM_REQUEST_LIST, every PARAM_VALUE until none comes for a timeout, then each
        missing index read by index (resent), as QGroundControl does (MAV-PRM-14, MAV-PRM-15:
        any order, duplicates counted once); the PARAM_VALUEs by index."""
        self.send(self.encode("PARAM_REQUEST_LIST"))
        got: dict[int, Any] = {}
        count, order = None, []
        for _ in range(65536):
            if (msg := self.recv(["PARAM_VALUE"], self.param_timeout)) is None:
                break
            if msg.param_index < msg.param_count:  # 65535: the answer to a set or a read by name
                count, got[msg.param_index] = msg.param_count, msg
                order.append(msg.param_index)
        for index in self.to_read(got, count or 0, order):
            read = self.encode("PARAM_REQUEST_READ", param_id=b"", param_index=index)
            for _ in range(1 + self.param_retries):
                self.send(read)
                if (msg := self.recv(["PARAM_VALUE"], self.param_timeout, lambda m, i=index: m.param_index == i)):
                    got[index] = msg
                    break
        self.log(f"params: {len(got)} of {count}")
        return got

    def set_param(self, name: str, value: float) -> bool:
        """PARAM_REQUEST_READ by name (its type), then PARAM_SET until its PARAM_VALUE comes."""
        def named(m: Any) -> bool:
            pid = m.param_id.decode(errors="replace") if isinstance(m.param_id, bytes) else m.param_id
            return bool(pid.rstrip("\0") == name)
        read = self.encode("PARAM_REQUEST_READ", param_id=name.encode(), param_index=-1)
        got = None
        for _ in range(1 + self.param_retries):
            self.send(read)
            if (got := self.recv(["PARAM_VALUE"], self.param_timeout, named)) is not None:
                break
        if got is None:
            self.log(f"param: {name} not read")
            return False
        write = self.encode("PARAM_SET", param_id=name.encode(), param_value=value, param_type=got.param_type)
        for _ in range(1 + self.param_retries):
            self.send(write)
            if (got := self.recv(["PARAM_VALUE"], self.param_timeout, named)) is not None:
                self.log(f"param: {name} = {got.param_value:g}")
                return True
        self.log(f"param: {name}: no PARAM_VALUE: given up")
        return False

    def command(self, command: int, params: Sequence[float]) -> int | None:
        """COMMAND_LONG, resent with confirmation incremented until its final COMMAND_ACK; its result."""
        p = [*params, *[0.0] * (7 - len(params))][:7]
        deadline = None
        for n in range(1 + self.command_retries):
            self.send(self.encode("COMMAND_LONG", command=command, confirmation=self.confirmation(n),
                                  param1=p[0], param2=p[1], param3=p[2], param4=p[3], param5=p[4], param6=p[5],
                                  param7=p[6]))
            timeout = self.command_timeout
            while (ack := self.recv(["COMMAND_ACK"], timeout, lambda m: self.answers(m, command))) is not None:
                if ack.result != mav.MAV_RESULT_IN_PROGRESS:
                    self.log(f"command {command}: {mav.enums['MAV_RESULT'][ack.result].name}")
                    return int(ack.result)
                deadline = deadline or self.now() + self.in_progress_timeout
                timeout = max(0.0, deadline - self.now())  # in progress: wait, never resend
            if deadline is not None:
                break
        self.log(f"command {command}: no COMMAND_ACK: given up")
        return None

    def command_int(self) -> int | None:
        """MAV_CMD_DO_SET_ROI_LOCATION at the vehicle's position, as COMMAND_INT (x, y in degE7)."""
        cmd = mav.MAV_CMD_DO_SET_ROI_LOCATION
        msg = self.encode("COMMAND_INT", frame=mav.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, command=cmd, current=0,
                          autocontinue=0, param1=0, param2=0, param3=0, param4=0, x=self.position[0] or 357713320,
                          y=self.position[1] or -786744210, z=10)
        for _ in range(1 + self.command_retries):
            self.send(msg)
            if (ack := self.recv(["COMMAND_ACK"], self.command_timeout, lambda m: m.command == cmd)) is not None:
                return int(ack.result)
        return None

    def download(self) -> int | None:
        """MISSION_REQUEST_LIST, MISSION_REQUEST_INT per seq (each resent on timeout), MISSION_ACK."""
        def ask(msg: Any, types: list[str], where: Any = None) -> Any | None:
            for _ in range(1 + self.mission_retries):
                self.send(msg)
                if (got := self.recv(types, self.mission_timeout, where)) is not None:
                    return got
            return None
        kind = mav.MAV_MISSION_TYPE_MISSION
        count = ask(self.encode("MISSION_REQUEST_LIST", mission_type=kind), ["MISSION_COUNT"])
        if count is None:
            self.log("download: no MISSION_COUNT: given up")
            return None
        for seq in range(count.count):
            req = self.encode("MISSION_REQUEST_INT", seq=seq, mission_type=kind)
            if ask(req, ["MISSION_ITEM_INT"], lambda m, s=seq: m.seq == s) is None:
                self.log(f"download: item {seq} never came: given up")
                return None
        self.send(self.encode("MISSION_ACK", type=mav.MAV_MISSION_ACCEPTED, mission_type=kind))
        self.log(f"download: {count.count} items")
        return int(count.count)

    def close(self) -> None:
        self._stop.set()
        if self._beater.is_alive():
            self._beater.join(timeout=2.0)
        self.conn.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mcp-node --protocol mavlink",
                                description="The reference ground station (gcs) of --protocol mavlink; "
                                            "'vehicle ARGS' (or no role) runs mcp-vehicle.")
    p.add_argument("role", choices=["gcs"], help="gcs: the reference ground station")
    p.add_argument("url", help="the vehicle's pymavlink URL: tcp:HOST:PORT, udpin:HOST:PORT, udpout:HOST:PORT")
    p.add_argument("--mission", metavar="FILE", help="QGC WPL 110 file to upload (default: four items around the vehicle)")
    p.add_argument("--param", default="RTL_ALT=1500", metavar="NAME=VALUE", help="the parameter to set (default RTL_ALT=1500)")
    p.add_argument("--command", default=f"{mav.MAV_CMD_REQUEST_MESSAGE},{mav.MAVLINK_MSG_ID_AUTOPILOT_VERSION}",
                   metavar="ID[,P1,...]", help="the COMMAND_LONG to send (default: REQUEST_MESSAGE AUTOPILOT_VERSION)")
    p.add_argument("--linger", type=float, default=5.0, metavar="S", help="seconds on the link after the work (default 5)")
    return p


def main(argv: Sequence[str] | None = None, gcs_class: type[ReferenceGcs] = ReferenceGcs) -> int:
    """``mcp-node --protocol mavlink gcs ...``; any other first word is ``mcp-vehicle``'s."""
    args_in = list(sys.argv[1:] if argv is None else argv)
    if not args_in or args_in[0] != "gcs":
        from mcp_conform.vehicle.cli import main as vehicle_main

        return int(vehicle_main(args_in[1:] if args_in[:1] == ["vehicle"] else args_in))
    ns = build_parser().parse_args(args_in)
    name, _, text = ns.param.partition("=")
    try:
        value, command = float(text), [float(v) for v in ns.command.split(",")]
    except ValueError:
        print(f"{PROG}: error: --param NAME=VALUE and --command ID[,P1,...] take numbers", file=sys.stderr)
        return 2
    if not name or not math.isfinite(value) or not command:
        print(f"{PROG}: error: --param NAME=VALUE: a name and a finite value", file=sys.stderr)
        return 2
    try:
        gcs = gcs_class(ns.url)
    except (OSError, ValueError) as exc:
        print(f"{PROG}: error: {ns.url}: cannot connect: {exc}", file=sys.stderr)
        return 2
    try:
        if not gcs.connect():
            return 1
        try:
            items = gcs.plan(ns.mission)
        except WaypointFileError as exc:
            print(f"{PROG}: error: {exc}", file=sys.stderr)
            return 2
        gcs.upload(items)
        gcs.fetch_params()
        gcs.set_param(name, value)
        gcs.command(int(command[0]), command[1:])
        gcs.command_int()
        gcs.download()
        end = time.monotonic() + max(0.0, ns.linger)
        while time.monotonic() < end:  # the link read, the heartbeat going
            gcs.conn.recv_match(blocking=True, timeout=0.2)
        return 0
    except KeyboardInterrupt:
        return 130
    finally:
        gcs.close()


if __name__ == "__main__":
    raise SystemExit(main())

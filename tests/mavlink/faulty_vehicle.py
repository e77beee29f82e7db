"""A faulty vehicle for the tests: our reference vehicle (``mcp-vehicle``) behind a TCP proxy
that changes one thing, so that ``mcp-conform --protocol mavlink`` must fail exactly the rule
of that one thing. The proxy parses both directions with pymavlink and packs the vehicle's
frames again with sequence numbers of its own (a frame dropped or added leaves no gap for
MAV-HB-11 to see); the runner's frames go through as they came unless a fault rewrites one.

    python tests/mavlink/faulty_vehicle.py --listen HOST:PORT --fault NAME [--duration S]

Faults: none (the proxy alone), no-unsupported-ack (a COMMAND_ACK with MAV_RESULT_UNSUPPORTED
is dropped: MAV-CMD-5), type-gcs (HEARTBEAT.type MAV_TYPE_GCS: MAV-HB-3; MAV_AUTOPILOT_INVALID
would also make its ArduPilot item 0 count against MAV-MIS-9, E-3), double-ack (every
COMMAND_ACK twice: MAV-CMD-3), acts-for-other-system (a command for another system is handed
to the vehicle as its own: MAV-CMD-14), acts-for-other-component (a command for another
component of the vehicle's system is handed to the vehicle as its own, as ArduPilot 4.x's
``MAVLink_routing`` processes one it has no route for: MAV-CMD-14), bad-param-type (every PARAM_VALUE's param_type
MAV_PARAM_TYPE_ENUM_END, no type: MAV-PRM-10), download-param1 (every MISSION_ITEM_INT the
vehicle sends with param1 one more: MAV-MIS-9).
"""

from __future__ import annotations

import argparse
import contextlib
import socket
import subprocess
import sys
import threading
import time

from pymavlink.dialects.v20 import ardupilotmega as mav

from mcp_conform.vehicle.ports import free_port

FAULTS = ("none", "no-unsupported-ack", "type-gcs", "double-ack", "acts-for-other-system",
          "acts-for-other-component", "bad-param-type", "download-param1")
VEHICLE_SYSID = 1
VEHICLE_COMPID = mav.MAV_COMP_ID_AUTOPILOT1


def from_vehicle(msg, fault):
    """The messages the proxy hands the runner for one message of the vehicle."""
    name = msg.get_type()
    if fault == "no-unsupported-ack" and name == "COMMAND_ACK" and msg.result == mav.MAV_RESULT_UNSUPPORTED:
        return []
    if fault == "type-gcs" and name == "HEARTBEAT":
        msg.type = mav.MAV_TYPE_GCS
    if fault == "double-ack" and name == "COMMAND_ACK":
        return [msg, msg]
    if fault == "download-param1" and name == "MISSION_ITEM_INT":
        msg.param1 += 1.0
    if fault == "bad-param-type" and name == "PARAM_VALUE":
        msg.param_type = max(mav.enums["MAV_PARAM_TYPE"])  # MAV_PARAM_TYPE_ENUM_END: no type
    return [msg]


def from_runner(msg, raw, fault):
    """The bytes the proxy hands the vehicle for one frame of the runner."""
    command = msg.get_type() in ("COMMAND_LONG", "COMMAND_INT")
    other_system = fault == "acts-for-other-system" and command and msg.target_system not in (0, VEHICLE_SYSID)
    other_component = (fault == "acts-for-other-component" and command and msg.target_system == VEHICLE_SYSID
                       and msg.target_component not in (0, VEHICLE_COMPID))
    if other_system or other_component:
        enc = mav.MAVLink(None, srcSystem=msg.get_srcSystem(), srcComponent=msg.get_srcComponent())
        enc.seq = msg.get_seq()
        msg.target_system, msg.target_component = VEHICLE_SYSID, VEHICLE_COMPID
        return bytes(msg.pack(enc))
    return raw


def pump(src, dst, fault, vehicle_side, stop):
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
    encoders = {}
    while not stop.is_set():
        try:
            data = src.recv(65536)
        except OSError:
            break
        if not data:
            break
        out = bytearray()
        for msg in parser.parse_buffer(data) or []:
            raw = bytes(msg.get_msgbuf())
            if msg.get_type() == "BAD_DATA":
                out += raw
            elif vehicle_side:
                for m in from_vehicle(msg, fault):
                    key = (m.get_srcSystem(), m.get_srcComponent())
                    enc = encoders.setdefault(key, mav.MAVLink(None, srcSystem=key[0], srcComponent=key[1]))
                    out += m.pack(enc)
                    enc.seq = (enc.seq + 1) % 256
            else:
                out += from_runner(msg, raw, fault)
        try:
            dst.sendall(bytes(out))
        except OSError:
            break
    stop.set()
    for s in (src, dst):
        with contextlib.suppress(OSError):
            s.shutdown(socket.SHUT_RDWR)


def main() -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--listen", required=True)
    p.add_argument("--fault", choices=FAULTS, default="none")
    p.add_argument("--duration", type=float, default=600.0)
    ns = p.parse_args()
    host, port = ns.listen.rsplit(":", 1)
    vport = free_port(kind=socket.SOCK_STREAM)
    vehicle = subprocess.Popen([sys.executable, "-m", "mcp_conform.vehicle", "-q", "--listen", f"127.0.0.1:{vport}",
                                "--sysid", str(VEHICLE_SYSID), "--duration", str(ns.duration)])
    server = socket.create_server((host, int(port)))
    server.settimeout(0.5)
    end = time.monotonic() + ns.duration
    try:
        while time.monotonic() < end and vehicle.poll() is None:
            try:
                client, _ = server.accept()
            except TimeoutError:
                continue
            upstream = None
            while upstream is None and time.monotonic() < end:
                try:
                    upstream = socket.create_connection(("127.0.0.1", vport), timeout=1.0)
                except OSError:
                    time.sleep(0.1)
            if upstream is None:
                break
            upstream.settimeout(None)
            stop = threading.Event()
            threads = [threading.Thread(target=pump, args=(upstream, client, ns.fault, True, stop), daemon=True),
                       threading.Thread(target=pump, args=(client, upstream, ns.fault, False, stop), daemon=True)]
            for t in threads:
                t.start()
            while not stop.wait(0.5) and time.monotonic() < end:
                pass
    finally:
        vehicle.terminate()
        vehicle.wait(5)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""A fragile vehicle for ``mcp-fuzz --protocol mavlink``'s tests: our reference vehicle
(``mcp-vehicle``) behind a TCP proxy that breaks in one way, which the fuzzer must find,
confirm, minimise and name by its rule.

    python tests/fuzz/fragile_vehicle.py --listen HOST:PORT --fault NAME [--duration S]

Faults: none (the proxy alone); param16-crash (a PARAM_SET whose param_id fills its 16 bytes
with no NUL -- legal, MAV-PRM-9 -- kills the process, as a C vehicle that strcpy's the name
would); mission-seq-hang (a MISSION_ITEM_INT whose seq is at or past the count of the last
MISSION_COUNT stops the vehicle's HEARTBEAT for good, while it goes on answering: MAV-MIS-4,
MAV-HB-1); ignores-clear-all (MISSION_CLEAR_ALL never reaches the vehicle, so it is never
answered: MAV-MIS-13); deaf-after-bad-crc (after a frame with a bad checksum nothing more
reaches the vehicle, which beats on: MAV-HB-14, "the next good frame is handled");
slow-heartbeat (one HEARTBEAT of four passed on, whatever is sent: MAV-HB-1 with no input to
blame). The proxy parses the ground station's frames with pymavlink and passes
every byte on as it came (but the frames it drops); the vehicle's frames pass as they came but
for the HEARTBEATs it withholds.
"""

from __future__ import annotations

import contextlib
import os
import socket
import subprocess
import sys
import threading

from pymavlink.dialects.v20 import ardupilotmega as mav

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2]))  # run as a script
from tests.mavlink.vehicle_proxy import serve  # noqa: E402

FAULTS = ("none", "param16-crash", "mission-seq-hang", "ignores-clear-all", "deaf-after-bad-crc",
          "slow-heartbeat")


class State:
    def __init__(self, fault: str, vehicle: subprocess.Popen) -> None:
        self.fault, self.vehicle = fault, vehicle
        self.count: int | None = None
        self.silent = False  # HEARTBEATs withheld
        self.deaf = False  # nothing more passed on to the vehicle
        self.beats = 0  # the vehicle's HEARTBEATs so far


def param_id(msg) -> bytes:
    """PARAM_SET.param_id as its bytes are on the wire (pymavlink decodes it as text)."""
    raw = bytes(msg.get_msgbuf())
    payload = raw[10:10 + raw[1]] if raw[0] == mav.PROTOCOL_MARKER_V2 else raw[6:6 + raw[1]]
    payload += bytes(max(0, type(msg).unpacker.size - len(payload)))
    return dict(zip(type(msg).ordered_fieldnames, type(msg).unpacker.unpack(payload[:type(msg).unpacker.size]),
                    strict=True))["param_id"]


def from_gcs(msg, state: State) -> None:
    name = msg.get_type()
    if state.fault == "param16-crash" and name == "PARAM_SET":
        pid = param_id(msg)
        if len(pid) == 16 and b"\0" not in pid:
            state.vehicle.kill()
            os._exit(3)
    if state.fault == "mission-seq-hang":
        if name == "MISSION_COUNT":
            state.count = msg.count
        elif name == "MISSION_ITEM_INT" and state.count is not None and msg.seq >= state.count:
            state.silent = True


def pump(src, dst, state: State, vehicle_side: bool, stop: threading.Event) -> None:
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
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
            if not vehicle_side and state.fault == "deaf-after-bad-crc" and msg.get_type() == "BAD_DATA" \
                    and "CRC" in str(msg.reason):
                state.deaf = True
            if msg.get_type() != "BAD_DATA":
                if vehicle_side and msg.get_type() == "HEARTBEAT":
                    state.beats += 1
                    if state.silent or (state.fault == "slow-heartbeat" and state.beats % 4):
                        continue
                if not vehicle_side:
                    from_gcs(msg, state)
                    if state.fault == "ignores-clear-all" and msg.get_type() == "MISSION_CLEAR_ALL":
                        continue
            out += raw
        if not vehicle_side and state.fault != "ignores-clear-all":  # the ground station's bytes as they came
            out = bytearray(data)
        if not vehicle_side and state.deaf:
            continue
        try:
            dst.sendall(bytes(out))
        except OSError:
            break
    stop.set()
    for s in (src, dst):
        with contextlib.suppress(OSError):
            s.shutdown(socket.SHUT_RDWR)


def main() -> int:
    return serve(None, FAULTS, pump, lambda client, vehicle, fault: State(fault, vehicle), ())


if __name__ == "__main__":
    sys.exit(main())

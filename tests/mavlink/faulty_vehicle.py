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
``MAVLink_routing`` processes one it has no route for: MAV-CMD-14), bad-param-type (every
PARAM_VALUE's param_type MAV_PARAM_TYPE_ENUM_END, no type: MAV-PRM-10), download-param1 (every
MISSION_ITEM_INT the vehicle sends with param1 one more: MAV-MIS-9), creates-unknown-param
(a PARAM_SET of a name the vehicle never listed is answered with a PARAM_VALUE of it, and so
are reads of it afterwards: MAV-PRM-11), clear-keeps-plan (MISSION_CLEAR_ALL answered
MAV_MISSION_ACCEPTED by the proxy and never handed on: MAV-MIS-13), out-of-sequence-stalls
(after the vehicle's MAV_MISSION_INVALID_SEQUENCE its requests are dropped until the next
MISSION_COUNT: MAV-MIS-4), ignores-mission-request (the runner's deprecated MISSION_REQUEST is
dropped: MAV-MIS-10), mission-type-lost (mission_type 0 in every mission message the vehicle
sends: MAV-MIS-16), set-current-ignored (MISSION_SET_CURRENT dropped: MAV-MIS-15), untruncated
(the vehicle's MAVLink 2 payloads sent whole, trailing zeros and all: MAV-HB-12), seq-gaps
(every 50th frame's sequence number skipped: MAV-HB-11), abandoned-stays-busy (the vehicle's
MISSION_ACK MAV_MISSION_OPERATION_CANCELLED at the end of an abandoned upload is dropped and
every download refused MAV_MISSION_DENIED until the next MISSION_COUNT, as a vehicle that never
leaves the upload: MAV-MIS-6), clear-ack-type-all (the MISSION_ACK answering MISSION_CLEAR_ALL
carries mission_type MAV_MISSION_TYPE_ALL: MAV-MIS-17).
"""

from __future__ import annotations

import contextlib
import socket
import sys
import threading
from typing import Any

from pymavlink.dialects.v20 import ardupilotmega as mav

sys.path.insert(0, str(__import__("pathlib").Path(__file__).resolve().parents[2]))  # run as a script
from tests.mavlink.vehicle_proxy import serve  # noqa: E402

FAULTS = ("none", "no-unsupported-ack", "type-gcs", "double-ack", "acts-for-other-system",
          "acts-for-other-component", "bad-param-type", "download-param1", "creates-unknown-param",
          "clear-keeps-plan", "out-of-sequence-stalls", "ignores-mission-request", "mission-type-lost",
          "set-current-ignored", "untruncated", "seq-gaps", "abandoned-stays-busy", "clear-ack-type-all")
VEHICLE_SYSID = 1
VEHICLE_COMPID = mav.MAV_COMP_ID_AUTOPILOT1
#: the mission messages that carry a mission_type
MISSION_TYPED = ("MISSION_ACK", "MISSION_COUNT", "MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ITEM",
                 "MISSION_ITEM_INT")


class Proxy:
    """One runner connection: what the faults remember, and the runner's side of the link
    (every frame to the runner is packed here, with the vehicle's sequence numbers)."""

    def __init__(self, client: socket.socket, fault: str) -> None:
        self.client, self.fault = client, fault
        self.lock = threading.Lock()
        self.encoders: dict[tuple[int, int], Any] = {}
        self.frames = 0
        self.names: set[str] = set()  # the parameters the vehicle listed
        self.count = 0
        self.created: dict[str, tuple[float, int]] = {}
        self.stalled = False
        self.busy = False  # abandoned-stays-busy: an upload timed out, the proxy refuses downloads
        self.cleared = False  # clear-ack-type-all: a MISSION_CLEAR_ALL awaits its MISSION_ACK

    def to_runner(self, msgs: list[Any]) -> None:
        with self.lock:
            out = bytearray()
            for m in msgs:
                key = (m.get_srcSystem(), m.get_srcComponent()) if m.get_srcSystem() else (VEHICLE_SYSID,
                                                                                             VEHICLE_COMPID)
                enc = self.encoders.setdefault(key, mav.MAVLink(None, srcSystem=key[0], srcComponent=key[1]))
                self.frames += 1
                if self.fault == "seq-gaps" and self.frames % 50 == 0:
                    enc.seq = (enc.seq + 1) % 256
                raw = bytes(m.pack(enc))
                enc.seq = (enc.seq + 1) % 256
                out += untruncated(raw, m) if self.fault == "untruncated" else raw
            self.client.sendall(bytes(out))


def untruncated(raw: bytes, msg: Any) -> bytes:
    """A MAVLink 2 frame with its payload padded back to the message's full size and the
    checksum computed again (what MAV-HB-12 forbids a sender)."""
    if raw[:1] != bytes([mav.PROTOCOL_MARKER_V2]):
        return raw
    head, payload = bytearray(raw[:10]), raw[10:10 + raw[1]]
    payload = payload + bytes(type(msg).unpacker.size - len(payload))
    head[1] = len(payload)
    crc = mav.x25crc(bytes(head[1:]) + payload)
    crc.accumulate(bytes([type(msg).crc_extra]))
    return bytes(head) + payload + crc.crc.to_bytes(2, "little")


def from_vehicle(msg, proxy):
    """The messages the proxy hands the runner for one message of the vehicle."""
    fault, name = proxy.fault, msg.get_type()
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
    if name == "PARAM_VALUE":
        proxy.names.add(param_name(msg.param_id))
        proxy.count = msg.param_count
    if fault == "out-of-sequence-stalls":
        if name == "MISSION_ACK" and msg.type == mav.MAV_MISSION_INVALID_SEQUENCE:
            proxy.stalled = True
        if proxy.stalled and name in ("MISSION_REQUEST", "MISSION_REQUEST_INT"):
            return []
    if fault == "mission-type-lost" and name in MISSION_TYPED:
        msg.mission_type = mav.MAV_MISSION_TYPE_MISSION
    if fault == "abandoned-stays-busy" and name == "MISSION_ACK" and msg.type == mav.MAV_MISSION_OPERATION_CANCELLED:
        proxy.busy = True
        return []
    if fault == "clear-ack-type-all" and name == "MISSION_ACK" and proxy.cleared:
        proxy.cleared = False
        msg.mission_type = mav.MAV_MISSION_TYPE_ALL
    return [msg]


def param_name(raw: Any) -> str:
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw)
    return text.split("\0", 1)[0]


def from_runner(msg, raw, proxy):
    """The bytes the proxy hands the vehicle for one frame of the runner (the proxy may
    answer the runner itself)."""
    fault, name = proxy.fault, msg.get_type()
    command = name in ("COMMAND_LONG", "COMMAND_INT")
    other_system = fault == "acts-for-other-system" and command and msg.target_system not in (0, VEHICLE_SYSID)
    other_component = (fault == "acts-for-other-component" and command and msg.target_system == VEHICLE_SYSID
                       and msg.target_component not in (0, VEHICLE_COMPID))
    if other_system or other_component:
        enc = mav.MAVLink(None, srcSystem=msg.get_srcSystem(), srcComponent=msg.get_srcComponent())
        enc.seq = msg.get_seq()
        msg.target_system, msg.target_component = VEHICLE_SYSID, VEHICLE_COMPID
        return bytes(msg.pack(enc))
    src = (msg.get_srcSystem(), msg.get_srcComponent())
    if fault == "creates-unknown-param" and name in ("PARAM_SET", "PARAM_REQUEST_READ") and proxy.names:
        key = param_name(msg.param_id)
        if name == "PARAM_SET" and key not in proxy.names:
            proxy.created[key] = (msg.param_value, msg.param_type)
        if key in proxy.created and (name == "PARAM_SET" or msg.param_index == -1):
            value, kind = proxy.created[key]
            proxy.to_runner([mav.MAVLink_param_value_message(key.encode(), value, kind, proxy.count, 65535)])
            return b""
    if fault == "clear-keeps-plan" and name == "MISSION_CLEAR_ALL":
        proxy.to_runner([mav.MAVLink_mission_ack_message(src[0], src[1], mav.MAV_MISSION_ACCEPTED,
                                                         msg.mission_type)])
        return b""
    if fault == "out-of-sequence-stalls" and name == "MISSION_COUNT":
        proxy.stalled = False
    if fault == "abandoned-stays-busy" and name == "MISSION_COUNT":
        proxy.busy = False
    if proxy.busy and name == "MISSION_REQUEST_LIST":
        proxy.to_runner([mav.MAVLink_mission_ack_message(src[0], src[1], mav.MAV_MISSION_DENIED,
                                                         msg.mission_type)])
        return b""
    if fault == "clear-ack-type-all" and name == "MISSION_CLEAR_ALL":
        proxy.cleared = True
    dropped = {"ignores-mission-request": "MISSION_REQUEST", "set-current-ignored": "MISSION_SET_CURRENT"}
    if dropped.get(fault) == name:
        return b""
    return raw


def pump(src, dst, proxy, vehicle_side, stop):
    parser = mav.MAVLink(None)
    parser.robust_parsing = True
    while not stop.is_set():
        try:
            data = src.recv(65536)
        except OSError:
            break
        if not data:
            break
        try:
            if vehicle_side:
                msgs = []
                for msg in parser.parse_buffer(data) or []:
                    if msg.get_type() == "BAD_DATA":
                        with proxy.lock:
                            proxy.client.sendall(bytes(msg.get_msgbuf()))
                    else:
                        msgs += from_vehicle(msg, proxy)
                proxy.to_runner(msgs)
            else:
                out = bytearray()
                for msg in parser.parse_buffer(data) or []:
                    raw = bytes(msg.get_msgbuf())
                    out += raw if msg.get_type() == "BAD_DATA" else from_runner(msg, raw, proxy)
                dst.sendall(bytes(out))
        except OSError:
            break
    stop.set()
    for s in (src, dst):
        with contextlib.suppress(OSError):
            s.shutdown(socket.SHUT_RDWR)


def main() -> int:
    return serve(None, FAULTS, pump, lambda client, vehicle, fault: Proxy(client, fault), ("--sysid", str(VEHICLE_SYSID)))


if __name__ == "__main__":
    sys.exit(main())

"""The faulty vehicles as models (issue 38, item 3): each fault is a rewrite of the frames
between a ground station and our reference vehicle (``vehicle.SimVehicle``), one thing changed,
so that the vehicle-role suite (``mcp-conform --protocol mavlink``) must fail exactly that
thing's rule. The rewrites are pure functions of a frame and a :class:`FaultState`; the same
functions serve the real proxy in front of ``mcp-vehicle`` (tests/mavlink/faulty_vehicle.py,
the real smoke runs) and the simulator (:mod:`sim.vehicle_role`, the whole matrix on virtual
time).

What a fault does with the vehicle's frames (:func:`from_vehicle`) and the ground station's
(:func:`from_runner`); the vehicle's frames handed on are packed again with sequence numbers of
the fault's own (:meth:`FaultState.pack`: a frame dropped or added leaves no gap for MAV-HB-11
to see), the ground station's go through as they came unless the fault rewrites one. Each
fault and its rule (:data:`RULES`):

- ``no-unsupported-ack``: a COMMAND_ACK with MAV_RESULT_UNSUPPORTED is dropped (MAV-CMD-5);
- ``type-gcs``: HEARTBEAT.type MAV_TYPE_GCS (MAV-HB-3; MAV_AUTOPILOT_INVALID would also make
  its ArduPilot item 0 count against MAV-MIS-9, E-3);
- ``double-ack``: every COMMAND_ACK twice (MAV-CMD-3);
- ``acts-for-other-system``: a command for another system is handed to the vehicle as its own
  (MAV-CMD-14);
- ``acts-for-other-component``: a command for another component of the vehicle's system is
  handed to the vehicle as its own, as ArduPilot 4.x's ``MAVLink_routing`` processes one it has
  no route for (MAV-CMD-14);
- ``bad-param-type``: every PARAM_VALUE's param_type MAV_PARAM_TYPE_ENUM_END, no type
  (MAV-PRM-10);
- ``download-param1``: every MISSION_ITEM_INT the vehicle sends with param1 one more
  (MAV-MIS-9);
- ``creates-unknown-param``: a PARAM_SET of a name the vehicle never listed is answered with a
  PARAM_VALUE of it, and so are reads of it afterwards (MAV-PRM-11);
- ``clear-keeps-plan``: MISSION_CLEAR_ALL answered MAV_MISSION_ACCEPTED by the fault and never
  handed on (MAV-MIS-13);
- ``out-of-sequence-stalls``: after the vehicle's MAV_MISSION_INVALID_SEQUENCE its requests are
  dropped until the next MISSION_COUNT (MAV-MIS-4);
- ``ignores-mission-request``: the ground station's deprecated MISSION_REQUEST is dropped
  (MAV-MIS-10);
- ``mission-type-lost``: mission_type 0 in every mission message the vehicle sends
  (MAV-MIS-16);
- ``set-current-ignored``: MISSION_SET_CURRENT dropped (MAV-MIS-15);
- ``untruncated``: the vehicle's MAVLink 2 payloads sent whole, trailing zeros and all
  (MAV-HB-12);
- ``seq-gaps``: every 50th frame's sequence number skipped (MAV-HB-11);
- ``abandoned-stays-busy``: the vehicle's MISSION_ACK MAV_MISSION_OPERATION_CANCELLED at the
  end of an abandoned upload is dropped and every download refused MAV_MISSION_DENIED until the
  next MISSION_COUNT, as a vehicle that never leaves the upload (MAV-MIS-6);
- ``clear-ack-type-all``: the MISSION_ACK answering MISSION_CLEAR_ALL carries mission_type
  MAV_MISSION_TYPE_ALL (MAV-MIS-17);
- ``unpaced-list``: a parameter list's PARAM_VALUEs held back until its last index and handed
  on in one burst (MAV-PRM-3, a SHOULD: warned, :data:`WARNS`).

``none`` is the rewriting alone (every frame parsed and packed again), which must change no
verdict. Constants and layouts are pymavlink's dialect's (``spec.MAVLINK.dialect``).
"""

from __future__ import annotations

from typing import Any

from mcp_conform.spec import MAVLINK
from mcp_conform.traceio.mavlink import robust_parser, version_of

__all__ = ["FAULTS", "RULES", "VEHICLE_COMPID", "WARNS", "VEHICLE_SYSID", "FaultProxy", "FaultState", "from_runner",
           "from_vehicle", "param_name", "untruncated"]

MAV: Any = MAVLINK.dialect
#: each fault and the MUST rule it breaks
RULES: dict[str, str] = {
    "no-unsupported-ack": "MAV-CMD-5", "type-gcs": "MAV-HB-3", "double-ack": "MAV-CMD-3",
    "acts-for-other-system": "MAV-CMD-14", "acts-for-other-component": "MAV-CMD-14",
    "bad-param-type": "MAV-PRM-10", "download-param1": "MAV-MIS-9", "creates-unknown-param": "MAV-PRM-11",
    "clear-keeps-plan": "MAV-MIS-13", "out-of-sequence-stalls": "MAV-MIS-4", "ignores-mission-request": "MAV-MIS-10",
    "mission-type-lost": "MAV-MIS-16", "set-current-ignored": "MAV-MIS-15", "untruncated": "MAV-HB-12",
    "seq-gaps": "MAV-HB-11", "abandoned-stays-busy": "MAV-MIS-6", "clear-ack-type-all": "MAV-MIS-17",
}
#: each fault that breaks a SHOULD rule, and that rule (warned, not failed)
WARNS: dict[str, str] = {"unpaced-list": "MAV-PRM-3"}
FAULTS: tuple[str, ...] = ("none", *RULES, *WARNS)
#: the vehicle's IDs (``mcp-vehicle --sysid 1``; its component the autopilot's)
VEHICLE_SYSID = 1
VEHICLE_COMPID = int(MAV.MAV_COMP_ID_AUTOPILOT1)
#: the mission messages that carry a mission_type
MISSION_TYPED = ("MISSION_ACK", "MISSION_COUNT", "MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ITEM",
                 "MISSION_ITEM_INT")
#: the ground station's messages a fault drops
DROPPED = {"ignores-mission-request": "MISSION_REQUEST", "set-current-ignored": "MISSION_SET_CURRENT"}


class FaultState:
    """One ground station's connection through fault ``fault``: what the fault remembers, and
    the encoders that pack the vehicle's frames for the ground station (one per source, with
    its own sequence numbers)."""

    def __init__(self, fault: str) -> None:
        if fault not in FAULTS:
            raise ValueError(f"{fault!r}: no such vehicle fault (known: {', '.join(FAULTS)})")
        self.fault = fault
        self.encoders: dict[tuple[int, int], Any] = {}
        self.frames = 0
        self.names: set[str] = set()  # the parameters the vehicle listed
        self.count = 0
        self.created: dict[str, tuple[float, int]] = {}
        self.stalled = False
        self.busy = False  # abandoned-stays-busy: an upload timed out, the fault refuses downloads
        self.cleared = False  # clear-ack-type-all: a MISSION_CLEAR_ALL awaits its MISSION_ACK
        self.listing: list[Any] | None = None  # unpaced-list: a list's PARAM_VALUEs held back

    def pack(self, msgs: list[Any]) -> bytes:
        """``msgs`` as the bytes the ground station gets: packed with the fault's sequence
        numbers (seq-gaps skips one every 50 frames; untruncated pads the payloads)."""
        out = bytearray()
        for m in msgs:
            key = (m.get_srcSystem(), m.get_srcComponent()) if m.get_srcSystem() else (VEHICLE_SYSID, VEHICLE_COMPID)
            enc = self.encoders.setdefault(key, MAV.MAVLink(None, srcSystem=key[0], srcComponent=key[1]))
            self.frames += 1
            if self.fault == "seq-gaps" and self.frames % 50 == 0:
                enc.seq = (enc.seq + 1) % 256
            raw = bytes(m.pack(enc))
            enc.seq = (enc.seq + 1) % 256
            out += untruncated(raw, m) if self.fault == "untruncated" else raw
        return bytes(out)


def untruncated(raw: bytes, msg: Any) -> bytes:
    """A MAVLink 2 frame with its payload padded back to the message's full size and the
    checksum computed again (what MAV-HB-12 forbids a sender)."""
    if version_of(raw) != 2:
        return raw
    head, payload = bytearray(raw[:10]), raw[10:10 + raw[1]]
    payload = payload + bytes(type(msg).unpacker.size - len(payload))
    head[1] = len(payload)
    crc = MAV.x25crc(bytes(head[1:]) + payload)
    crc.accumulate(bytes([type(msg).crc_extra]))
    return bytes(head) + payload + crc.crc.to_bytes(2, "little")


def param_name(raw: Any) -> str:
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw)
    return text.split("\0", 1)[0]


def from_vehicle(msg: Any, state: FaultState) -> list[Any]:
    """The messages handed to the ground station for one message of the vehicle."""
    fault, name = state.fault, msg.get_type()
    if fault == "no-unsupported-ack" and name == "COMMAND_ACK" and msg.result == MAV.MAV_RESULT_UNSUPPORTED:
        return []
    if fault == "type-gcs" and name == "HEARTBEAT":
        msg.type = MAV.MAV_TYPE_GCS
    if fault == "double-ack" and name == "COMMAND_ACK":
        return [msg, msg]
    if fault == "download-param1" and name == "MISSION_ITEM_INT":
        msg.param1 += 1.0
    if fault == "bad-param-type" and name == "PARAM_VALUE":
        msg.param_type = max(MAV.enums["MAV_PARAM_TYPE"])  # MAV_PARAM_TYPE_ENUM_END: no type
    if name == "PARAM_VALUE":
        state.names.add(param_name(msg.param_id))
        state.count = msg.param_count
        if state.listing is not None:
            state.listing.append(msg)
            if msg.param_index < msg.param_count - 1:
                return []
            held, state.listing = state.listing, None
            return held
    if fault == "out-of-sequence-stalls":
        if name == "MISSION_ACK" and msg.type == MAV.MAV_MISSION_INVALID_SEQUENCE:
            state.stalled = True
        if state.stalled and name in ("MISSION_REQUEST", "MISSION_REQUEST_INT"):
            return []
    if fault == "mission-type-lost" and name in MISSION_TYPED:
        msg.mission_type = MAV.MAV_MISSION_TYPE_MISSION
    if fault == "abandoned-stays-busy" and name == "MISSION_ACK" and msg.type == MAV.MAV_MISSION_OPERATION_CANCELLED:
        state.busy = True
        return []
    if fault == "clear-ack-type-all" and name == "MISSION_ACK" and state.cleared:
        state.cleared = False
        msg.mission_type = MAV.MAV_MISSION_TYPE_ALL
    return [msg]


def from_runner(msg: Any, raw: bytes, state: FaultState) -> tuple[bytes, list[Any]]:
    """For one frame of the ground station (``raw``, parsed as ``msg``): the bytes handed to
    the vehicle, and the messages the fault answers the ground station with itself."""
    fault, name = state.fault, msg.get_type()
    command = name in ("COMMAND_LONG", "COMMAND_INT")
    other_system = fault == "acts-for-other-system" and command and msg.target_system not in (0, VEHICLE_SYSID)
    other_component = (fault == "acts-for-other-component" and command and msg.target_system == VEHICLE_SYSID
                       and msg.target_component not in (0, VEHICLE_COMPID))
    if other_system or other_component:
        enc = MAV.MAVLink(None, srcSystem=msg.get_srcSystem(), srcComponent=msg.get_srcComponent())
        enc.seq = msg.get_seq()
        msg.target_system, msg.target_component = VEHICLE_SYSID, VEHICLE_COMPID
        return bytes(msg.pack(enc)), []
    src = (msg.get_srcSystem(), msg.get_srcComponent())
    if fault == "creates-unknown-param" and name in ("PARAM_SET", "PARAM_REQUEST_READ") and state.names:
        key = param_name(msg.param_id)
        if name == "PARAM_SET" and key not in state.names:
            state.created[key] = (msg.param_value, msg.param_type)
        if key in state.created and (name == "PARAM_SET" or msg.param_index == -1):
            value, kind = state.created[key]
            return b"", [MAV.MAVLink_param_value_message(key.encode(), value, kind, state.count, 65535)]
    if fault == "clear-keeps-plan" and name == "MISSION_CLEAR_ALL":
        return b"", [MAV.MAVLink_mission_ack_message(src[0], src[1], MAV.MAV_MISSION_ACCEPTED, msg.mission_type)]
    if fault == "out-of-sequence-stalls" and name == "MISSION_COUNT":
        state.stalled = False
    if fault == "abandoned-stays-busy" and name == "MISSION_COUNT":
        state.busy = False
    if state.busy and name == "MISSION_REQUEST_LIST":
        return b"", [MAV.MAVLink_mission_ack_message(src[0], src[1], MAV.MAV_MISSION_DENIED, msg.mission_type)]
    if fault == "clear-ack-type-all" and name == "MISSION_CLEAR_ALL":
        state.cleared = True
    if fault == "unpaced-list" and name == "PARAM_REQUEST_LIST":
        state.listing = []
    if DROPPED.get(fault) == name:
        return b"", []
    return raw, []


class FaultProxy:
    """A fault between one ground station and the vehicle, over bytes as they come (a TCP
    stream's chunks, or datagrams): each direction parsed with pymavlink (robustly: bytes that
    are no frame go on as they came) and rewritten by :func:`from_runner` and
    :func:`from_vehicle`. Not thread-safe: the caller holds one lock over both directions."""

    def __init__(self, fault: str) -> None:
        self.state = FaultState(fault)
        self._parsers = {side: robust_parser() for side in ("runner", "vehicle")}

    def down(self, data: bytes) -> tuple[bytes, bytes]:
        """The ground station's bytes: (what goes on to the vehicle, what the fault answers the
        ground station with)."""
        out, answers = bytearray(), []
        for msg in self._parsers["runner"].parse_buffer(data) or []:
            raw = bytes(msg.get_msgbuf())
            if msg.get_type() == "BAD_DATA":
                out += raw
                continue
            to_vehicle, answer = from_runner(msg, raw, self.state)
            out += to_vehicle
            answers += answer
        return bytes(out), self.state.pack(answers)

    def up(self, data: bytes) -> bytes:
        """The vehicle's bytes: what goes on to the ground station (bytes that are no frame
        first, as they came, then the frames packed again)."""
        bad, msgs = bytearray(), []
        for msg in self._parsers["vehicle"].parse_buffer(data) or []:
            if msg.get_type() == "BAD_DATA":
                bad += bytes(msg.get_msgbuf())
            else:
                msgs += from_vehicle(msg, self.state)
        return bytes(bad) + self.state.pack(msgs)

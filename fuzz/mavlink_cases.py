"""MAVLink's fuzz cases (``mcp-fuzz --protocol mavlink``, issue 39 item 4): frames built with
pymavlink's dialect (``spec.MAVLINK.dialect``, ardupilotmega: no layout, id, CRC_EXTRA or enum
re-typed here), then mutated.

A :class:`Case` is one or more frames sent together to the vehicle, the rule it exercises
(a death, a hang or an unanswered probe after it is named by it), what answer it must or must
not get (:class:`Expect`, judged by ``fuzz.mavlink_oracles``) and whether it may leave the
vehicle's parser inside a frame (``resync``: the fuzzer then sends filler bytes before its
probe, as any MAVLink parser loses the bytes of a frame it gave up on).

The kinds (:data:`KINDS`), by the page they come from:

- framing (serialization, https://mavlink.io/en/guide/serialization.html): a bad checksum, an
  incompatibility flag nobody understands (MAV-HB-14: discarded, not answered), a bad length,
  a frame cut short, MAVLink 1/2 start markers swapped, an unknown message id, random bytes
  with start markers (MAV-HB-14: the node goes on), a MAVLink 2 payload with its trailing
  zeros (MAV-HB-13: handled), the same request in MAVLink 1 (MAV-HB-15);
- any message of the dialect with its fields at their type's limits (MAV-HB-1);
- commands (https://mavlink.io/en/services/command.html): COMMAND_LONG and COMMAND_INT with
  known and unknown command ids and parameters at their limits (MAV-CMD-1, -2, -5), to
  another system or component (MAV-CMD-14), broadcast (MAV-CMD-15);
- parameters (https://mavlink.io/en/services/parameter.html): PARAM_REQUEST_READ and PARAM_SET
  of known and unknown names, 16-character names without a NUL, names with bytes after a NUL,
  non-ASCII names, indices at their limits, values at their type's limits and types that are
  no MAV_PARAM_TYPE (MAV-PRM-4, -5, -7, -9, -11);
- missions (https://mavlink.io/en/services/mission.html): handshakes out of order (an item
  without MISSION_COUNT, a seq beyond the count, items out of sequence), counts at their
  limits, requests beyond the plan, mission types that are none, fields at their limits
  (MAV-MIS-1, -4, -8, -14, -15, -17, -18).
"""

from __future__ import annotations

import math
import random
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.spec import MAVLINK

__all__ = ["FILLER", "KINDS", "Case", "CaseMaker", "Expect", "Packer", "Vehicle", "asks_heartbeat_stop", "case_from_json",
           "frame_name", "raw_fields", "spare_heartbeat", "stops_heartbeat"]

D: Any = MAVLINK.dialect
GCS_SYSID = 255
GCS_COMPID = int(D.MAV_COMP_ID_MISSIONPLANNER)
#: What follows a case that may leave the vehicle's parser inside a frame: longer than the
#: longest MAVLink frame (v2: 10 + 255 + 2 + 13 = 280 bytes), with no start marker, so the
#: frame given up on is done with and the parser hunts for the next marker.
FILLER = bytes(300)
#: The command a malformed frame carries (answered with a COMMAND_ACK when it is acted on).
MALFORMED_COMMAND = int(D.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES)
#: Commands never sent: a vehicle that obeys them reboots, shuts down, wipes its parameters or
#: stops flying, which is no fault (MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN, ...).
NEVER_SENT = frozenset(int(getattr(D, n)) for n in (
    "MAV_CMD_PREFLIGHT_REBOOT_SHUTDOWN", "MAV_CMD_PREFLIGHT_STORAGE", "MAV_CMD_DO_FLIGHTTERMINATION",
    "MAV_CMD_PREFLIGHT_UAVCAN", "MAV_CMD_DO_SEND_BANNER") if hasattr(D, n))
#: MAV_CMD_SET_MESSAGE_INTERVAL may name the HEARTBEAT (param1), and -1 (param2) then stops it:
#: ACCEPTED by ArduPilot (``GCS_MAVLINK::set_message_interval``: ``vehicle.telemetry``) as
#: mavlink.io's message-rates page has it ("To silence a message, set param2 ... to -1"), an
#: interval past the oracle's gap (up to 60 s) as good as stops it. That stop is the input's
#: documented effect, not a hang: a case never asks it (:func:`spare_heartbeat`), and a hang
#: after a case that does is not blamed on the vehicle (:func:`asks_heartbeat_stop`).
SET_INTERVAL = int(D.MAV_CMD_SET_MESSAGE_INTERVAL)
#: The longest HEARTBEAT interval a case may ask (µs): its usual period (MAV-HB-1).
BEAT_US = float(MAVLINK.params["heartbeat_period_s"]) * 1e6
#: Messages the any-message kind does not send: those of the services' own kinds below, and
#: SETUP_SIGNING (a vehicle that obeys it then drops every unsigned frame) and SERIAL_CONTROL
#: (it can take the link over as a serial passthrough).
NOT_ANY = frozenset({"SETUP_SIGNING", "SERIAL_CONTROL", "COMMAND_LONG", "COMMAND_INT", "PARAM_REQUEST_LIST",
                     "PARAM_REQUEST_READ", "PARAM_SET", "PARAM_EXT_SET", "PARAM_EXT_REQUEST_LIST",
                     "PARAM_EXT_REQUEST_READ"} | {n for n in MAVLINK.layouts if n.startswith("MISSION_")})
_INT_LIMITS = {"int8_t": (-128, 127), "uint8_t": (0, 255), "int16_t": (-32768, 32767), "uint16_t": (0, 65535),
               "int32_t": (-2**31, 2**31 - 1), "uint32_t": (0, 2**32 - 1), "int64_t": (-2**63, 2**63 - 1),
               "uint64_t": (0, 2**64 - 1)}
_FLOATS = (math.nan, math.inf, -math.inf, 0.0, -0.0, 3.4028234e38, -3.4028234e38, 1e-45, -1.0, 1.0)


@dataclass(frozen=True)
class Expect:
    """An answer the case must (``ack``, ``param``, ``param-index``, ``msg``) or must not
    (``no-ack``, ``no-param``) get before the probe's answer; ``key``: the command id, the
    parameter name (its bytes as hex) or index, the messages (``|``-separated) one of which
    answers; ``result``: the MAV_RESULT an ``ack`` must carry, if one."""

    what: str
    key: int | str
    rule: str
    result: int | None = None

    def to_json(self) -> list[Any]:
        return [self.what, self.key, self.rule, self.result]


@dataclass(frozen=True)
class Case:
    """Frames sent together, the rule they exercise, the answers judged, how they were made."""

    kind: str
    rule: str
    frames: tuple[bytes, ...]
    expect: tuple[Expect, ...] = ()
    resync: bool = False
    messages: tuple[str, ...] = ()  # the messages the frames were built from
    note: str = ""

    def wire(self) -> bytes:
        """The bytes sent for it (its frames, then the filler when it may leave the parser
        inside a frame)."""
        return b"".join(self.frames) + (FILLER if self.resync else b"")

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "rule": self.rule, "frames": [f.hex() for f in self.frames],
                "expect": [e.to_json() for e in self.expect], "resync": self.resync,
                "messages": list(self.messages), "note": self.note}

    def describe(self) -> str:
        return f"{self.kind} ({', '.join(self.messages) or 'bytes'}): {self.note}"


def case_from_json(d: Any) -> Case:
    """A case from its ``finding.json`` form; ValueError when it is none."""
    try:
        return Case(str(d["kind"]), str(d["rule"]), tuple(bytes.fromhex(f) for f in d["frames"]),
                    tuple(Expect(str(e[0]), e[1], str(e[2]), e[3]) for e in d.get("expect", [])),
                    bool(d.get("resync", False)), tuple(d.get("messages", [])), str(d.get("note", "")))
    except (TypeError, KeyError, ValueError, IndexError) as exc:
        raise ValueError(f"not a MAVLink fuzz case: {exc}") from None


def frame_name(frame: bytes) -> str | None:
    """The dialect's name of a frame's message id, None when it has none (or no frame)."""
    if len(frame) >= 10 and frame[0] == D.PROTOCOL_MARKER_V2:
        cls = D.mavlink_map.get(frame[7] | frame[8] << 8 | frame[9] << 16)
    elif len(frame) >= 6 and frame[0] == D.PROTOCOL_MARKER_V1:
        cls = D.mavlink_map.get(frame[5])
    else:
        return None
    return None if cls is None else str(cls.msgname)


def raw_fields(msg: Any) -> dict[str, Any]:
    """A message's fields as its frame's bytes hold them (char arrays as bytes, before any
    NUL is cut: pymavlink decodes them as text)."""
    raw = bytes(msg.get_msgbuf())
    v2 = raw[:1] == bytes([D.PROTOCOL_MARKER_V2])
    payload = raw[10:10 + raw[1]] if v2 else raw[6:6 + raw[1]]
    cls = type(msg)
    payload = payload + bytes(max(0, cls.unpacker.size - len(payload)))
    return dict(zip(cls.ordered_fieldnames, cls.unpacker.unpack(payload[:cls.unpacker.size]), strict=True))


def stops_heartbeat(command: int, param1: float, param2: float) -> bool:
    """Whether a command may stop the HEARTBEAT by request: MAV_CMD_SET_MESSAGE_INTERVAL whose
    param1 may name it (anything but a finite id 1 .. 2**24-1: a C cast of 0, of a fraction,
    of NaN, of a negative or huge value may give HEARTBEAT's id 0) and whose param2 is no
    interval up to the HEARTBEAT's period (-1, one past the oracle's gap, NaN, infinite)."""
    names_it = not (math.isfinite(param1) and 1 <= param1 < 2**24)
    keeps = math.isfinite(param2) and -1 < param2 <= BEAT_US
    return command == SET_INTERVAL and names_it and not keeps


def spare_heartbeat(msg: Any) -> str:
    """A COMMAND_LONG / COMMAND_INT that :func:`stops_heartbeat` made to ask the HEARTBEAT's
    default interval instead (param2 0; its path in the vehicle exercised, the beat kept);
    what was changed, for the case's note."""
    if not stops_heartbeat(msg.command, msg.param1, msg.param2):
        return ""
    was, msg.param2 = msg.param2, 0.0
    return f", param2 {was!r} -> 0 (would stop the HEARTBEAT)"


def asks_heartbeat_stop(case: Case) -> bool:
    """Whether a frame of ``case`` is a command that may stop the HEARTBEAT by request
    (:func:`stops_heartbeat`; whatever its target: a finding's cases, judged without the vehicle)."""
    parser = D.MAVLink(None)
    for frame in case.frames:
        try:
            m = parser.decode(bytearray(frame))
        except Exception:  # a malformed frame: no command a vehicle acts on
            continue
        if m.get_type() in ("COMMAND_LONG", "COMMAND_INT") and stops_heartbeat(m.command, m.param1, m.param2):
            return True
    return False


def name_key(raw: bytes) -> bytes:
    """A parameter name as a vehicle reads it: cut at the first NUL, at most 16 bytes (MAV-PRM-9)."""
    return raw.split(b"\0", 1)[0][:16]


@dataclass
class Vehicle:
    """What the cases are built for: the vehicle's IDs (its HEARTBEAT's) and parameters (its
    list: name -> (index, MAV_PARAM_TYPE)), and the parameter the probe reads (never touched by
    a case, so that no case's answer is taken for the probe's)."""

    sysid: int
    compid: int
    params: dict[bytes, tuple[int, int]] = field(default_factory=dict)
    probe: bytes = b""

    def names(self) -> list[bytes]:
        return [n for n in self.params if n != self.probe]

    @property
    def probe_index(self) -> int:
        return self.params[self.probe][0] if self.probe in self.params else -1


class Packer:
    """The fuzzer's frames, a ground station's (system ``GCS_SYSID``, component ``GCS_COMPID``),
    each with the next sequence number: a case's (:class:`CaseMaker`) and the fuzzer's own
    keep-alive and probe (``fuzz.mavlink_vehicle.MavVehicle``)."""

    def __init__(self) -> None:
        self.enc = D.MAVLink(None, srcSystem=GCS_SYSID, srcComponent=GCS_COMPID)

    def pack(self, msg: Any) -> bytes:
        data = bytes(msg.pack(self.enc))
        self.enc.seq = (self.enc.seq + 1) % 256
        return data


class CaseMaker(Packer):
    """Cases drawn from a seeded ``random.Random``, built for one :class:`Vehicle`."""

    def __init__(self, rng: random.Random, vehicle: Vehicle) -> None:
        super().__init__()
        self.rng, self.v = rng, vehicle
        self.known_cmds = sorted(c for c in D.enums["MAV_CMD"] if c not in NEVER_SENT
                                 and not D.enums["MAV_CMD"][c].name.endswith("_ENUM_END"))
        self.any_msgs = sorted((cls for cls in D.mavlink_map.values() if cls.msgname not in NOT_ANY),
                               key=lambda c: c.id)
        self.kinds = {k: getattr(self, "_" + k.replace("-", "_")) for k in KINDS}

    def draw(self) -> Case:
        kind = self.rng.choice(KINDS)
        return self.kinds[kind]()

    # -- building ------------------------------------------------------------------------
    def limit(self, ctype: str) -> Any:
        """A value of the C type at or near its limits."""
        if ctype in ("float", "double"):
            return self.rng.choice(_FLOATS)
        lo, hi = _INT_LIMITS[ctype]
        return self.rng.choice((lo, hi, 0, 1, hi - 1, lo + 1 if lo else hi // 2, self.rng.randint(lo, hi)))

    def message(self, cls: Any, **given: Any) -> Any:
        """``cls`` with every field not ``given`` at a value of its type's limits (targets: the
        vehicle's IDs)."""
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
        args = []
        for name, ctype in zip(cls.fieldnames, cls.fieldtypes, strict=True):
            n = lengths.get(name, 0)
            if name in given:
                args.append(given[name])
            elif name == "target_system":
                args.append(self.v.sysid)
            elif name == "target_component":
                args.append(self.v.compid)
            elif ctype == "char":
                args.append(bytes(self.rng.choice((0x00, 0x41, 0xFF, 0x7F)) for _ in range(n or 1)))
            elif n:
                args.append([self.limit(ctype) for _ in range(n)])
            else:
                args.append(self.limit(ctype))
        return cls(*args)

    def command_long(self, command: int, target: tuple[int, int] | None = None, **params: float) -> Any:
        ts, tc = target or (self.v.sysid, self.v.compid)
        p = [params.get(f"param{i}", 0.0) for i in range(1, 8)]
        return D.MAVLink_command_long_message(ts, tc, command, 0, *p)

    # -- framing (MAV-HB-13, -14, -15) ---------------------------------------------------
    def _request(self) -> Any:
        return self.command_long(MALFORMED_COMMAND, param1=1.0)

    def _v2(self, msg: Any, *, flags: int | None = None, pad: bool = False, crc_xor: int = 0) -> bytes:
        """``msg`` as a MAVLink 2 frame, its incompat flags, padding and checksum as asked,
        the checksum computed again by pymavlink's x25crc with the message's CRC_EXTRA."""
        raw = bytearray(self.pack(msg))
        head, payload = raw[:10], raw[10:10 + raw[1]]
        if pad:
            payload = payload + bytes(type(msg).unpacker.size - len(payload))
            head[1] = len(payload)
        if flags is not None:
            head[2] = flags
        crc = D.x25crc(bytes(head[1:] + payload))
        crc.accumulate(bytes([type(msg).crc_extra]))
        return bytes(head + payload + (crc.crc ^ crc_xor).to_bytes(2, "little"))

    def _bad_crc(self) -> Case:
        frame = self._v2(self._request(), crc_xor=self.rng.randint(1, 0xFFFF))
        return Case("bad-crc", "MAV-HB-14", (frame,), (Expect("no-ack", MALFORMED_COMMAND, "MAV-HB-14"),),
                    messages=("COMMAND_LONG",), note="checksum spoiled")

    def _bad_incompat(self) -> Case:
        flags = self.rng.choice([1 << b for b in range(1, 8)] + [0xFE, 0xFF & ~D.MAVLINK_IFLAG_SIGNED])
        frame = self._v2(self._request(), flags=flags)
        return Case("bad-incompat", "MAV-HB-14", (frame,), (Expect("no-ack", MALFORMED_COMMAND, "MAV-HB-14"),),
                    messages=("COMMAND_LONG",), note=f"incompat_flags 0x{flags:02x}, checksum right")

    def _bad_length(self) -> Case:
        frame = bytearray(self.pack(self._request()))
        frame[1] = self.rng.choice((0, 1, 255, max(0, frame[1] - 1), min(255, frame[1] + 1)))
        return Case("bad-length", "MAV-HB-14", (bytes(frame),), resync=True, messages=("COMMAND_LONG",),
                    note=f"length byte {frame[1]}")

    def _truncated(self) -> Case:
        msg = self.message(self.rng.choice(self.any_msgs))
        frame = self.pack(msg)
        cut = self.rng.randint(1, len(frame) - 1)
        return Case("truncated", "MAV-HB-14", (frame[:cut],), resync=True, messages=(msg.get_type(),),
                    note=f"cut at {cut} of {len(frame)} bytes")

    def _marker_swap(self) -> Case:
        frame = bytearray(self.pack(self._request()))
        frame[0] = D.PROTOCOL_MARKER_V1
        return Case("marker-swap", "MAV-HB-14", (bytes(frame),), resync=True, messages=("COMMAND_LONG",),
                    note="a MAVLink 2 frame behind the MAVLink 1 start marker")

    def _unknown_msgid(self) -> Case:
        msgid = self.rng.choice([i for i in (255, 1000, 2**16 - 1, 2**24 - 1, self.rng.randint(0, 2**24 - 1))
                                 if i not in D.mavlink_map])
        payload = bytes(self.rng.randint(0, 255) for _ in range(self.rng.randint(1, 40)))
        head = bytes([D.PROTOCOL_MARKER_V2, len(payload), 0, 0, self.enc.seq, GCS_SYSID, GCS_COMPID,
                      msgid & 0xFF, msgid >> 8 & 0xFF, msgid >> 16])
        crc = D.x25crc(head[1:] + payload)
        crc.accumulate(bytes([self.rng.randint(0, 255)]))
        return Case("unknown-msgid", "MAV-HB-14", (head + payload + crc.crc.to_bytes(2, "little"),),
                    note=f"message id {msgid}")

    def _garbage(self) -> Case:
        data = bytearray(self.rng.randint(0, 255) for _ in range(self.rng.randint(1, 300)))
        for _ in range(self.rng.randint(1, 4)):
            data[self.rng.randrange(len(data))] = self.rng.choice((D.PROTOCOL_MARKER_V1, D.PROTOCOL_MARKER_V2))
        return Case("garbage", "MAV-HB-14", (bytes(data),), resync=True, note=f"{len(data)} random bytes")

    def _untruncated(self) -> Case:
        frame = self._v2(self._request(), pad=True)
        return Case("untruncated", "MAV-HB-13", (frame,), (Expect("ack", MALFORMED_COMMAND, "MAV-HB-13"),),
                    messages=("COMMAND_LONG",), note="MAVLink 2 payload with its trailing zeros")

    def _v1_frame(self) -> Case:
        from pymavlink.dialects.v10 import ardupilotmega as mavlink1

        enc = mavlink1.MAVLink(None, srcSystem=GCS_SYSID, srcComponent=GCS_COMPID)
        enc.seq = self.enc.seq
        frame = bytes(mavlink1.MAVLink_command_long_message(self.v.sysid, self.v.compid, MALFORMED_COMMAND, 0,
                                                            1.0, 0, 0, 0, 0, 0, 0).pack(enc))
        self.enc.seq = (self.enc.seq + 1) % 256
        return Case("v1-frame", "MAV-HB-15", (frame,), (Expect("ack", MALFORMED_COMMAND, "MAV-HB-15"),),
                    messages=("COMMAND_LONG",), note="the request in MAVLink 1")

    # -- any message at its limits (MAV-HB-1) ----------------------------------------------
    def _any_message(self) -> Case:
        msg = self.message(self.rng.choice(self.any_msgs))
        return Case("any-message", "MAV-HB-1", (self.pack(msg),), messages=(msg.get_type(),),
                    note="fields at their type's limits")

    # -- commands (MAV-CMD-1, -2, -5, -14, -15) ------------------------------------------------
    def _command_id(self) -> tuple[int, bool]:
        """A command id and whether the dialect knows it."""
        if self.rng.random() < 0.7:
            return self.rng.choice(self.known_cmds), True
        while True:
            c = self.rng.choice((0, 65535, self.rng.randint(1, 65534)))
            if c not in D.enums["MAV_CMD"]:
                return c, False

    def _target(self) -> tuple[tuple[int, int], str]:
        """(target_system, target_component) and how it is addressed: to the vehicle, to its
        system (component 0), to another system, to another component of its system."""
        how = self.rng.choice(("vehicle", "vehicle", "vehicle", "system", "other-system", "other-component"))
        sys_, comp = self.v.sysid, self.v.compid
        if how == "system":
            return (sys_, 0), how
        if how == "other-system":
            return (self.rng.choice([s for s in (2, 42, 254, 255) if s != sys_]), comp), how
        if how == "other-component":
            return (sys_, self.rng.choice([c for c in (2, 100, 154, 250) if c != comp])), how
        return (sys_, comp), how

    def _commanded(self, kind: str, msg: Any, command: int, known: bool, how: str, rule: str) -> Case:
        spared = spare_heartbeat(msg)
        if how.startswith("other"):
            expect = Expect("no-ack", command, "MAV-CMD-14")
        elif not known:
            expect = Expect("ack", command, "MAV-CMD-5", int(D.MAV_RESULT_UNSUPPORTED))
        else:
            expect = Expect("ack", command, "MAV-CMD-15" if how == "system" else rule)
        return Case(kind, expect.rule, (self.pack(msg),), (expect,),
                    messages=(msg.get_type(),), note=f"command {command} ({'known' if known else 'unknown'}), "
                                                     f"to {how}{spared}")

    def _command_long(self) -> Case:
        command, known = self._command_id()
        target, how = self._target()
        params = {f"param{i}": (self.limit("float") if self.rng.random() < 0.5 else 0.0) for i in range(1, 8)}
        msg = self.command_long(command, target, **params)
        msg.confirmation = self.rng.choice((0, 0, 1, 255))
        return self._commanded("command-long", msg, command, known, how, "MAV-CMD-1")

    def _command_int(self) -> Case:
        command, known = self._command_id()
        target, how = self._target()
        msg = self.message(D.MAVLink_command_int_message, target_system=target[0], target_component=target[1],
                           command=command, frame=self.rng.choice((0, 3, 5, 6, 255)))
        return self._commanded("command-int", msg, command, known, how, "MAV-CMD-2")

    # -- parameters (MAV-PRM-4, -5, -7, -9, -11) ---------------------------------------------
    def _name(self) -> tuple[bytes, bytes | None]:
        """A param_id's 16 bytes and the known name a vehicle reads in it (None: none)."""
        known = self.v.names()
        r = self.rng.random()
        if known and r < 0.35:
            name = self.rng.choice(known)
            if self.rng.random() < 0.5 and len(name) < 15:  # bytes after the NUL (MAV-PRM-9)
                name = name + b"\0" + bytes(self.rng.randint(1, 255) for _ in range(15 - len(name)))
        elif r < 0.6:  # 16 characters, no NUL (MAV-PRM-9)
            name = bytes(self.rng.choice(b"ABCDEFGHIJKLMNOPQRSTUVWXYZ_0123456789") for _ in range(16))
        elif r < 0.8:
            name = bytes(self.rng.choice(b"ABCDEFGHIJKLMNOPQRSTUVWXYZ_") for _ in range(self.rng.randint(1, 15)))
        else:  # not ASCII, or nothing
            name = bytes(self.rng.randint(0x80, 0xFF) for _ in range(self.rng.randint(0, 16)))
        key = name_key(name)
        if key == self.v.probe or (key in self.v.params and key not in known):
            return self._name()
        return name, (key if key in self.v.params else None)

    def _param_read_name(self) -> Case:
        name, known = self._name()
        msg = D.MAVLink_param_request_read_message(self.v.sysid, self.v.compid, name, -1)
        if known is not None:
            expect: tuple[Expect, ...] = (Expect("param", known.hex(), "MAV-PRM-4"),)
        else:
            expect = (Expect("no-param", name_key(name).hex(), "MAV-PRM-11"),) if name_key(name) else ()
        rule = "MAV-PRM-9" if len(name) == 16 and b"\0" not in name else expect[0].rule if expect else "MAV-PRM-4"
        return Case("param-read-name", rule, (self.pack(msg),), expect, messages=("PARAM_REQUEST_READ",),
                    note=f"param_id {name!r}")

    def _param_read_index(self) -> Case:
        count = len(self.v.params)
        index = self.rng.choice((count, count + 1, 32767, -2, -32768, self.rng.randrange(max(count, 1))))
        name = bytes(self.rng.randint(0, 255) for _ in range(self.rng.randint(0, 16)))
        if index == self.v.probe_index:
            index = count
        msg = D.MAVLink_param_request_read_message(self.v.sysid, self.v.compid, name, index)
        expect = (Expect("param-index", index, "MAV-PRM-5"),) if 0 <= index < count else ()
        return Case("param-read-index", "MAV-PRM-5" if expect else "MAV-PRM-11", (self.pack(msg),), expect,
                    messages=("PARAM_REQUEST_READ",), note=f"param_index {index}, param_id {name!r}")

    def _param_set(self) -> Case:
        name, known = self._name()
        ptype = self.v.params[known][1] if known is not None and self.rng.random() < 0.6 else \
            self.rng.choice((0, 11, 255, *range(1, 11)))
        value = self.rng.choice((*_FLOATS, 1.0, 0.5, 127.0, 128.0, -129.0, 32768.0, 2.0**31))
        msg = D.MAVLink_param_set_message(self.v.sysid, self.v.compid, name, value, ptype)
        if known is not None:
            # a written value, or the unchanged one, answered (MAV-PRM-7); ArduPilot ignores a
            # NaN or infinite value (GCS_Param.cpp handle_param_set): not judged
            expect: tuple[Expect, ...] = (Expect("param", known.hex(), "MAV-PRM-7"),) if math.isfinite(value) else ()
        else:
            expect = (Expect("no-param", name_key(name).hex(), "MAV-PRM-11"),) if name_key(name) else ()
        rule = "MAV-PRM-9" if len(name) == 16 and b"\0" not in name else expect[0].rule if expect else "MAV-PRM-7"
        return Case("param-set", rule, (self.pack(msg),), expect, messages=("PARAM_SET",),
                    note=f"param_id {name!r}, value {value!r}, type {ptype}")

    # -- missions (MAV-MIS-1, -4, -8, -14, -15, -17, -18) ---------------------------------------
    def _mtype(self) -> int:
        return self.rng.choice((0, 0, 0, 1, 2, 3, 254, 255))

    def _item(self, seq: int, mission_type: int = 0, limits: bool = False) -> Any:
        if limits:
            return self.message(D.MAVLink_mission_item_int_message, seq=seq, mission_type=mission_type)
        return D.MAVLink_mission_item_int_message(self.v.sysid, self.v.compid, seq, 6, 16, 0, 1, 0, 0, 0, 0,
                                                  357713320, -786744210, 10.0, mission_type)

    def _count_msg(self, count: int, mission_type: int = 0) -> Any:
        return D.MAVLink_mission_count_message(self.v.sysid, self.v.compid, count, mission_type)

    def _mission_item_alone(self) -> Case:
        seq = self.rng.choice((0, 1, 65535, self.rng.randint(0, 700)))
        msg = self._item(seq, limits=self.rng.random() < 0.5)
        return Case("mission-item-alone", "MAV-MIS-1", (self.pack(msg),), messages=("MISSION_ITEM_INT",),
                    note=f"MISSION_ITEM_INT seq {seq} without MISSION_COUNT")

    def _mission_seq(self) -> Case:
        count = self.rng.choice((1, 2, 3, 5))
        seq = self.rng.choice((count, count + 1, 65535, self.rng.randint(1, count + 3)))
        frames = (self.pack(self._count_msg(count)), self.pack(self._item(seq)))
        return Case("mission-seq", "MAV-MIS-4", frames, messages=("MISSION_COUNT", "MISSION_ITEM_INT"),
                    note=f"MISSION_COUNT {count}, then the item of seq {seq}")

    def _mission_count(self) -> Case:
        count = self.rng.choice((0, 1, 700, 701, 32767, 65535))
        mtype = self._mtype()
        frames = [self.pack(self._count_msg(count, mtype))]
        if count and self.rng.random() < 0.5:
            frames.append(self.pack(self._item(0, mtype, limits=True)))
        # an upload of none is answered with MISSION_ACK at once (MAV-MIS-14)
        expect = (Expect("msg", "MISSION_ACK", "MAV-MIS-14"),) if count == 0 else ()
        return Case("mission-count", "MAV-MIS-14" if count == 0 else "MAV-MIS-1", tuple(frames), expect,
                    messages=("MISSION_COUNT", "MISSION_ITEM_INT")[:len(frames)],
                    note=f"MISSION_COUNT {count}, mission_type {mtype}")

    def _mission_request(self) -> Case:
        name = self.rng.choice(("MISSION_REQUEST_INT", "MISSION_REQUEST", "MISSION_REQUEST_LIST",
                                "MISSION_CLEAR_ALL", "MISSION_SET_CURRENT", "MISSION_ACK"))
        seq, mtype = self.rng.choice((0, 1, 700, 65535)), self._mtype()
        msg = {"MISSION_REQUEST_INT": lambda: D.MAVLink_mission_request_int_message(
                   self.v.sysid, self.v.compid, seq, mtype),
               "MISSION_REQUEST": lambda: D.MAVLink_mission_request_message(self.v.sysid, self.v.compid, seq, mtype),
               "MISSION_REQUEST_LIST": lambda: D.MAVLink_mission_request_list_message(
                   self.v.sysid, self.v.compid, mtype),
               "MISSION_CLEAR_ALL": lambda: D.MAVLink_mission_clear_all_message(self.v.sysid, self.v.compid, mtype),
               "MISSION_SET_CURRENT": lambda: D.MAVLink_mission_set_current_message(
                   self.v.sysid, self.v.compid, seq),
               "MISSION_ACK": lambda: D.MAVLink_mission_ack_message(
                   self.v.sysid, self.v.compid, self.rng.choice((0, 2, 15, 255)), mtype)}[name]()
        rule = {"MISSION_SET_CURRENT": "MAV-MIS-15", "MISSION_ACK": "MAV-MIS-18",
                "MISSION_CLEAR_ALL": "MAV-MIS-13"}.get(name, "MAV-MIS-8")
        # answered, whatever the type and the vehicle's state: a clear with MISSION_ACK
        # (MAV-MIS-13), a download's start with MISSION_COUNT or an error MISSION_ACK (MAV-MIS-8, -16)
        expect = {"MISSION_CLEAR_ALL": (Expect("msg", "MISSION_ACK", "MAV-MIS-13"),),
                  "MISSION_REQUEST_LIST": (Expect("msg", "MISSION_COUNT|MISSION_ACK", "MAV-MIS-8"),)}.get(name, ())
        return Case("mission-request", rule, (self.pack(msg),), expect, messages=(name,),
                    note=f"{name} seq {seq}, mission_type {mtype}")


#: Every kind, as ``--engine stateless`` draws them (equally likely).
KINDS = ("bad-crc", "bad-incompat", "bad-length", "truncated", "marker-swap", "unknown-msgid", "garbage",
         "untruncated", "v1-frame", "any-message", "command-long", "command-int", "param-read-name",
         "param-read-index", "param-set", "mission-item-alone", "mission-seq", "mission-count", "mission-request")

"""The MAVLink microservices as a ground station speaks them to a vehicle under test, for the
vehicle cases of this package (``--protocol mavlink``): MAVLink's content, beside its cases.
The ``node`` fixture (``conformance.mavlink_case.MavlinkCaseContext``, the shared link case's
plumbing) takes them as :class:`VehicleServices`.

- Commands (https://mavlink.io/en/services/command.html): COMMAND_LONG / COMMAND_INT built
  for the vehicle, one final COMMAND_ACK awaited (MAV-CMD-1..5), none for what it must not
  process.
- Heartbeat (MAV-HB-1): the gaps between the vehicle's HEARTBEATs over a window.
- Parameters (MAV-PRM-*): the PARAM_VALUEs answering a request, a whole list read to its end.
- Missions (MAV-MIS-*): a plan, its upload (each item the vehicle asks for, a re-request
  answered once: :class:`ItemAnswers`) and download, and an upload judged as MAV-MIS-1/2/3
  have it.
- Frames built by hand (a padded payload, a spoiled checksum) and a frame's fields as its
  bytes hold them, by the dialect's layout.

Every message, field and constant comes from pymavlink's dialect (``spec.MAVLINK.dialect``);
the times from ``spec/mavlink.yaml``'s parameters.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Sequence
from typing import Any

from mcp_conform.conformance._link_case import LinkCaseBase
from mcp_conform.harness.mavlink_session import DIALECT, GCS_COMPID, GCS_SYSID, Link, Received

__all__ = ["FINAL", "RESULTS", "UNKNOWN_COMMAND", "ItemAnswers", "MavlinkServices", "VehicleServices",
           "param_id", "result_name", "result_name_mission", "upload_replies"]

#: MAV_RESULT's entries by value, as the dialect has them
RESULTS: dict[int, str] = {v: e.name for v, e in DIALECT.enums["MAV_RESULT"].items()
                           if not e.name.endswith("_ENUM_END")}
FINAL = frozenset(RESULTS) - {DIALECT.MAV_RESULT_IN_PROGRESS}
#: a command id no MAV_CMD of the dialect has: unknown to every vehicle (MAV-CMD-5)
UNKNOWN_COMMAND = max(v for v in range(1, 65536) if v not in DIALECT.enums["MAV_CMD"])
#: how long after a command's first final ACK the runner watches for a second (MAV-CMD-3)
SECOND_ACK_WATCH_S = 0.5


def result_name(value: int) -> str:
    return RESULTS.get(value, f"{value} (no MAV_RESULT)")


class MavlinkServices(LinkCaseBase):
    """What a case of either MAVLink role reads of MAVLink's frames: a command's name, a
    frame's fields as its bytes hold them."""

    def command_name(self, command: int) -> str:
        entry = DIALECT.enums["MAV_CMD"].get(command)
        return entry.name if entry is not None else f"command {command}"

    def raw_fields(self, r: Received) -> dict[str, Any]:
        """A frame's fields as its bytes hold them (char arrays as bytes, before any NUL is
        cut), by the dialect's layout of its message (the payload padded to its full size)."""
        cls = type(r.msg)
        payload = r.raw[10:10 + r.raw[1]] if r.version == 2 else r.raw[6:6 + r.raw[1]]
        payload = payload + bytes(max(0, cls.unpacker.size - len(payload)))
        return dict(zip(cls.ordered_fieldnames, cls.unpacker.unpack(payload[:cls.unpacker.size]), strict=True))


class ItemAnswers:
    """The items the runner sent in one upload, by seq: when each was last sent, and how many
    were sent again. A request for a seq whose item went out at or after the request came
    (:meth:`due` False) was sent again by the vehicle before it could have had that item
    (ArduPilot re-requests an unanswered item each second: a runner stalled on a loaded host,
    its reader or its case thread, reads both requests late), and the item already sent answers
    both; a request that came after it is answered again (the item may have been lost)."""

    def __init__(self) -> None:
        self.at: dict[int, float] = {}
        self.again: set[int] = set()

    def due(self, request: Received) -> bool:
        t = self.at.get(int(request.msg.seq))
        return t is None or t < request.t

    def sent(self, seq: int, t: float) -> None:
        if seq in self.at:
            self.again.add(seq)
        self.at[seq] = t


class VehicleServices(MavlinkServices):
    """The microservices as the runner, a ground station, drives them with the vehicle under
    test (system ``sysid``, component ``compid``; ``from_vehicle``: its frames)."""

    link: Link
    sysid: int
    compid: int
    ack_max: float
    reply_max: float

    def from_vehicle(self, since: float = 0.0, name: str | None = None) -> list[Received]:
        raise NotImplementedError

    # -- sending --------------------------------------------------------------------------

    def command_long(self, command: int, *params: float, confirmation: int = 0,
                     target_system: int | None = None, target_component: int | None = None) -> float:
        p = [*params, *[0.0] * (7 - len(params))]
        return self.send("COMMAND_LONG", target_system=self.sysid if target_system is None else target_system,
                         target_component=self.compid if target_component is None else target_component,
                         command=command, confirmation=confirmation, param1=p[0], param2=p[1], param3=p[2],
                         param4=p[3], param5=p[4], param6=p[5], param7=p[6])

    def command_int(self, command: int, *params: float, frame: int | None = None, x: int = 0, y: int = 0,
                    z: float = 0.0) -> float:
        p = [*params, *[0.0] * (4 - len(params))]
        return self.send("COMMAND_INT", target_system=self.sysid, target_component=self.compid,
                         frame=DIALECT.MAV_FRAME_GLOBAL_INT if frame is None else frame, command=command,
                         current=0, autocontinue=0, param1=p[0], param2=p[1], param3=p[2], param4=p[3],
                         x=x, y=y, z=z)

    def frame_of(self, msg: Any, *, pad: bool = False, bad_crc: bool = False) -> bytes:
        """``msg`` as the bytes of a MAVLink 2 frame with the link's next sequence number,
        built by pymavlink; ``pad``: the payload's trailing zeros left in (not truncated),
        the checksum computed again over it; ``bad_crc``: the checksum spoiled."""
        raw = bytearray(msg.pack(self.link.encoder))
        head, payload = raw[:10], raw[10:10 + raw[1]]
        if pad:
            payload = payload + bytes(type(msg).unpacker.size - len(payload))
            head[1] = len(payload)
        crc = DIALECT.x25crc(bytes(head[1:] + payload))
        crc.accumulate(bytes([type(msg).crc_extra]))
        value = crc.crc ^ (0xFFFF if bad_crc else 0)
        return bytes(head + payload + value.to_bytes(2, "little"))

    # -- what came ------------------------------------------------------------------------
    def acks(self, since: float, command: int) -> list[Received]:
        return [r for r in self.from_vehicle(since, "COMMAND_ACK") if r.msg.command == command]

    # -- verify helpers -------------------------------------------------------------------
    def expect_heartbeats(self, window: float, rule: str = "MAV-HB-1") -> list[Received]:
        """HEARTBEATs of the vehicle over ``window`` s from now: none of the gaps (the window's
        start to the first, between two, the last to the window's end) over
        ``heartbeat_gap_max_s``; the HEARTBEATs seen."""
        gap_max = float(self.params["heartbeat_gap_max_s"])
        start = self.now()
        self.watch(window)
        end = self.now()
        beats = [r.t for r in self.from_vehicle(start, "HEARTBEAT")]
        edges = [start, *beats, end]
        gaps = [b - a for a, b in zip(edges, edges[1:], strict=False)]
        self.expect_true(bool(beats) and max(gaps) <= gap_max, rule,
                         f"a HEARTBEAT at least every {gap_max:g} s over {window:g} s",
                         f"{len(beats)} HEARTBEAT(s), longest gap {max(gaps):.2f} s",
                         [f"gaps (s): {', '.join(f'{g:.2f}' for g in gaps)}"])
        return self.from_vehicle(start, "HEARTBEAT")

    def expect_ack(self, since: float, command: int, rule: str, *, results: Sequence[int] | None = None,
                   once_rule: str | None = "MAV-CMD-3", what: str = "") -> Received:
        """One final COMMAND_ACK for ``command`` after ``since`` within ``command_ack_max_s``,
        its result a MAV_RESULT (one of ``results`` when given); with ``once_rule``, no second
        final ACK within ``SECOND_ACK_WATCH_S`` after it. The ACK."""
        what = what or f"{self.command_name(command)} sent"
        got = self.link.wait_for(lambda: any(a.msg.result in FINAL or a.msg.result not in RESULTS
                                             for a in self.acks(since, command)), self.ack_max)
        if not got:
            others = [a.msg.command for a in self.from_vehicle(since, "COMMAND_ACK")]
            raise self.fail(rule, f"after {what}, a COMMAND_ACK with command {command} within {self.ack_max:g} s",
                            "no COMMAND_ACK" + (f" for it (ACKs for commands {others})" if others else ""))
        final = [a for a in self.acks(since, command) if a.msg.result not in (DIALECT.MAV_RESULT_IN_PROGRESS,)]
        ack = final[0]
        result = ack.msg.result
        if result not in RESULTS or (results is not None and result not in results):
            wanted = " or ".join(result_name(r) for r in results) if results is not None else "a MAV_RESULT"
            raise self.fail(rule, f"after {what}, COMMAND_ACK.result {wanted}", f"{result_name(result)}")
        if once_rule is not None:
            self.watch(max(0.0, ack.t + SECOND_ACK_WATCH_S - self.now()))
            final = [a for a in self.acks(since, command) if a.msg.result != DIALECT.MAV_RESULT_IN_PROGRESS]
            if len(final) > 1:
                raise self.fail(once_rule, f"after {what}, one final COMMAND_ACK",
                                f"{len(final)} final COMMAND_ACKs ({', '.join(result_name(a.msg.result) for a in final)})")
        return ack

    def expect_no_ack(self, since: float, command: int, rule: str, what: str) -> None:
        """No COMMAND_ACK for ``command`` after ``since`` within ``command_ack_max_s``."""
        self.link.wait_for(lambda: bool(self.acks(since, command)), self.ack_max)
        acks = self.acks(since, command)
        if acks:
            raise self.fail(rule, f"after {what}, no COMMAND_ACK (the vehicle does not process it)",
                            f"COMMAND_ACK {result_name(acks[0].msg.result)}")

    def expect_param_values(self, since: float, pred: Callable[[Any], bool], rule: str, expected: str,
                            within: float | None = None) -> list[Received]:
        """At least one PARAM_VALUE after ``since`` for which ``pred(msg)`` holds, within
        ``param_reply_max_s``; the PARAM_VALUEs that do."""
        within = self.reply_max if within is None else within
        def match() -> list[Received]:
            return [r for r in self.from_vehicle(since, "PARAM_VALUE") if pred(r.msg)]
        if not self.link.wait_for(lambda: bool(match()), within):
            seen = [param_id(r.msg) for r in self.from_vehicle(since, "PARAM_VALUE")][:5]
            raise self.fail(rule, expected, f"none within {within:g} s"
                            + (f" (PARAM_VALUE for {', '.join(seen)})" if seen else " (no PARAM_VALUE)"))
        return match()

    def param_list(self, since: float) -> list[Any]:
        """The PARAM_VALUEs after ``since`` until ``param_list_gap_max_s`` passes with none
        (at most ``param_list_max_s``)."""
        gap, end = float(self.params["param_list_gap_max_s"]), self.now() + float(self.params["param_list_max_s"])
        count = -1
        while self.now() < end:
            n = len(self.from_vehicle(since, "PARAM_VALUE"))
            if n == count:
                break
            count = n
            self.link.wait_for(lambda n=n: len(self.from_vehicle(since, "PARAM_VALUE")) > n,
                               min(gap, max(0.0, end - self.now())))
        return [r.msg for r in self.from_vehicle(since, "PARAM_VALUE")]

    def capabilities(self) -> int | None:
        """AUTOPILOT_VERSION.capabilities, asked for with MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES
        once a run; None when the vehicle sends none."""
        got = self.from_vehicle(0.0, "AUTOPILOT_VERSION")
        if not got:
            since = self.command_long(DIALECT.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES, 1)
            self.link.wait_for(lambda: bool(self.from_vehicle(since, "AUTOPILOT_VERSION")), self.ack_max)
            got = self.from_vehicle(0.0, "AUTOPILOT_VERSION")
        return int(got[-1].msg.capabilities) if got else None

    # -- the mission protocol ---------------------------------------------------------------
    def plan(self, n: int = 4) -> list[dict[str, Any]]:
        """``n`` MISSION_ITEM_INT fields (seq 0 a waypoint, as ArduPilot's home; then a takeoff
        and waypoints 20 m apart), around the vehicle's GLOBAL_POSITION_INT, degE7 in a global
        relative-altitude integer frame."""
        pos = [r.msg for r in self.from_vehicle(0.0, "GLOBAL_POSITION_INT") if r.msg.lat or r.msg.lon]
        lat, lon = (pos[-1].lat, pos[-1].lon) if pos else (473977420, 85455940)
        items = []
        for seq in range(n):
            cmd = DIALECT.MAV_CMD_NAV_TAKEOFF if seq == 1 else DIALECT.MAV_CMD_NAV_WAYPOINT
            items.append({"seq": seq, "frame": DIALECT.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT, "command": cmd,
                          "current": 0, "autocontinue": 1, "param1": float(seq), "param2": 0.0, "param3": 0.0,
                          "param4": 0.0, "x": lat + 1800 * seq, "y": lon, "z": 10.0 + seq,
                          "mission_type": DIALECT.MAV_MISSION_TYPE_MISSION})
        return items

    def mission_replies(self, since: float) -> list[Received]:
        return [r for r in self.from_vehicle(since) if r.name in ("MISSION_REQUEST_INT", "MISSION_REQUEST",
                                                                    "MISSION_ACK")]

    def mission_requests(self, since: float, bound: int, wait: float) -> Iterator[Received]:
        """The vehicle's mission replies after ``since`` in order, each as it comes, for an
        upload's runner to answer (MAV-MIS-1/2): its MISSION_REQUEST_INTs and MISSION_REQUESTs,
        until a MISSION_ACK that ends the upload (any but MAV_MISSION_INVALID_SEQUENCE, a NACK
        that does not: E-1, read past) or ``wait`` s with no reply after the last one read;
        at most ``bound`` replies read (ACKs included)."""
        done = 0
        for _ in range(bound):
            if not self.link.wait_for(lambda done=done: len(self.mission_replies(since)) > done, wait):
                return
            reply = self.mission_replies(since)[done]
            done += 1
            if reply.name == "MISSION_ACK":
                if reply.msg.type == DIALECT.MAV_MISSION_INVALID_SEQUENCE:
                    continue
                return
            yield reply

    def upload(self, items: list[dict[str, Any]], *, withhold: int | None = None) -> list[Received]:
        """Upload ``items``: MISSION_COUNT, then each item the vehicle asks for
        (:meth:`mission_requests`: until its MISSION_ACK, or ``mission_reply_max_s`` with
        nothing new; bounded: 3 x count + 10 replies); ``withhold``: that seq's first request
        goes unanswered; a request already answered after it came is not answered again
        (:class:`ItemAnswers`). The vehicle's requests and ACKs, in order."""
        wait = float(self.params["mission_reply_max_s"])
        if withhold is not None:
            wait = max(wait, float(self.params["mission_rerequest_max_s"]))
        since = self.send("MISSION_COUNT", target_system=self.sysid, target_component=self.compid,
                          count=len(items), mission_type=DIALECT.MAV_MISSION_TYPE_MISSION)
        answers = ItemAnswers()
        for reply in self.mission_requests(since, 3 * len(items) + 10, wait):
            seq = reply.msg.seq
            if withhold == seq:
                withhold = None
                continue
            if 0 <= seq < len(items) and answers.due(reply):
                answers.sent(seq, self.send("MISSION_ITEM_INT", target_system=self.sysid,
                                            target_component=self.compid, **{k: v for k, v in items[seq].items()}))
        self.settle(answers, len(items) - 1)
        return upload_replies(self.mission_replies(since))

    def settle(self, answers: ItemAnswers, last: int) -> None:
        """After an upload in which the runner sent its last item (seq ``last``) again:
        ``mission_reply_max_s`` for the vehicle's answer to it (an error MISSION_ACK: the item
        came after the upload ended), so that it falls in this exchange, not in the next one's."""
        if last in answers.again:
            self.watch(float(self.params["mission_reply_max_s"]))

    def download(self) -> tuple[int | None, list[Any]]:
        """Download the mission: MISSION_REQUEST_LIST, then MISSION_REQUEST_INT for each seq,
        then MISSION_ACK; (the count, or None when no MISSION_COUNT came; the items that came)."""
        wait = float(self.params["mission_reply_max_s"])
        since = self.send("MISSION_REQUEST_LIST", target_system=self.sysid, target_component=self.compid,
                          mission_type=DIALECT.MAV_MISSION_TYPE_MISSION)
        if not self.link.wait_for(lambda: bool(self.from_vehicle(since, "MISSION_COUNT")), wait):
            return None, []
        count = int(self.from_vehicle(since, "MISSION_COUNT")[0].msg.count)
        items = []
        for seq in range(count):
            t = self.send("MISSION_REQUEST_INT", target_system=self.sysid, target_component=self.compid, seq=seq,
                          mission_type=DIALECT.MAV_MISSION_TYPE_MISSION)
            def got(t: float = t, seq: int = seq) -> list[Received]:
                return [r for r in self.from_vehicle(t)
                        if r.name in ("MISSION_ITEM_INT", "MISSION_ITEM") and r.msg.seq == seq]
            if not self.link.wait_for(lambda: bool(got()), wait):
                break
            items.append(got()[0].msg)
        self.send("MISSION_ACK", target_system=self.sysid, target_component=self.compid,
                  type=DIALECT.MAV_MISSION_ACCEPTED, mission_type=DIALECT.MAV_MISSION_TYPE_MISSION)
        return count, items

    def expect_upload(self, replies: list[Received], count: int, rule: str = "MAV-MIS-1",
                      order_rule: str = "MAV-MIS-2", rerequested: int | None = None) -> None:
        """An upload of ``count`` items as MAV-MIS-1 has it: requests for 0..count-1, then
        MISSION_ACK MAV_MISSION_ACCEPTED with the mission's mission_type (a
        MAV_MISSION_INVALID_SEQUENCE before it is a NACK that does not end the upload: E-1);
        MAV-MIS-2: in order, each request the last one again (a re-request) or the next, none
        past the end -- as the trace monitor reads it (``judge._mavlink_services``); with
        ``rerequested``, that seq requested again (MAV-MIS-3)."""
        seqs = [r.msg.seq for r in replies if r.name != "MISSION_ACK"]
        acks = [r for r in replies if r.name == "MISSION_ACK" and r.msg.type != DIALECT.MAV_MISSION_INVALID_SEQUENCE]
        want = list(range(count))
        if rerequested is not None:
            want.insert(rerequested + 1, rerequested)
        shown = [f"{r.name} {r.msg.seq if r.name != 'MISSION_ACK' else result_name_mission(r.msg.type)}"
                 for r in replies]
        steps = zip([-1, *seqs], seqs, strict=False)
        if any(s >= count for s in seqs) or not all(b in (a, a + 1) and b >= 0 for a, b in steps):
            raise self.fail(order_rule, f"requests for seq {want} (each the last one again, or the next)",
                            f"requests for seq {seqs}", shown)
        distinct = [s for i, s in enumerate(seqs) if i == 0 or s != seqs[i - 1]]
        again = rerequested is None or seqs.count(rerequested) > 1
        if not acks or acks[0].msg.type != DIALECT.MAV_MISSION_ACCEPTED or distinct != list(range(count)) or not again:
            got = f"MISSION_ACK {result_name_mission(acks[0].msg.type)}" if acks else "no MISSION_ACK"
            raise self.fail(rule, f"requests for seq {want}, then MISSION_ACK MAV_MISSION_ACCEPTED",
                            f"requests for seq {seqs}, {got}", shown)
        if acks[0].msg.mission_type != DIALECT.MAV_MISSION_TYPE_MISSION:
            raise self.fail(rule, "MISSION_ACK.mission_type MAV_MISSION_TYPE_MISSION",
                            f"mission_type {acks[0].msg.mission_type}", shown)

    @property
    def gcs(self) -> tuple[int, int]:
        """The runner's own system and component IDs."""
        return GCS_SYSID, GCS_COMPID


def upload_replies(replies: list[Received]) -> list[Received]:
    """An upload's replies up to the MISSION_ACK that ended it (the first but
    MAV_MISSION_INVALID_SEQUENCE, a NACK that does not: E-1): what came after it answers
    something else (an item the runner sent again)."""
    for i, r in enumerate(replies):
        if r.name == "MISSION_ACK" and r.msg.type != DIALECT.MAV_MISSION_INVALID_SEQUENCE:
            return replies[:i + 1]
    return replies


def result_name_mission(value: int) -> str:
    entry = DIALECT.enums["MAV_MISSION_RESULT"].get(value)
    return entry.name if entry is not None else f"{value} (no MAV_MISSION_RESULT)"

def param_id(msg: Any) -> str:
    """A PARAM_VALUE's or request's name as text (pymavlink gives str or bytes)."""
    raw = msg.param_id
    text = raw.decode("ascii", "replace") if isinstance(raw, bytes) else str(raw)
    return text.split("\0", 1)[0]

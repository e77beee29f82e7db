"""The MAVLink trace monitor's heartbeat, framing and command rules (``judge.mavlink_monitor``).

:class:`LinkService`: MAV-HB-1..12 as the heartbeat page (https://mavlink.io/en/services/heartbeat.html),
serialization page (https://mavlink.io/en/guide/serialization.html) and routing page
(https://mavlink.io/en/guide/routing.html) have them. :class:`CommandService`: the command
protocol (https://mavlink.io/en/services/command.html): "The recipient ... should respond
with a COMMAND_ACK", matched to the transmissions of its command first in, first out, as
the runner's case context waits for them (``conformance.cases_mavlink.mavlink_services.expect_ack``).
Every constant is the dialect's (``spec.MAVLINK.dialect``).
"""

from __future__ import annotations

import inspect
from collections import deque
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import Any, NamedTuple

from mcp_conform.spec import MAVLINK
from mcp_conform.traceio.mavlink import MavFrame

DIALECT: Any = MAVLINK.dialect
#: HEARTBEAT.mavlink_version as pymavlink's encoder fills it in (the dialect's, MAV-HB-9)
MAVLINK_VERSION = inspect.signature(DIALECT.MAVLink.heartbeat_encode).parameters["mavlink_version"].default
GCS_TYPES = frozenset({int(DIALECT.MAV_TYPE_GCS), int(DIALECT.MAV_TYPE_ONBOARD_CONTROLLER)})


def _entries(enum: str) -> dict[int, str]:
    return {int(v): e.name for v, e in DIALECT.enums[enum].items() if not e.name.endswith("_ENUM_END")}


RESULTS = _entries("MAV_RESULT")
TYPES, STACKS = _entries("MAV_TYPE"), _entries("MAV_AUTOPILOT")
COMMANDS = _entries("MAV_CMD")
IN_PROGRESS = int(DIALECT.MAV_RESULT_IN_PROGRESS)
_V2 = int(DIALECT.PROTOCOL_MARKER_V2)


class Violation(NamedTuple):
    """A rule broken by one node: when, what was expected and what came, the frames."""

    rule: str
    node: str  # "SYSID/COMPID"
    role: str
    t_ns: int
    expected: str
    actual: str
    evidence: tuple[str, ...] = ()
    frames: tuple[int, ...] = ()


@dataclass
class Node:
    """One source (system and component IDs) of the trace."""

    sysid: int
    compid: int
    role: str | None = None  # vehicle, gcs, other; None: not known yet
    frames: int = 0
    first_ns: int = 0
    last_ns: int = 0
    beats: int = 0
    last_beat_ns: int | None = None
    heartbeat: tuple[int, int] | None = None  # the last HEARTBEAT's (type, autopilot)
    seq: int | None = None
    state: dict[str, Any] = field(default_factory=dict)  # what the services keep of the node

    @property
    def key(self) -> tuple[int, int]:
        return self.sysid, self.compid

    @property
    def name(self) -> str:
        return f"{self.sysid}/{self.compid}"

    @property
    def ardupilot(self) -> bool:
        return self.heartbeat is not None and self.heartbeat[1] == DIALECT.MAV_AUTOPILOT_ARDUPILOTMEGA


@dataclass
class Expect:
    """An answer ``node`` owes by ``deadline``: the first frame of it ``match`` takes keeps
    ``rule``; none by then breaks it."""

    node: tuple[int, int]
    deadline: int
    rule: str
    match: Callable[[MavFrame], bool]
    expected: str
    frames: tuple[int, ...]
    on_expiry: Callable[[], str] | None = None


class Service:
    """A part of the monitor: the rules it judges and the messages it reads."""

    RULES: tuple[str, ...] = ()

    def __init__(self, mon: Any) -> None:
        self.mon = mon
        self.p = mon.params

    def handlers(self) -> dict[str, Any]:
        return {}

    def advance(self, t_ns: int) -> None:
        """Time is ``t_ns`` (before the frame of that time is read)."""

    def finish(self, end_ns: int) -> None:
        """The trace ended at ``end_ns``."""


def describe(f: MavFrame) -> str:
    """One line of evidence: ``#12 HEARTBEAT v2 from 1/1 seq 40: {...}``."""
    if f.bad:
        return f"#{f.index} bad data ({getattr(f.msg, 'reason', '?')}): {f.raw[:32].hex(' ')}"
    fields = {k: v for k, v in f.msg.to_dict().items() if k != "mavpackettype"}
    text = f"#{f.index} {f.name} v{f.version} from {f.source[0]}/{f.source[1]} seq {f.msg.get_seq()}: {fields}"
    return text if len(text) <= 240 else text[:237] + "..."


class Evidence:
    """``Evidence(f)`` as a judgement's evidence, described only when a violation keeps it
    (``MavlinkMonitor.judge``): every frame is judged by several rules, nearly always held, and
    describing a frame (pymavlink's ``to_dict``) was a sixth of the simulated ground station's
    runs (issue 38)."""

    __slots__ = ("f",)

    def __init__(self, f: MavFrame) -> None:
        self.f = f

    def __iter__(self) -> Iterator[str]:
        yield describe(self.f)


def name_of(table: dict[int, str], value: int) -> str:
    return table.get(int(value), f"{value} (not in the dialect)")


class LinkService(Service):
    """Heartbeat, identity and framing: MAV-HB-1..6, 8..12."""

    RULES = ("MAV-HB-1", "MAV-HB-2", "MAV-HB-3", "MAV-HB-4", "MAV-HB-5", "MAV-HB-6", "MAV-HB-8", "MAV-HB-9",
             "MAV-HB-10", "MAV-HB-11", "MAV-HB-12")

    def __init__(self, mon: Any) -> None:
        super().__init__(mon)
        self.gap_ns = int(float(self.p["heartbeat_gap_max_s"]) * 1e9)
        #: per recorded direction, the IDs of its first HEARTBEAT (MAV-HB-6 in our MCAP)
        self.side_ids: dict[str, tuple[int, int]] = {}

    def handlers(self) -> dict[str, Any]:
        return {"*": self.every_frame, "HEARTBEAT": self.heartbeat}

    def every_frame(self, n: Node, f: MavFrame) -> None:
        mon, t = self.mon, f.t_ns
        sysid, compid = f.source
        ids_ok = 1 <= sysid <= 255 and 1 <= compid <= 255
        side = self.side_ids.get(f.direction or "")
        same = side is None or sysid != side[0] or (sysid, compid) == side
        other = "" if side is None or same else f" (the side's HEARTBEAT: {side[0]}/{side[1]})"
        mon.judge("MAV-HB-6", n, ids_ok and same, t,
                  "source IDs 1..255, one pair for every frame of the node" if ids_ok else "source IDs 1..255",
                  f"{f.name} from {sysid}/{compid}{other}",
                  Evidence(f), (f.index,))
        mon.judge("MAV-HB-10", n, True, t)
        if mon.complete:
            seq = int(f.msg.get_seq())
            if n.seq is not None:
                want = (n.seq + 1) % 256
                mon.judge("MAV-HB-11", n, seq == want, t, f"seq {want} (the previous frame's + 1)",
                          f"{f.name} with seq {seq}", Evidence(f), (f.index,))
            n.seq = seq
        if f.raw[0] == _V2:
            length = f.raw[1]
            payload = f.raw[10:10 + length]
            mon.judge("MAV-HB-12", n, not (length > 1 and payload[-1:] == b"\0"), t,
                      "a MAVLink 2 payload without trailing zeros", f"{f.name}: {length} B ending in a zero",
                      Evidence(f), (f.index,))

    def bad_frame(self, f: MavFrame) -> None:
        """Bytes that are no good frame: the vehicle's MAV-HB-10 where the trace says it sent
        them (a tlog's cannot be put on anyone)."""
        mon = self.mon
        if f.direction is None:
            mon.unattributed_bad += 1
            return
        role = "vehicle" if f.direction == "tx" else "gcs"
        side = self.side_ids.get(f.direction)
        n = mon.nodes.get(side) if side else next((x for x in mon.nodes.values() if x.role == role), None)
        if n is not None:
            mon.judge("MAV-HB-10", n, False, f.t_ns, "whole MAVLink frames of the dialect, checksums right",
                      describe(f), Evidence(f), (f.index,))

    def heartbeat(self, n: Node, f: MavFrame) -> None:
        mon, m, t = self.mon, f.msg, f.t_ns
        if f.direction is not None:
            self.side_ids.setdefault(f.direction, f.source)
        gap_rule = "MAV-HB-1" if n.role == "vehicle" else "MAV-HB-2"
        if n.last_beat_ns is not None:
            gap = t - n.last_beat_ns
            mon.judge(gap_rule, n, gap <= self.gap_ns, t, f"a HEARTBEAT at least every {self.gap_ns / 1e9:g} s",
                      f"{gap / 1e9:.2f} s without one", Evidence(f), (f.index,))
        n.last_beat_ns = t
        n.beats += 1
        n.heartbeat = (int(m.type), int(m.autopilot))
        mon.judge("MAV-HB-9", n, m.mavlink_version == MAVLINK_VERSION, t, f"mavlink_version {MAVLINK_VERSION}",
                  f"mavlink_version {m.mavlink_version}", Evidence(f), (f.index,))
        ev = (Evidence(f), (f.index,))
        if n.role == "vehicle":
            bad_type = m.type not in TYPES or m.type in GCS_TYPES
            bad_stack = m.autopilot not in STACKS or m.autopilot == DIALECT.MAV_AUTOPILOT_INVALID
            actual = (f"type {name_of(TYPES, m.type)}" if bad_type else f"autopilot {name_of(STACKS, m.autopilot)}")
            mon.judge("MAV-HB-3", n, not (bad_type or bad_stack), t,
                      "HEARTBEAT.type a vehicle's MAV_TYPE, HEARTBEAT.autopilot a flight stack", actual, *ev)
            mon.judge("MAV-HB-8", n, n.compid == DIALECT.MAV_COMP_ID_AUTOPILOT1, t,
                      f"component ID {DIALECT.MAV_COMP_ID_AUTOPILOT1} (MAV_COMP_ID_AUTOPILOT1)",
                      f"component ID {n.compid}", *ev)
        elif n.role == "gcs":
            mon.judge("MAV-HB-4", n, m.type in GCS_TYPES, t, "HEARTBEAT.type MAV_TYPE_GCS or MAV_TYPE_ONBOARD_CONTROLLER",
                      f"type {name_of(TYPES, m.type)}", *ev)
            mon.judge("MAV-HB-5", n, m.autopilot == DIALECT.MAV_AUTOPILOT_INVALID, t,
                      "HEARTBEAT.autopilot MAV_AUTOPILOT_INVALID", f"autopilot {name_of(STACKS, m.autopilot)}", *ev)

    def finish(self, end_ns: int) -> None:
        """The tail: the last HEARTBEAT of each node to the trace's end (at a session's end,
        to the node's own last frame: ``MavlinkMonitor._next_segment``)."""
        for n in list(self.mon.nodes.values()):
            end_ns = n.last_ns if self.mon.segment_ending else end_ns
            rule = "MAV-HB-1" if n.role == "vehicle" else "MAV-HB-2"
            if n.last_beat_ns is not None and end_ns - n.last_beat_ns > self.gap_ns:
                self.mon.judge(rule, n, False, end_ns, f"a HEARTBEAT at least every {self.gap_ns / 1e9:g} s",
                               f"none in the last {(end_ns - n.last_beat_ns) / 1e9:.2f} s of the trace")
            elif n.last_beat_ns is None and n.last_ns - n.first_ns > self.gap_ns:
                self.mon.judge(rule, n, False, end_ns, f"a HEARTBEAT at least every {self.gap_ns / 1e9:g} s",
                               f"no HEARTBEAT in {(n.last_ns - n.first_ns) / 1e9:.2f} s of its frames")


@dataclass
class Sent:
    """One transmission of a command: when, by whom, to whom."""

    t_ns: int
    index: int
    kind: str  # COMMAND_LONG, COMMAND_INT
    sender: tuple[int, int]
    target: tuple[int, int]
    command: int
    confirmation: int
    deadline: int
    in_progress: bool = False
    expired: bool = False
    acked_ns: int | None = None  # when a final COMMAND_ACK answered it


class CommandService(Service):
    """The command protocol: MAV-CMD-1..5, 7, 8, 11, 12, 14, 15."""

    RULES = ("MAV-CMD-1", "MAV-CMD-2", "MAV-CMD-3", "MAV-CMD-4", "MAV-CMD-5", "MAV-CMD-7", "MAV-CMD-8",
             "MAV-CMD-11", "MAV-CMD-12", "MAV-CMD-14", "MAV-CMD-15")
    MAX_SENT = 1024  # transmissions of one command kept at once

    def __init__(self, mon: Any) -> None:
        super().__init__(mon)
        self.ack_ns = int(float(self.p["command_ack_max_s"]) * 1e9)
        self.progress_ns = int(float(self.p["in_progress_final_max_s"]) * 1e9)
        self.resend_ns = int(float(self.p["command_resend_window_s"]) * 1e9)
        self.sent: dict[int, deque[Sent]] = {}
        #: (vehicle, command) -> the times of its last final ACKs that answered a transmission
        self.acked: dict[tuple[tuple[int, int], int], deque[int]] = {}
        #: (ground station, command) -> its last transmission (MAV-CMD-7/8)
        self.last: dict[tuple[tuple[int, int], int], Sent] = {}
        #: final ACKs that answered no transmission yet: their command may be stamped after
        #: them (``mavlink_monitor.ORDER_SLACK_S``)
        self.held: list[tuple[Node, MavFrame]] = []

    def handlers(self) -> dict[str, Any]:
        return {"COMMAND_LONG": self.command, "COMMAND_INT": self.command, "COMMAND_ACK": self.ack}

    def rule_of(self, s: Sent) -> str:
        if s.command not in COMMANDS:
            return "MAV-CMD-5"
        return "MAV-CMD-2" if s.kind == "COMMAND_INT" else "MAV-CMD-1"

    def command(self, n: Node, f: MavFrame) -> None:
        m, t = f.msg, f.t_ns
        conf = int(getattr(m, "confirmation", 0))
        s = Sent(t, f.index, f.name, n.key, (int(m.target_system), int(m.target_component)), int(m.command),
                 conf, t + self.ack_ns)
        q = self.sent.setdefault(s.command, deque())
        if len(q) >= self.MAX_SENT:
            q.popleft()
        q.append(s)
        if f.name == "COMMAND_LONG":
            self._numbering(n, f, s, q)
        self.last[(n.key, s.command)] = s
        for v, a in list(self.held):  # an ACK stamped before this, its command (ORDER_SLACK_S)?
            if int(a.msg.command) == s.command and a.t_ns >= t - self.mon.slack_ns and self.addressed(s, v):
                other = self._other(v, a)
                if other is None or abs(a.t_ns - other.t_ns) > t - a.t_ns:  # no nearer command for it
                    self.held.remove((v, a))
                    self.ack(v, a)

    def _numbering(self, n: Node, f: MavFrame, s: Sent, q: deque[Sent]) -> None:
        """The ground station's numbering of a COMMAND_LONG's transmissions: confirmation 0 on
        a first one (MAV-CMD-7), the last one's + 1 on a resend (MAV-CMD-8). A transmission
        is a resend when the ground station's last one of the command, within
        command_resend_window_s, is still owed its ACK; or when that one was answered but this
        one crossed the ACK -- sent before the ground station read it, it numbers it a resend
        (confirmation > 0), arriving within command_resend_window_s of the ACK going out (a
        lossy link, a reader off the CPU). A crossed copy numbered neither the last one's + 1
        nor 0 is a first transmission misnumbered (MAV-CMD-7) or a resend misnumbered
        (MAV-CMD-8): the trace cannot tell which, and neither rule is judged on it."""
        t, conf = s.t_ns, s.confirmation
        prev = self.last.get((n.key, s.command))
        ev = (Evidence(f), (f.index,))
        if prev is None or t - prev.t_ns > self.resend_ns:
            resend = False
        elif any(x is prev for x in q):
            resend = True
        elif prev.acked_ns is not None and conf > 0 and t - prev.acked_ns <= self.resend_ns:
            if conf != prev.confirmation + 1:
                return  # a crossed resend or a new command, misnumbered either way: not which rule
            resend = True
        else:
            resend = False
        if not resend:
            self.mon.judge("MAV-CMD-7", n, conf == 0, t, "confirmation 0 on a command's first transmission",
                           f"confirmation {conf}", *ev)
        else:
            self.mon.judge("MAV-CMD-8", n, conf == prev.confirmation + 1, t,  # type: ignore[union-attr]
                           f"confirmation {prev.confirmation + 1} on a resend", f"confirmation {conf}", *ev)  # type: ignore[union-attr]

    @staticmethod
    def addressed(s: Sent, v: Node) -> bool:
        return s.target[0] == 0 or (s.target[0] == v.sysid and s.target[1] in (0, v.compid))

    def ack(self, v: Node, f: MavFrame) -> None:
        mon, m, t = self.mon, f.msg, f.t_ns
        command, result = int(m.command), int(m.result)
        asker = (int(getattr(m, "target_system", 0)), int(getattr(m, "target_component", 0)))
        q = self.sent.get(command, deque())
        mine = [s for s in q if asker[0] in (0, s.sender[0]) and asker[1] in (0, s.sender[1])]
        ev = Evidence(f)
        if result == IN_PROGRESS:
            progress = int(getattr(m, "progress", 0))
            mon.judge("MAV-CMD-12", v, progress <= 100 or progress == 255, t, "progress 0..100, or 255 (unknown)",
                      f"progress {progress}", ev, (f.index,))
            for s in mine:
                if self.addressed(s, v) and not s.expired:
                    s.in_progress, s.deadline = True, t + self.progress_ns
                    break
            return
        to_me = ([s for s in mine if not s.expired and self.addressed(s, v)]
                 or [s for s in mine if s.expired and self.addressed(s, v)])  # a late ACK: an expired one
        if to_me:
            s = to_me[0]
            q.remove(s)
            s.acked_ns = t
            self.acked.setdefault((v.key, command), deque(maxlen=8)).append(t)
            frames = (s.index, f.index)
            if s.expired:
                return  # late: its rule was broken at its deadline
            rule = "MAV-CMD-11" if s.in_progress else self.rule_of(s)
            unknown = s.command not in COMMANDS
            ok = result in RESULTS and (not unknown or result == DIALECT.MAV_RESULT_UNSUPPORTED)
            mon.judge(rule, v, ok, t, "MAV_RESULT_UNSUPPORTED for a command no MAV_CMD has" if unknown
                      else "COMMAND_ACK.result a MAV_RESULT", f"result {name_of(RESULTS, result)}", ev, frames)
            if rule != self.rule_of(s):
                mon.judge(self.rule_of(s), v, True, t)
            mon.judge("MAV-CMD-3", v, True, t)
            if s.target[1] == 0 and s.target[0] == v.sysid:
                mon.judge("MAV-CMD-15", v, True, t)
            if f.version == 2:
                mon.judge("MAV-CMD-4", v, asker == s.sender, t,
                          f"COMMAND_ACK.target_system/component {s.sender[0]}/{s.sender[1]} (the sender)",
                          f"{asker[0]}/{asker[1]}", ev, frames)
            return
        self.held.append((v, f))  # its command may be stamped after it (mavlink_monitor.ORDER_SLACK_S)
        mon.later(t + mon.slack_ns, lambda: self._unmatched(v, f))

    def _explain(self, v: Node, f: MavFrame) -> None:
        """A final ACK that answered no transmission to ``v``, put on the nearer in time of: a
        command of it to another system or component, still owed an answer, sent before it (or
        stamped at most ORDER_SLACK_S after it): the vehicle acting for that one (MAV-CMD-14);
        and the vehicle's last final ACK of the command before it (a second one for one
        transmission: MAV-CMD-3). Neither: an ACK for a command the trace does not hold (sent
        before it began, or on another link), not judged."""
        mon, t = self.mon, f.t_ns
        command, result = int(f.msg.command), int(f.msg.result)
        last = max((x for x in self.acked.get((v.key, command), ()) if x <= t), default=None)
        q = self.sent.get(command, deque())
        other = self._other(v, f)
        ev = Evidence(f)
        if other is not None and (last is None or abs(t - other.t_ns) < t - last):
            q.remove(other)
            mon.judge("MAV-CMD-14", v, False, t, f"no COMMAND_ACK for a command to {other.target[0]}/{other.target[1]}",
                      f"COMMAND_ACK {name_of(RESULTS, result)} from {v.name}", ev, (other.index, f.index))
        elif last is not None:
            mon.judge("MAV-CMD-3", v, False, t, f"one final COMMAND_ACK per transmission of command {command}",
                      f"another COMMAND_ACK {name_of(RESULTS, result)} with no transmission left to answer",
                      ev, (f.index,))

    def _other(self, v: Node, f: MavFrame) -> Sent | None:
        """The transmission of ``f``'s command to another system or component than ``v``,
        still owed an answer, nearest ``f`` in time (stamped at most ORDER_SLACK_S after it)."""
        t = f.t_ns
        asker = (int(getattr(f.msg, "target_system", 0)), int(getattr(f.msg, "target_component", 0)))
        others = [s for s in self.sent.get(int(f.msg.command), ()) if not s.expired and not self.addressed(s, v)
                  and s.t_ns <= t + self.mon.slack_ns and asker[0] in (0, s.sender[0])
                  and asker[1] in (0, s.sender[1])]
        return min(others, key=lambda s: abs(t - s.t_ns)) if others else None

    def _unmatched(self, v: Node, f: MavFrame) -> None:
        """A held ACK whose slack is over, no transmission to ``v`` having come for it."""
        if (v, f) in self.held:
            self.held.remove((v, f))
            self._explain(v, f)

    def advance(self, t_ns: int) -> None:
        for q in self.sent.values():
            for s in list(q):
                if s.expired:
                    if t_ns - s.deadline > self.resend_ns:
                        q.remove(s)  # a late ACK now counts as none of its
                    continue
                if s.deadline >= t_ns:
                    continue
                s.expired = True
                self._unanswered(s)

    def _unanswered(self, s: Sent) -> None:
        """No final ACK for ``s`` by its deadline: which rule that breaks, or keeps."""
        mon = self.mon
        if s.target[0] == 0:
            return  # a broadcast: no one in particular owed an answer
        asked = f"{s.kind} {name_of(COMMANDS, s.command)} from {s.sender[0]}/{s.sender[1]} to {s.target[0]}/{s.target[1]}"
        within = (s.deadline - s.t_ns) / 1e9
        system = [v for v in mon.vehicles() if v.sysid == s.target[0]]
        for v in mon.vehicles():
            if v in system and s.target[1] in (0, v.compid):
                if s.in_progress:
                    rule, what = "MAV-CMD-11", f"a final COMMAND_ACK within {within:g} s of IN_PROGRESS"
                elif s.target[1] == 0 and v.compid != 0:
                    rule, what = "MAV-CMD-15", f"a COMMAND_ACK within {within:g} s (component 0: every component)"
                else:
                    rule = self.rule_of(s)
                    what = f"a COMMAND_ACK with command {s.command} within {within:g} s"
                mon.judge(rule, v, False, s.deadline, f"after {asked}, {what}", "no COMMAND_ACK for it",
                          (f"#{s.index} {asked}, confirmation {s.confirmation}",), (s.index,))
            else:
                mon.judge("MAV-CMD-14", v, True, s.deadline)

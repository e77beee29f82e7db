"""A capture judged by the trace monitor: what ``mcp-capture check`` and ``show`` share.

``judge(path, params)`` reads the capture (``traceio.reader``), feeds every datagram to
``judge.monitor.Monitor`` in capture order, closes the trace at its last record, and
returns a :class:`Judgement`: the nodes found (MCP ID, role, addresses, datagrams sent and
received), the violations, the monitor's per-node, per-rule verdicts, and what the capture
itself said (format, truncated, notes). Without a challenge it infers one from the manager's
commands (WP_List: challenge 1, WP_On / WP_Off: 2, Obstacles_List: 3, MCP-FLOW-4/5/6) and
says which datagram decided, or why none could be inferred.

What it is judged with (:class:`Params`) and the options that set it (``add_monitor_options``,
shared by ``check`` and ``show``) are ``judge.params``'s, imported here too.
"""

from __future__ import annotations

import contextlib
import gc
from array import array
from collections import deque
from collections.abc import Iterator
from dataclasses import dataclass, field, replace
from operator import attrgetter
from pathlib import Path
from typing import Any

from mcp_conform.judge.params import Params, add_monitor_options, params_from_args, selected
from mcp_conform.judge.run_monitor import MISSION_METADATA, from_node, recorded_mission, session_end
from mcp_conform.spec.codec import PREAMBLE, Action, peek_header
from mcp_conform.traceio.files import UsageError
from mcp_conform.traceio.merge import SEGMENT
from mcp_conform.traceio.reader import (
    CaptureError,
    CaseMark,
    Datagram,
    MavlinkFrame,
    Metadata,
    VehicleMark,
    open_capture,
)
from mcp_conform.traceio.recorder import NODE_METADATA, RUN_DELAY_METADATA, recorded_run_delay
from mcp_conform.traceio.trace import Node, action_name, evidence_indexes

__all__ = ["VERDICT_RANK", "Judgement", "MonitorUnavailable", "NoJudge", "Params", "UsageError", "add_monitor_options",
           "evidence_of", "fetch", "judge", "merge_segments", "params_from_args", "selected", "CaptureError"]

#: The challenge each challenge-specific command implies (MCP-FLOW-4/5/6).
CHALLENGE_OF = {int(Action.WP_LIST): 1, int(Action.WP_ON): 2, int(Action.WP_OFF): 2,
                int(Action.OBSTACLES_LIST): 3}


@dataclass
class Judgement:
    path: str
    format: str
    params: Params
    nodes: dict[int, Node]
    violations: list[Any]
    verdicts: dict[int, dict[str, str]]
    datagrams: int
    first_ns: int | None
    last_ns: int | None
    truncated: str | None
    notes: list[str]
    unattributed: int = 0  # datagrams without an MCP header
    kept: list[Datagram] | None = None  # every datagram, when asked for (charts)
    cases: list[CaseMark] = field(default_factory=list)
    metadata: list[Metadata] = field(default_factory=list)
    vehicle_drone: int | None = None  # whose autopilot link was judged (our MCAP captures)
    evidence: dict[int, Datagram] = field(default_factory=dict)  # what judging kept of the evidence
    #: a merged capture's sessions (pytest-xdist workers: gw0, ...), each judged on its own
    segments: dict[str, Judgement] = field(default_factory=dict)

    @property
    def shown_violations(self) -> list[Any]:
        select = self.params.select
        if not select:  # every rule selected: a copy, not a million calls (issue 17)
            return list(self.violations)
        return [v for v in self.violations if selected(v.rule, select)]

    def failing(self) -> list[Any]:
        """Violations that make the exit code 1: MUSTs, and SHOULDs under --strict."""
        bad = {"MUST", "SHOULD"} if self.params.strict else {"MUST"}
        counts: dict[Any, bool] = {}  # per level: the levels are few, the violations may be a million
        out = []
        for v in self.shown_violations:
            level = v.level
            got = counts.get(level)
            if got is None:
                got = counts[level] = str(level).upper() in bad
            if got:
                out.append(v)
        return out

    def exit_code(self) -> int:
        return 1 if self.failing() else 0

    def rel(self, t_ns: int) -> float:
        return (t_ns - (self.first_ns or 0)) / 1e9


class MonitorUnavailable(UsageError):
    """This installation has no trace monitor (``judge.monitor``)."""


def _make_monitor(params: Params, party: int | None = None) -> Any:
    try:
        from mcp_conform.judge.monitor import Monitor
    except ImportError as exc:
        raise MonitorUnavailable(f"the trace monitor (judge.monitor) is not available: {exc}") from None

    return Monitor(rto=params.rto, ack_window=params.ack_window, broadcast_id=params.broadcast_id,
                   drones=list(params.drones) if params.drones is not None else None,
                   challenge=params.challenge, waypoints=params.waypoints, complete=params.complete,
                   party=party, rto_declared=params.rto_declared)


class NoJudge:
    """Reads a trace without judging it (``show`` where the monitor is unavailable)."""

    inferred_challenge = None

    def datagram(self, t_ns: int, src_addr: Any, dst_addr: Any, data: bytes, origin: Any = None,
                 run_delay: int | None = None) -> list[Any]:
        return []

    def finish(self, t_ns: int) -> list[Any]:
        return []

    def verdicts(self) -> dict[int, dict[str, str]]:
        return {}


MISSION_READY = int(Action.MISSION_READY)
#: MCAP writers whose own datagrams (``/mcp/tx``) are the test harness's: input to the node
#: under test, often faulty on purpose, never blamed (the monitor's ``TESTER`` origin).
HARNESSES = frozenset({"mcp-conform", "mcp-fuzz", "mcp-capture"})
#: The writer of a node's own capture (``mcp-node --capture``).
NODE_RECORDER = "mcp-node"
#: Writers of a node's own view: the node itself, or ``mcp-soak``'s medium (what the node
#: sent into its link and what the link delivered to it: complete for that node's part).
NODE_RECORDERS = frozenset({NODE_RECORDER, "mcp-soak"})


def judge(path: str | Path, params: Params, keep: bool = False, monitor: Any = None) -> Judgement:
    """Read ``path`` and judge it; raises :class:`traceio.reader.CaptureError`.

    Our MCAP captures: the harness's own datagrams are fed as the monitor's ``TESTER``
    origin, the trace is complete (the runner's socket saw every datagram it exchanged),
    and the autopilot-link frames (``/mavlink``) are fed as vehicle events of the drone
    under test (the sender of the first Mission_Ready the harness received). A pcap is
    complete only with ``--complete``.

    A capture merged from pytest-xdist workers (``traceio.merge``) holds one session per
    worker, each against its own node with its own runner: each segment is judged on its
    own, by its own monitor, as that worker's run monitor judged it (its node, its runner's
    ID and address, its parameters); ``Judgement.segments`` holds each, and the judgement of
    the file is theirs merged per node (:func:`merge_segments`). So does a run that restarts
    its node for each fresh mission (``mcp-conform --role manager``): each mission is a session
    (``McapRecorder.begin_segment``; under xdist ``gw0/main``), complete on its own; the
    run's metadata holds for every session, a session's for it and those within it."""
    cap = open_capture(path)  # unreadable files fail here, before any judging
    sessions: dict[str | None, _Session] = {}
    meta: list[Metadata] = []

    def session(seg: str | None) -> _Session:
        got = sessions.get(seg)
        if got is None:
            got = sessions[seg] = _Session(cap.format, params if seg is None else replace(params), keep,
                                           monitor if seg is None else _fresh(monitor))
            for rec in meta:  # the run's records so far that hold for this session
                if _holds_for(rec, seg):
                    got.metadata(rec)
        return got

    with _collector_paused():
        for rec in cap:
            if isinstance(rec, Metadata):
                meta.append(rec)
                for seg, s in sessions.items():
                    if _holds_for(rec, seg):
                        s.metadata(rec)
            elif type(rec) is Datagram:  # most records: straight to its session's datagram
                session(rec.segment).datagram(rec)
            elif isinstance(rec, (Datagram, MavlinkFrame, VehicleMark, CaseMark)):
                session(rec.segment).record(rec)
        if not sessions:
            session(None)
        judged = {seg: s.finish(str(path), cap) for seg, s in sessions.items()}  # sorted: a key per violation
    if list(judged) == [None]:
        j = judged[None]
        j.metadata = meta
        return j
    parts = {str(seg): j for seg, j in judged.items()}
    out = merge_segments(str(path), cap, parts, meta)
    params.__dict__.update(out.params.__dict__)
    out.params = params
    return out


@contextlib.contextmanager
def _collector_paused() -> Iterator[None]:
    """Python's cyclic garbage collector off while a capture is read and judged, back as it
    was after (an error too). What judging keeps grows with the capture (every violation, its
    evidence datagram: two million tuples for a million violations), and each of the
    collector's passes over the oldest generation walks all of it: a fifth of the CPU time of
    checking a million violations (issue 17). Reading and judging make almost no cyclic
    garbage (the collector found some 1,800 objects in those 10^6 datagrams); refcounting
    frees the rest as before, and the collector takes up what is left once it is back.
    What judging made goes to the oldest generation at once (``gc.freeze`` then
    ``gc.unfreeze``: a splice of lists), not through three passes of the collector over
    it; only when nothing else is frozen (a process that froze its objects keeps them so)."""
    was = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if gc.get_freeze_count() == 0:
            gc.freeze()
            gc.unfreeze()
        if was:
            gc.enable()


def _holds_for(rec: Metadata, seg: str | None) -> bool:
    """Whether a metadata record holds for session ``seg``: a record of no session holds
    for every one (the run's), a session's for it and the sessions within it (``gw0`` for
    ``gw0/main``: a worker's run whose missions are sessions, ``traceio.merge.nested``)."""
    own = rec.data.get(SEGMENT)
    return own is None or (seg is not None and (seg == own or seg.startswith(own + "/")))


#: How a node's verdicts of several segments merge: the worst wins (as the merged report's
#: monitor section of an xdist run merges its workers' sections).
VERDICT_RANK = {"not_observed": 0, "info": 1, "passed": 2, "warned": 3, "failed": 4}


def merge_segments(path: str, cap: Any, parts: dict[str, Judgement], meta: list[Metadata]) -> Judgement:
    """One judgement of a merged capture from its segments' (each judged on its own): the
    violations of all, each node's verdicts worst-first, its addresses and counts summed."""
    first = next(iter(parts.values()))
    nodes: dict[int, Node] = {}
    verdicts: dict[int, dict[str, str]] = {}
    for j in parts.values():
        for nid, n in j.nodes.items():
            have = nodes.get(nid)
            if have is None:
                nodes[nid] = Node(n.id, n.role, set(n.addresses), n.sent, n.received)
            else:
                have.addresses |= set(n.addresses)
                have.sent += n.sent
                have.received += n.received
        for nid, table in j.verdicts.items():
            merged = verdicts.setdefault(nid, {})
            for rule, verdict in table.items():
                if VERDICT_RANK.get(verdict, 0) >= VERDICT_RANK.get(merged.get(rule, "not_observed"), 0):
                    merged[rule] = verdict
    firsts = [j.first_ns for j in parts.values() if j.first_ns is not None]
    lasts = [j.last_ns for j in parts.values() if j.last_ns is not None]
    kept = None if first.kept is None else sorted((d for j in parts.values() for d in j.kept or ()),
                                                  key=lambda d: d.index)
    violations = sorted((v for j in parts.values() for v in j.violations), key=lambda v: (v.rule, v.t_ns))
    evidence = {i: d for j in parts.values() for i, d in j.evidence.items()}
    cases = sorted((c for j in parts.values() for c in j.cases), key=lambda c: c.t_ns)
    params = replace(first.params)
    notes = list(cap.notes) + [f"{len(parts)} sessions ({', '.join(parts)}: pytest-xdist workers, or missions "
                               "of a run that restarts its node): each judged on its own, verdicts merged per node"]
    return Judgement(path, cap.format, params, dict(sorted(nodes.items())), violations,
                     dict(sorted(verdicts.items())), sum(j.datagrams for j in parts.values()),
                     min(firsts) if firsts else None, max(lasts) if lasts else None, cap.truncated,
                     notes, sum(j.unattributed for j in parts.values()), kept, cases, meta,
                     first.vehicle_drone, evidence, parts)


def _fresh(monitor: Any) -> Any:
    """A monitor of the same kind for another segment (``show``'s :class:`NoJudge`)."""
    return None if monitor is None else type(monitor)()


class _Session:
    """One session of a capture (the whole file, or one segment of a merged file) judged by
    its own monitor. The monitor numbers the datagrams it is fed; ``fed`` maps its numbers
    back to the capture's indexes, so evidence names the file's datagrams."""

    def __init__(self, fmt: str, params: Params, keep: bool, monitor: Any) -> None:
        self.format = fmt
        self.params = params
        self.mon = monitor
        self.tester = _tester()
        self.harness: bool | None = None
        self.violations: list[Any] = []
        self.kept: list[Datagram] | None = [] if keep else None
        self.recent: dict[int, Datagram] = {}  # the evidence of a violation is mostly recent
        self.order: deque[int] = deque()
        self.evidence: dict[int, Datagram] = {}
        self.fed = array("q")  # the monitor's datagram numbers -> the capture's indexes
        self.fed_as_is = True  # so far each capture index is the monitor's number: nothing to map
        self.cases: list[CaseMark] = []
        self.frames: list[Any] = []  # autopilot-link records before the drone under test is known
        self.drone: int | None = None
        self.node_addr: Any = None  # the drone under test's address: what comes from there is its own
        self.recorded_complete: bool | None = None  # how the run's own monitor judged the trace
        self.recorded_harness = False  # the run's metadata names a harness as its recorder
        self.party: int | None = None  # a node's own capture: that node's ID
        #: (t_ns, node ID, ns): run delays recorded without a datagram (RUN_DELAY_METADATA)
        self.run_delays: list[tuple[int, int, int]] = []
        self.marks = False  # the run recorded the link and fix events its monitor judged by
        self.first: int | None = None
        self.last: int | None = None  # the last datagram or autopilot-link record
        self.last_mark: int | None = None  # the last case mark
        self.n = self.unattributed = 0

    def metadata(self, rec: Metadata) -> None:
        recorder = rec.data.get("recorder")
        if rec.name == RUN_DELAY_METADATA:  # as the runner stopped its node: fed at the finish
            got = recorded_run_delay(rec.data)
            if got is not None:
                self.run_delays.append(got)
        elif self.mon is None and recorder in HARNESSES:  # before the first datagram
            self.recorded_harness = True
            self.params.adopt(_recorded_parameters(rec))
        elif self.mon is None and recorder in NODE_RECORDERS:
            # a node's own capture (mcp-node --capture): its socket saw every datagram it
            # exchanged, so the file says it is complete; the node's own timeout
            self.params.adopt(_recorded_parameters(rec))
            if rec.data.get("complete") in ("true", "false"):
                self.recorded_complete = rec.data["complete"] == "true"
            with contextlib.suppress(KeyError, ValueError):  # complete for what it took part in
                self.party = int(rec.data["node_id"])
        elif rec.name == MISSION_METADATA and self.mon is None:  # the mission, as the run's monitor knew it
            self.params.adopt_mission(*recorded_mission(rec.data))
        elif rec.name == NODE_METADATA and self.drone is None:  # the node under test, as the run knew it
            self.drone, self.node_addr = _recorded_node(rec)
            if rec.data.get("complete") in ("true", "false"):  # as the run's monitor judged it
                self.recorded_complete = rec.data["complete"] == "true"

    def _found(self, found: list[Any]) -> None:
        if not found:
            return
        fed = self.fed
        recent, kept = self.recent, self.evidence
        for v in found:
            ev = getattr(v, "evidence", None)
            if ev and not self.fed_as_is:
                mapped = tuple((fed[e[0]], *e[1:]) if isinstance(e, tuple) and e and isinstance(e[0], int)
                               and 0 <= e[0] < len(fed) and fed[e[0]] != e[0] else e for e in ev)
                if any(a is not b for a, b in zip(mapped, ev, strict=True)):
                    v = v._replace(evidence=mapped)  # else shared with the monitor's own record
            for i in evidence_indexes(v):
                d = recent.get(i)
                if d is not None:
                    kept[i] = d
            self.violations.append(v)

    def record(self, rec: Any) -> None:
        if isinstance(rec, Datagram):
            self.datagram(rec)
        elif isinstance(rec, (MavlinkFrame, VehicleMark)):
            self.last = max(self.last or rec.t_ns, rec.t_ns)
            self.marks = self.marks or isinstance(rec, VehicleMark)
            if self.drone is None or self.mon is None:
                self.frames.append(rec)
            else:
                self._found(_vehicle(self.mon, rec, self.drone, self.marks))
        elif isinstance(rec, CaseMark):
            self.cases.append(rec)
            self.last_mark = max(self.last_mark or rec.t_ns, rec.t_ns)

    def datagram(self, rec: Datagram) -> None:
        index, t, src_addr, dst_addr, data, direction, _, burst, _, rd = rec
        params = self.params
        if self.first is None:
            self.first = t
            self.harness = rec.recorder in HARNESSES or (rec.segment is not None and self.recorded_harness)
            if self.mon is None:
                # a harness is a party to every exchange with the one node it tests, so its
                # capture holds them all (complete), as does a node's own capture (mcp-node
                # --capture) when its record says so -- complete for what that node took part
                # in, unless the user says the whole trace is (--complete); any other capture
                # is judged as lossy
                party = None if params.complete else self.party
                params.complete = params.complete or (self.format == "mcap" and (
                    (self.harness and self.recorded_complete is not False) or self.recorded_complete is True))
                self.mon = _make_monitor(params, party)
            if self.drone is not None:  # named by the run's record: its autopilot link so far
                self._flush()
        harness = self.harness
        self.last = t
        self.n += 1
        self.recent[index] = rec
        order = self.order
        order.append(index)
        if len(order) > RECENT:
            del self.recent[order.popleft()]
        h = peek_header(data) if harness and self.drone is None and direction == "rx" else None
        if h is not None and h[3] == MISSION_READY:  # its sender is the drone under test:
            self.drone, self.node_addr = h[1], src_addr  # its autopilot link so far, then this
            self._flush()
        feed = self.mon.datagram
        if burst and harness:
            # a flood the harness recorded as a count (its MCP-ROB-7 input, judged by its
            # case): the run's monitor judges around it, and so does this one
            found: list[Any] = []
        else:
            fed = self.fed
            if index != len(fed):
                self.fed_as_is = False
            fed.append(index)
            if harness and direction == "tx":
                found = feed(t, src_addr, dst_addr, data, self.tester)
            elif harness and from_node(src_addr, self.node_addr):  # the node's own
                found = feed(t, src_addr, dst_addr, data, self.drone, **_rd(rec))
            elif rd is None:  # as _rd has it: no keyword at all
                found = feed(t, src_addr, dst_addr, data)
            else:
                found = feed(t, src_addr, dst_addr, data, run_delay=rd)
        if found:
            self._found(found)
        if self.kept is not None:
            self.kept.append(rec)
        if not data.startswith(PREAMBLE) or len(data) < 17:
            self.unattributed += 1

    def _flush(self) -> None:
        """The autopilot-link records held until the drone under test was known, judged."""
        assert self.drone is not None
        self.marks = self.marks or any(isinstance(f, VehicleMark) for f in self.frames)
        for f in self.frames:
            self._found(_vehicle(self.mon, f, self.drone, self.marks))
        self.frames.clear()

    def finish(self, path: str, cap: Any) -> Judgement:
        params = self.params
        mon = self.mon
        if mon is None:  # no datagram at all
            mon = self.mon = _make_monitor(params)
        marks, data = self.last_mark, self.last
        last = data if marks is None else max(data or marks, marks)  # the session's last record
        if last is not None:
            # a node's run delay as the runner stopped it (D-7): a stall after its last
            # datagram, which the veto weighs as the run monitor's own finish would
            sample = getattr(mon, "run_delay", None)
            end = last
            if sample is not None:
                stop = None
                for t_ns, node, ns in self.run_delays:
                    sample(t_ns, node, ns)
                    end = max(end, t_ns)
                    stop = max(stop or t_ns, t_ns)
                # the view ends where the runner stopped the node (its reading's time), as the
                # run monitor's own finish comes after that stop: a view ended at the last
                # datagram left that reading outside it (judge.veto weighs none after the view's
                # end), and check failed MCP-RTX-2 where the live monitor, weighing it, had
                # vetoed it; and no later, where that stop came after the node's last datagram
                # (run_monitor.session_end: the runner's case marks after it are no time of the
                # node's, a false MCP-RTX-1 of the silent drone's stopped manager instance)
                cut = session_end(end, data, stop)
                end = end if cut is None else cut
            self._found(mon.finish(end))
        if params.challenge is None:
            inferred = getattr(mon, "inferred_challenge", None)
            params.challenge_source = "inferred" if inferred else "unknown"
            params.challenge_note = (
                f"challenge {inferred} inferred from the manager's commands "
                f"({', '.join(a for a, c in _CHALLENGE_NAMES if c == inferred)}); give --challenge to override"
                if inferred else "challenge not inferred: the manager sent no WP_List, WP_On, WP_Off or "
                "Obstacles_List; MCP-FLOW-4/5/6 were not judged (give --challenge)")
            params.challenge = inferred
        # judge.explain's veto (judge/veto.py) dropped these at the monitor's finish: the
        # violations collected as they came are filtered, and each one's explanation noted
        vetoed = list(getattr(mon, "vetoed", ()))
        gone = {_key(x.violation) for x in vetoed}  # not by identity: evidence may be remapped
        violations = sorted((v for v in self.violations if _key(v) not in gone) if gone else self.violations,
                            key=_BY_RULE_AND_TIME)
        notes = [*cap.notes, *(x.note() for x in vetoed)] if vetoed else cap.notes
        nodes = {f.id: Node(f.id, f.role, set(f.addresses), f.datagrams, f.received) for f in _nodes(mon)}
        return Judgement(path, cap.format, params, nodes, violations, mon.verdicts(), self.n, self.first,
                         last, cap.truncated, notes, self.unattributed, self.kept, self.cases, [],
                         self.drone, self.evidence)


def _key(v: Any) -> tuple[Any, ...]:
    return v.rule, v.node, v.t_ns, v.actual


#: The order of a session's violations: by rule, then time (stable).
_BY_RULE_AND_TIME = attrgetter("rule", "t_ns")
_CHALLENGE_NAMES = tuple((action_name(a), c) for a, c in CHALLENGE_OF.items())


#: Datagrams kept while judging, to show a violation's evidence without reading the file again.
RECENT = 4096


def _tester() -> Any:
    try:
        from mcp_conform.judge.monitor import TESTER
    except ImportError:
        return None
    return TESTER


def _recorded_parameters(rec: Metadata) -> dict[str, Any]:
    """The run's parameters as its metadata record holds them (JSON), else nothing."""
    import json

    try:
        values = json.loads(rec.data.get("parameters") or "{}")
    except (ValueError, RecursionError):
        return {}
    return values if isinstance(values, dict) else {}


def _rd(rec: Datagram) -> dict[str, int]:
    """The sender's run delay as the capture recorded it (MCP-RTX-3, ``judge.spacing``), as
    the monitor's keyword: none at all where unknown (a monitor of four parameters still works)."""
    return {} if rec.run_delay_ns is None else {"run_delay": rec.run_delay_ns}


def _recorded_node(rec: Metadata) -> tuple[int | None, Any]:
    """The node under test's ID and address from the run's record (None, None if unusable)."""
    try:
        node = int(rec.data.get("id", ""))
        host, _, port = str(rec.data.get("address", "")).rpartition(":")
        address = (host, int(port))
    except ValueError:
        return None, None
    return (node, address) if 0 <= node <= 0xFFFF and host else (None, None)


def _nodes(mon: Any) -> list[Any]:
    return list(mon.nodes()) if hasattr(mon, "nodes") else []


def _vehicle(mon: Any, rec: MavlinkFrame | VehicleMark, drone: int, marks: bool) -> list[Any]:
    """One autopilot-link record as the run's monitor took it: the link and fix events the
    run recorded (``/vehicle``), and the frames the drone wrote to its autopilot; without
    recorded events (a node's own capture, older captures) the fix comes from the
    autopilot's GPS_RAW_INT frames."""
    from mcp_conform.judge.monitor import VehicleEvent, events_from_mavlink

    if isinstance(rec, VehicleMark):
        return mon.vehicle(rec.t_ns, drone, VehicleEvent(rec.kind, detail=rec.detail or ""))
    direction = rec.direction or "rx"
    if marks and direction == "tx":
        return []  # the recorded fix events say the same, before the frames left
    out: list[Any] = []
    for ev in events_from_mavlink(rec.data, direction):
        out.extend(mon.vehicle(rec.t_ns, drone, ev))
    return out


def evidence_of(j: Judgement, indexes: set[int] | None = None) -> dict[int, Datagram]:
    """The datagrams of ``indexes`` (default: every shown violation's evidence): from what
    judging kept, else from a second, targeted pass over the file (evidence far older than the
    violation). When judging kept them all, its own dict is returned, not a copy (a million
    violations: a copy and the set of indexes cost more than 100 MB)."""
    if indexes is None:
        have = j.evidence if j.kept is None else {d.index: d for d in j.kept}
        missing = {i for v in j.shown_violations for i in evidence_indexes(v) if i not in have}
        return {**have, **fetch(j.path, missing)} if missing else have
    kept = {d.index: d for d in j.kept if d.index in indexes} if j.kept is not None else \
        {i: j.evidence[i] for i in indexes if i in j.evidence}
    missing = indexes - set(kept)
    return {**kept, **fetch(j.path, missing)} if missing else kept


def fetch(path: str | Path, indexes: set[int]) -> dict[int, Datagram]:
    """The datagrams of ``indexes`` (a second, targeted pass: evidence for the report)."""
    out: dict[int, Datagram] = {}
    if not indexes:
        return out
    top = max(indexes)
    for d in open_capture(path).datagrams():
        if d.index in indexes:
            out[d.index] = d
        if d.index >= top:
            break
    return out

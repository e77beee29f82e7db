"""The MAVLink trace monitor: the rules of ``spec/mavlink.yaml`` that traffic alone shows, judged
from who sent what, for either role, live and offline (``mcp-capture check --protocol mavlink``).

Fed every frame of a link in order (:meth:`MavlinkMonitor.feed`, a ``traceio.mavlink.MavFrame``:
from our MCAP's ``/mavlink`` channel, a ``.tlog``, or a live link), it keeps per node (a
source system/component pair) what the rules need and judges each rule as the frames come:
per rule ``failed`` (a MUST broken) or ``warned`` (a SHOULD), with the node, the time, what
was expected and what came and the frames as evidence, ``passed`` (judged, none broke it) or
``not_observed``. Memory is bounded: the expectations open at once and the examples kept per
rule are capped, and the counts go on.

Who is who (mavlink.io's heartbeat page: "the type of the component" in HEARTBEAT.type):
where the trace says (our MCAP records each frame from the autopilot's side: ``tx`` the
vehicle sent it, ``rx`` the ground station), that; else a node's HEARTBEAT: a flight stack
in ``autopilot`` (not MAV_AUTOPILOT_INVALID) is a vehicle, MAV_TYPE_GCS or
MAV_TYPE_ONBOARD_CONTROLLER with MAV_AUTOPILOT_INVALID a ground station (MAV-HB-4), an
autopilot's component ID (MAV_COMP_ID_AUTOPILOT1) a vehicle, anything else (a gimbal, a
camera) another component, not judged; before its first HEARTBEAT, by the messages it sends
(the spec's ``sent_by`` of each service's messages).

What is judged (the rest needs what the runner's cases send, or the node's own state):

- heartbeat and framing (``judge._mavlink_link``): MAV-HB-1/2 (no gap over
  heartbeat_gap_max_s between two HEARTBEATs of a node, nor after its last one to the
  trace's end), HB-3/4/5 (type and autopilot per role), HB-6 (source IDs 1..255; in our
  MCAP one pair on the vehicle's side), HB-8 (SHOULD: MAV_COMP_ID_AUTOPILOT1), HB-9
  (mavlink_version), HB-10 (a frame the vehicle sent that is no good frame: only where the
  trace says who sent it), HB-11 (sequence numbers: only where the trace holds every frame
  of the link, our MCAP; a tlog cannot tell a frame lost on the radio from a number
  skipped), HB-12 (MAVLink 2 payloads truncated);
- commands (``judge._mavlink_link``): MAV-CMD-1/2 (a COMMAND_LONG/COMMAND_INT addressed to a
  vehicle answered by a final COMMAND_ACK of its command within command_ack_max_s, a
  MAV_RESULT), CMD-3 (one final ACK per transmission: ACKs are matched to transmissions
  first in, first out), CMD-4 (SHOULD: the ACK names the sender), CMD-5 (a command no
  MAV_CMD has: MAV_RESULT_UNSUPPORTED), CMD-11 (IN_PROGRESS ended within
  in_progress_final_max_s), CMD-12 (progress), CMD-14 (a command for another system or
  component not acknowledged), CMD-15 (SHOULD: component 0 answered); the ground station's
  CMD-7 (a first transmission has confirmation 0), CMD-8 (SHOULD: a resend increments it; a
  resend that crossed the ACK of the transmission before it is still a resend);
- parameters and missions (``judge._mavlink_services``).

The same frames get the same verdicts wherever they were seen: the runner's cases judge a
rule by what they sent and saw (``conformance.mavlink_case``), with the same bounds from the
spec's parameters; this monitor judges what the trace shows of it, and its verdicts agree
with the cases' on the rules both judge (tests/captures/test_mavlink_capture.py).
"""

from __future__ import annotations

from collections import Counter, deque
from collections.abc import Callable, Iterable
from typing import Any

from mcp_conform.judge._mavlink_link import (
    GCS_TYPES,
    CommandService,
    Expect,
    LinkService,
    Node,
    Violation,
)
from mcp_conform.judge._mavlink_services import MissionService, ParamService
from mcp_conform.spec import MAVLINK
from mcp_conform.spec.mavlink import MavlinkSpec
from mcp_conform.traceio.mavlink import MavFrame, parse_frame, robust_parser

__all__ = ["RULES", "MavlinkMonitor", "Node", "Violation"]

DIALECT: Any = MAVLINK.dialect
#: the rules this monitor judges, in the spec's order
RULES: tuple[str, ...] = tuple(r.id for r in MAVLINK.rules if r.id in {
    *LinkService.RULES, *CommandService.RULES, *ParamService.RULES, *MissionService.RULES})
#: the role a message names its sender's, before its first HEARTBEAT (spec: ``sent_by``)
SENT_BY = {m.name: m.sent_by for m in MAVLINK.messages if m.sent_by != "any"}
#: How long before its request an answer may be stamped and still be its answer. A trace's
#: two directions are ordered by their record times; the runner's link
#: (``harness.mavlink_session.Link``) stamps a frame before sending it and its answer once it
#: came, under one lock, so none of its answers is stamped first. A recorder that stamps a
#: frame once sent can stamp the answer first, by as long as its sending thread waits: the
#: runner's link did until its captures were stamped before sending, by over 100 ms under load.
#: Measured (issue 39): our captures since then need 0; the earlier ones at hand, MAVProxy's
#: tlogs and the MCP drone runs' autopilot links judge the same from 2 ms up; from 50 ms up a
#: request of an earlier exchange is taken for this one's (a false MAV-MIS-2 on our vehicle).
ORDER_SLACK_S = 0.01


class MavlinkMonitor:
    """The one judge of MAVLink traffic (see the module docstring).

    ``roles``: the roles judged (our MCAP of ``mcp-conform --protocol mavlink`` judges its
    node under test's; a tlog both); ``complete``: the trace holds every frame of its link
    (MAV-HB-11 is judged); ``params``: the spec's parameters, overridden."""

    MAX_EXAMPLES = 200
    MAX_EXPECTS = 4096

    def __init__(self, spec: MavlinkSpec = MAVLINK, *, roles: tuple[str, ...] = ("vehicle", "gcs"),
                 complete: bool = False, params: dict[str, Any] | None = None) -> None:
        self.spec = spec
        self.roles = tuple(roles)
        self.complete = complete
        self.params = {**spec.params, **(params or {})}
        self.nodes: dict[tuple[int, int], Node] = {}
        self.judged: Counter[str] = Counter()
        self.failed: dict[str, list[Violation]] = {r: [] for r in RULES}
        self.failed_count: Counter[str] = Counter()
        self.expects: list[Expect] = []
        self.dropped_expects = 0
        self.first_ns: int | None = None
        self.last_ns: int | None = None
        self.count = 0
        self.unattributed_bad = 0  # bytes no frame of a tlog (whose sender nobody knows)
        self._parsers: dict[Any, Any] = {}
        self.slack_ns = int(ORDER_SLACK_S * 1e9)
        #: the last frames, for an answer stamped before its request (:data:`ORDER_SLACK_S`)
        self.recent: deque[MavFrame] = deque(maxlen=256)
        self._later: list[tuple[int, Callable[[], None]]] = []
        #: the trace's session the frames come from (``MavFrame.segment``), and the nodes of
        #: the sessions before it (:meth:`_next_segment`)
        self.segment: str | None = None
        self._live_segment: str | None = None
        self.retired: list[Node] = []
        #: a session is ending: each node's heartbeat is judged up to its own last frame
        self.segment_ending = False
        self._start_services()

    def _start_services(self) -> None:
        self.services = (LinkService(self), CommandService(self), ParamService(self), MissionService(self))
        self._handlers: dict[str, list[Callable[[Node, MavFrame], None]]] = {}
        for svc in self.services:
            for name, handler in svc.handlers().items():
                self._handlers.setdefault(name, []).append(handler)

    def _next_segment(self) -> None:
        """The trace's next session (``McapRecorder.begin_segment``: the gcs role's runner
        starts each ground station afresh, and its vehicle with it): what was owed in the
        session that ended is judged at its last frame, what was owed later is not (the
        runner stopped its parties), and every party starts anew -- a new process numbers
        its frames from 0 and its first command has confirmation 0, no gap in MAV-HB-11's
        count, no resend of MAV-CMD-8's. A node's heartbeat is judged up to its own last
        frame: its silence after it is the stopping's, not its own (MAV-HB-2 "while it
        commands nothing": while it is on the link)."""
        end = self.last_ns or 0
        later, self._later = self._later, []
        for _, fn in later:
            fn()
        self.advance(end + 1)
        self.segment_ending = True
        try:
            for svc in self.services:
                svc.finish(end)
        finally:
            self.segment_ending = False
        self.expects = []
        self.retired.extend(self.nodes.values())
        self.nodes = {}
        self.recent.clear()
        self._start_services()

    def all_nodes(self) -> list[Node]:
        """Every node of the trace, the earlier sessions' first."""
        return [*self.retired, *self.nodes.values()]

    def role_of(self, source: tuple[int, int]) -> str | None:
        """The role of the node with these IDs (its latest session's), None: not known."""
        roles = [n.role for n in self.all_nodes() if n.key == source and n.role]
        return roles[-1] if roles else None

    # -- feeding --------------------------------------------------------------------------
    def begin_segment(self, name: str) -> None:
        """A live link's next session (the capture's ``McapRecorder.begin_segment`` of the
        same name): the frames from now on are its, judged as :meth:`_next_segment` says."""
        self._live_segment = name
        self._parsers = {}  # a new link: no bytes of the last one's half-read frames

    def frame(self, t_ns: int, raw: bytes, direction: str | None = None, msg: Any = None) -> None:
        """One frame of a live link (``msg``: pymavlink's, when already parsed)."""
        if msg is None:
            p = self._parsers.get(direction)
            if p is None:
                p = self._parsers[direction] = robust_parser()
            msg = parse_frame(raw, p)
        self.feed(MavFrame(self.count, int(t_ns), direction, bytes(raw), msg, self._live_segment))

    def feed(self, f: MavFrame) -> None:
        """The trace's next frame, in time order."""
        if f.segment != self.segment:
            if self.count:
                self._next_segment()
            self.segment = f.segment
        t = f.t_ns
        self.advance(t)
        self.count += 1
        if self.first_ns is None:
            self.first_ns = t
        self.last_ns = t if self.last_ns is None else max(self.last_ns, t)
        if f.bad:
            self.services[0].bad_frame(f)  # type: ignore[attr-defined]
            return
        n = self.node_of(f)
        n.frames += 1
        n.first_ns = n.first_ns or t
        n.last_ns = t
        for handler in self._handlers.get("*", ()):
            handler(n, f)
        for handler in self._handlers.get(f.name, ()):
            handler(n, f)
        if self.expects:
            self._answers(n, f)
        self.recent.append(f)

    def node_of(self, f: MavFrame) -> Node:
        """The frame's sender, its role settled as the module docstring says."""
        key = f.source
        n = self.nodes.get(key)
        if n is None:
            n = self.nodes[key] = Node(*key)
        if f.direction is not None:
            n.role = "vehicle" if f.direction == "tx" else "gcs"
        elif f.name == "HEARTBEAT":
            m = f.msg
            if m.autopilot != DIALECT.MAV_AUTOPILOT_INVALID:
                n.role = "vehicle"
            elif m.type in GCS_TYPES:
                n.role = "gcs"
            else:
                n.role = "vehicle" if key[1] == DIALECT.MAV_COMP_ID_AUTOPILOT1 else "other"
        elif n.role is None:
            n.role = SENT_BY.get(f.name)
        return n

    def vehicles(self) -> list[Node]:
        return [n for n in self.nodes.values() if n.role == "vehicle"]

    # -- expectations ---------------------------------------------------------------------
    def expect(self, node: Node, within_s: float, rule: str, match: Callable[[MavFrame], bool],
               expected: str, frames: tuple[int, ...], t_ns: int,
               on_expiry: Callable[[], str] | None = None) -> None:
        """``node`` owes a frame ``match`` takes within ``within_s`` of ``t_ns``."""
        if not self.judges(rule, node):
            return
        for r in self.recent_from(node, t_ns):
            if match(r):
                self.judge(rule, node, True, r.t_ns)
                return
        if len(self.expects) >= self.MAX_EXPECTS:
            self.expects.pop(0)
            self.dropped_expects += 1
        self.expects.append(Expect(node.key, t_ns + int(within_s * 1e9), rule, match, expected, frames, on_expiry))

    def recent_from(self, node: Node, t_ns: int) -> list[MavFrame]:
        """``node``'s frames stamped at most :data:`ORDER_SLACK_S` before ``t_ns``."""
        return [r for r in self.recent if r.t_ns >= t_ns - self.slack_ns and r.source == node.key]

    def later(self, t_ns: int, fn: Callable[[], None]) -> None:
        """Call ``fn`` once time passes ``t_ns`` (a judgement that waits for the slack)."""
        self._later.append((t_ns, fn))

    def _answers(self, n: Node, f: MavFrame) -> None:
        kept = []
        for e in self.expects:
            if e.node == n.key and e.match(f):
                self.judge(e.rule, n, True, f.t_ns)
            else:
                kept.append(e)
        self.expects = kept

    def advance(self, t_ns: int) -> None:
        """Time is ``t_ns``: what was owed before it and did not come breaks its rule."""
        if self.expects and any(e.deadline < t_ns for e in self.expects):
            kept = []
            for e in self.expects:
                if e.deadline < t_ns:
                    n = self.nodes[e.node]
                    within = (e.deadline - (self.first_ns or 0)) / 1e9
                    actual = e.on_expiry() if e.on_expiry else "nothing"
                    self.judge(e.rule, n, False, e.deadline, e.expected, f"{actual} (by +{within:.3f} s)",
                               frames=e.frames)
                else:
                    kept.append(e)
            self.expects = kept
        if self._later and any(due < t_ns for due, _ in self._later):
            due_now = [fn for due, fn in self._later if due < t_ns]
            self._later = [(due, fn) for due, fn in self._later if due >= t_ns]
            for fn in due_now:
                fn()
        for svc in self.services:
            svc.advance(t_ns)

    def finish(self, t_ns: int | None = None) -> None:
        """The trace ended at ``t_ns`` (its last frame's time by default): what was owed by
        then is judged; what was owed later is not (the trace ended before its bound)."""
        end = t_ns if t_ns is not None else (self.last_ns or 0)
        later, self._later = self._later, []
        for _, fn in later:  # nothing more comes: what waited for the slack is judged now
            fn()
        self.advance(end + 1)
        for svc in self.services:
            svc.finish(end)
        self.expects = []

    # -- verdicts -------------------------------------------------------------------------
    def judges(self, rule: str, node: Node) -> bool:
        """Whether ``rule`` is judged on ``node``: its role is one judged and the rule's."""
        r = self.spec.rules_by_id[rule]
        return node.role in self.roles and ("any" in r.roles or node.role in r.roles)

    def judge(self, rule: str, node: Node, ok: bool, t_ns: int, expected: str = "", actual: str = "",
              evidence: Iterable[str] = (), frames: tuple[int, ...] = ()) -> None:
        """One observation of ``rule`` on ``node``: held (``ok``) or broken. ``evidence``: its
        lines, made into a tuple only when kept (``_mavlink_link.Evidence``: described then)."""
        if not self.judges(rule, node):
            return
        self.judged[rule] += 1
        if ok:
            return
        self.failed_count[rule] += 1
        if len(self.failed[rule]) < self.MAX_EXAMPLES:
            self.failed[rule].append(Violation(rule, node.name, node.role or "?", t_ns, expected, actual,
                                               evidence if type(evidence) is tuple else tuple(evidence), frames))

    def verdicts(self) -> dict[str, str]:
        """rule -> failed (a MUST broken), warned (a SHOULD), passed or not_observed."""
        out = {}
        for rule in RULES:
            if self.failed_count[rule]:
                out[rule] = "failed" if self.spec.rules_by_id[rule].level == "MUST" else "warned"
            else:
                out[rule] = "passed" if self.judged[rule] else "not_observed"
        return out

    @property
    def violations(self) -> list[Violation]:
        return sorted((v for r in RULES for v in self.failed[r]), key=lambda v: (v.t_ns, v.rule))

    def _nodes_json(self) -> list[dict[str, Any]]:
        """One entry per node, its sessions' counts summed (a ground station started afresh
        for each case is one node of the report)."""
        out: dict[str, dict[str, Any]] = {}
        for n in self.all_nodes():
            e = out.setdefault(n.name, {"id": n.name, "role": n.role, "frames": 0, "heartbeats": 0,
                                        "type": None, "autopilot": None})
            e["frames"] += n.frames
            e["heartbeats"] += n.beats
            e["role"] = e["role"] or n.role
            if n.heartbeat:
                e["type"], e["autopilot"] = n.heartbeat
        return list(out.values())

    def to_json(self) -> dict[str, Any]:
        """The monitor's judgement as a report's ``monitor`` section has it."""
        return {
            "complete": self.complete,
            "frames": self.count,
            "nodes": self._nodes_json(),
            "violations": [{"rule": v.rule, "node": v.node, "role": v.role, "t_ns": v.t_ns, "expected": v.expected,
                            "actual": v.actual, "evidence": list(v.evidence), "frames": list(v.frames)}
                           for v in self.violations],
            "failed_count": {r: self.failed_count[r] for r in RULES if self.failed_count[r]},
            "rules": self.verdicts(),
        }

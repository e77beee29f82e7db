"""The trace monitor over a whole conformance run (docs/design.md, "The trace monitor").

One :class:`RunMonitor` per run watches every datagram the runner sends and receives (the
target driver's observer hook, the same one captures use) and, where the runner drives the
simulated vehicle, every frame on the node's autopilot link. The runner's own datagrams
are fed as the harness's (``origin=TESTER``): they are input to the node, often faulty on
purpose (a wrong-source ACK, a bad preamble), and never blamed. A datagram that arrives
from the node's address is fed as the node's (``origin=target ID``), so a malformed one is
still the node's (MCP-HDR-1/2) and a wrong src is MCP-HDR-4. The runner's socket sees all
traffic between it and the node, so the trace is complete (absences are evidence).

Thread-safe: the driver's receive thread, the sending thread and the vehicle's threads
all feed it. The report's ``monitor`` section is :meth:`RunMonitor.to_json`.
"""

from __future__ import annotations

import contextlib
import heapq
import threading
import time
from typing import Any

from mcp_conform.judge.monitor import (
    TESTER,
    Monitor,
    Violation,
    events_from_mavlink,
    events_from_vehicle,
)

__all__ = ["LINK_KINDS", "MISSION_METADATA", "REORDER_NS", "RunMonitor", "SessionMonitors", "from_node",
           "link_events", "mission_metadata", "recorded_mission", "session_end", "violation_json"]

#: The vehicle's events the run's monitor judges by (the link, the fix coming and going, an
#: earlier command's action in progress and done: MCP-BLK-7); the frames on the link come
#: through ``events_from_mavlink``. The capture records the same ones.
LINK_KINDS = ("link", "fix", "fix_lost", "busy", "idle")


def link_events(event: Any) -> list[Any]:
    """The monitor's events (``LINK_KINDS``) for one ``vehicle.records.Event``."""
    return [e for e in events_from_vehicle(event) if e.kind in LINK_KINDS]


def from_node(addr: Any, node_addr: Any) -> bool:
    """Whether a datagram from ``addr`` is the node's own: from the node's port, and its host
    or any loopback host (a node listening on every address answers from 127.x)."""
    if addr is None or node_addr is None:
        return False
    host, port = node_addr
    if addr[1] != port:
        return False
    return host in ("", "0.0.0.0", addr[0]) or str(addr[0]).startswith("127.")

#: How long a datagram or event is held so that everything is fed in time order.
REORDER_NS = 100_000_000


def violation_json(v: Violation) -> dict[str, Any]:
    return {"rule": v.rule, "level": v.level, "node": v.node, "t_ns": v.t_ns, "expected": v.expected,
            "actual": v.actual, "evidence": [{"index": i, "t_ns": t} for i, t in v.evidence]}


def vetoed_json(x: Any) -> dict[str, Any]:
    """A failure the monitor dropped at its finish because ``judge.explain`` explains the trace
    without it (``judge.veto.Vetoed``): the violation as it was, and the explanation."""
    return {**violation_json(x.violation), "sender": x.sender, "receiver": x.receiver,
            "explanation": x.explanation}


class RunMonitor:
    """A :class:`~judge.monitor.Monitor` fed by the runner (see the module docstring).

    ``node_id`` is the node under test's MCP ID when known, ``node_addr`` its address
    (datagrams from there are its own), ``vehicle_id`` the drone whose autopilot link the
    runner observes (None: not observed).
    """

    def __init__(self, *, rto: float, ack_window: float, broadcast_id: int, node_id: int | None,
                 node_addr: tuple[str, int] | None, complete: bool = True,
                 drones: Any = None, challenge: int | None = None, waypoints: Any = None,
                 rto_declared: bool = False, reorder_ns: int | None = REORDER_NS) -> None:
        self.monitor = Monitor(rto=rto, ack_window=ack_window, broadcast_id=broadcast_id,
                               drones=drones, challenge=challenge, waypoints=waypoints, complete=complete,
                               rto_declared=rto_declared)
        self.node_id = node_id
        self.node_addr = node_addr
        self.listen: tuple[str, int] | None = None
        self._lock = threading.Lock()
        self._finished = False
        self._pending: list[tuple[int, int, Any, tuple[Any, ...]]] = []  # heap: (t_ns, n, fn, args)
        self._n = 0
        self.errors = 0  # feeding problems (a monitor bug must not stop the run)
        #: how long a datagram is held before it is fed (None: until read, everything in order)
        self.reorder_ns = reorder_ns

    # ------------------------------------------------------------------ feeding
    def _push(self, t_ns: int, fn: Any, *args: Any) -> None:
        """Feed in time order: the sending thread reports a datagram after it left, so the
        node's answer can reach the receiving thread first; hold everything ``reorder_ns``
        (None: until the monitor is read -- a runner thread taken off the CPU between a
        datagram's stamp and its report can report it any time later)."""
        with self._lock:
            if self._finished:
                return
            self._n += 1
            heapq.heappush(self._pending, (t_ns, self._n, fn, args))
            if self.reorder_ns is not None:
                self._drain(t_ns - self.reorder_ns)

    def _drain(self, until: int | None = None) -> None:
        pending = self._pending
        while pending and (until is None or pending[0][0] <= until):
            t_ns, _, fn, args = heapq.heappop(pending)
            try:
                fn(t_ns, *args)
            except Exception:  # noqa: BLE001 - a monitor bug must not stop the run
                self.errors += 1

    def observe(self, direction: str, data: bytes, addr: tuple[str, int], t_ns: int,
                run_delay: int | None = None) -> None:
        """The target driver's observer: ("tx"|"rx", data, peer address, t_ns), with the
        spawned node's run delay when known (MCP-RTX-3)."""
        if direction == "tx":
            self._push(t_ns, self.monitor.datagram, self.listen, addr, data, TESTER)
        else:
            self._push(t_ns, self.monitor.datagram, addr, self.listen, data, self._origin(addr), run_delay)

    def _origin(self, addr: Any) -> int | None:
        """The node's own datagrams are the ones from its address (any local host when it
        listens on all addresses)."""
        if self.node_id is None:
            return None
        return self.node_id if from_node(addr, self.node_addr) else None

    def run_delay(self, t_ns: int, node: int, run_delay_ns: int) -> None:
        """The spawned node's run delay read as the runner stops it (``Monitor.run_delay``): a
        stall after its last datagram, as ``mcp-capture check`` reads it from the capture."""
        self._push(t_ns, self.monitor.run_delay, node, run_delay_ns)

    def vehicle_frame(self, t_ns: int, direction: str, raw: bytes) -> None:
        """A frame the node wrote to its autopilot ("rx"); the autopilot's own ("tx") are
        left out: the vehicle's fix events say the same, before the frames leave."""
        if direction == "rx":
            self._vehicle(t_ns, events_from_mavlink(raw, direction))

    def vehicle_event(self, t_ns: int, event: Any) -> None:
        """One ``vehicle.records.Event`` of the simulated vehicle: the link connecting and
        the GPS fix coming and going (recorded before the telemetry that shows it is sent,
        so no Mission_Ready that answers it can come first)."""
        self._vehicle(t_ns, link_events(event))

    def _vehicle(self, t_ns: int, events: list[Any]) -> None:
        if events and self.node_id is not None:
            for ev in events:
                self._push(t_ns, self.monitor.vehicle, self.node_id, ev)

    # ------------------------------------------------------------------ reading
    def finish(self, t_ns: int | None = None) -> None:
        with self._lock:
            if not self._finished:
                self._drain()
                self._finished = True
                try:
                    self.monitor.finish(time.time_ns() if t_ns is None else t_ns)
                except Exception:  # noqa: BLE001
                    self.errors += 1

    def verdicts(self) -> dict[int, dict[str, str]]:
        with self._lock:
            self._drain()
            return self.monitor.verdicts()

    def violations(self, rule: str | None = None, node: int | None = None) -> list[Violation]:
        """The violations so far (everything fed until now judged)."""
        with self._lock:
            self._drain()
            return [v for v in self.monitor.violations
                    if (rule is None or v.rule == rule) and (node is None or v.node == node)]

    def verdict(self, node: int, rule: str) -> str:
        return self.verdicts().get(node, {}).get(rule, "not_observed")

    def to_json(self) -> dict[str, Any]:
        """The report's ``monitor`` section."""
        with self._lock:
            self._drain()
            m = self.monitor
            return {
                "complete": m.complete,
                "datagrams": m.count,
                "nodes": [{"id": n.id, "role": n.role, "addresses": [f"{h}:{p}" for h, p in n.addresses],
                           "datagrams": n.datagrams} for n in m.nodes()],
                "violations": [violation_json(v) for v in m.violations],
                "vetoed": [vetoed_json(x) for x in m.vetoed],
                "rules": {str(k): v for k, v in m.verdicts().items()},
            }


#: The metadata record of a session's mission as the run's monitor judged it: the challenge
#: and the items the manager was handed (waypoints; obstacles for challenge 3), so that
#: ``mcp-capture check`` judges MCP-FLOW-4/5/6 with them as the run did.
MISSION_METADATA = "mcp-conform mission"


def mission_metadata(challenge: int, items: Any) -> dict[str, str]:
    """``MISSION_METADATA``'s values: the challenge, and each item's fields (JSON)."""
    import json

    out = {"challenge": str(challenge)}
    if items is not None:
        out["items"] = json.dumps([list(it) for it in items])
    return out


def recorded_mission(values: dict[str, str]) -> tuple[int | None, tuple[Any, ...] | None]:
    """(challenge, items) of a ``MISSION_METADATA`` record; None for what is unusable."""
    import json

    from mcp_conform.spec.codec import MissionItem

    challenge: int | None = None
    with contextlib.suppress(ValueError):
        challenge = int(values.get("challenge", ""))
    if challenge not in (1, 2, 3):
        challenge = None
    items = None
    with contextlib.suppress(ValueError, TypeError, RecursionError):
        got = json.loads(values["items"]) if "items" in values else None
        if isinstance(got, list) and all(isinstance(it, list) and len(it) == len(MissionItem._fields) for it in got):
            items = tuple(MissionItem._make(it) for it in got)
    return challenge, items


def session_end(last: int | None, data: int | None, stop: int | None) -> int | None:
    """Where a session's view ends, live (:class:`SessionMonitors`) and in ``mcp-capture
    check`` (``judge.judging``) alike: at its last record ``last``, unless its node's last stop
    ``stop`` (a run delay read as the runner stopped it) came after its last datagram or
    autopilot-link record ``data``: then at that stop. What the runner records later (its case
    marks) is no time of that node's: a message whose copies the stop cut short is not proven
    unretransmitted (MCP-RTX-1), nor is any absence after it evidence. A datagram after the
    stop (a node started again and not stopped since) leaves the end at ``last``."""
    if stop is not None and (data is None or stop >= data):
        return stop
    return last


#: How a node's verdicts of several sessions merge: the worst wins (``judge.judging``'s).
_RANK = {"not_observed": 0, "info": 1, "passed": 2, "warned": 3, "failed": 4}


class SessionMonitors:
    """One :class:`RunMonitor` per session of a run whose node is restarted for each fresh
    mission (``mcp-conform --role manager``: a manager runs one mission and is done), with
    :class:`RunMonitor`'s interface. Each session is judged on its own, complete (the runner's
    socket saw every datagram of it), as ``mcp-capture check`` judges the capture's sessions
    (``McapRecorder.begin_segment``); the report's section is theirs merged per node, worst
    verdict first, as the judgement of the file is (``judge.judging.merge_segments``).

    When the run's monitor is finished (:meth:`finish`), a session's monitor is finished where
    the capture's session ends (:func:`session_end`, ``mcp-capture check``'s too): at its last
    record (a datagram, a case mark -- :meth:`mark`
    -- or the node's run delay read as it was stopped: :meth:`run_delay`); but where its
    manager instance was stopped after its last datagram, at that stop: a case mark after it
    (the silent drone's scenario, told to its session as its case asks, then the run's later
    cases) is the runner's time, not the instance's, and an absence there proves nothing (a
    false MCP-RTX-1 "none for 2.5 s" of copies the stop cut short).

    The runner's datagrams go to a session by their stamps, not by when a thread told them: a
    runner thread taken off the CPU between a datagram's stamp (its send; the kernel's receive
    time) and its report tells it late, after the next session began -- the previous
    manager's last End_Mission copy, and the runner's ACK of it, judged in the silent drone's
    session as a command after that drone's End_Mission (MCP-BLK-6, MCP-SEQ-1: simulator
    seed 110 of ``preempt=(0.3, 0.3)``). A session begun ``at_ns`` holds the driver's datagrams
    stamped from then until the next such session begins; one begun ``held`` (a scenario that
    ran beside on sockets of its own, told after by :meth:`observe_held`) takes none of them.
    Each session's monitor is fed in stamp order however late a datagram was told
    (``RunMonitor(reorder_ns=None)``): the case thread's ACK of a Start_Mission copy told
    195 ms after it left, behind the next Start_Mission, was a false MCP-BLK-1 (seed 118)."""

    def __init__(self, **kw: Any) -> None:
        self._kw = kw
        self.parts: dict[str, RunMonitor] = {}
        self.current: RunMonitor | None = None
        self.listen: tuple[str, int] | None = None
        self._last: dict[str, int] = {}  # a session's last record
        self._data: dict[str, int] = {}  # its last datagram
        self._stop: dict[str, int] = {}  # its node's last stop (a run delay read as it was stopped)
        self._name: str | None = None
        self._lock = threading.Lock()
        #: (begin stamp, name) of the sessions the driver's own datagrams go to, in order
        self._live: list[tuple[int, str]] = []

    @property
    def node_id(self) -> int | None:
        return self._kw.get("node_id")

    def begin(self, name: str, at_ns: int | None = None, *, held: bool = False) -> None:
        """Session ``name`` starts, at ``at_ns`` (None: it takes every datagram of the driver
        told from now on, whatever its stamp); ``held``: its traffic comes by
        :meth:`observe_held` alone (see the class)."""
        with self._lock:
            mon = RunMonitor(**self._kw, reorder_ns=None)
            mon.listen = self.listen
            self.parts[name] = self.current = mon
            self._name = name
            if not held:
                self._live.append((at_ns if at_ns is not None else -1, name))

    def _session_of(self, t_ns: int) -> str | None:
        """The session a datagram of the driver stamped ``t_ns`` belongs to: the last begun by
        then (the first, for one stamped before any began)."""
        live = self._live
        for begun, name in reversed(live):
            if begun <= t_ns:
                return name
        return live[0][1] if live else None

    def observe(self, direction: str, data: bytes, addr: tuple[str, int], t_ns: int,
                run_delay: int | None = None) -> None:
        """The driver's observer: to the session of the datagram's stamp."""
        with self._lock:
            self._feed(self._session_of(t_ns), direction, data, addr, t_ns, run_delay)

    def observe_held(self, direction: str, data: bytes, addr: tuple[str, int], t_ns: int,
                     run_delay: int | None = None) -> None:
        """A held session's traffic, told after it ran: to the session current."""
        with self._lock:
            self._feed(self._name, direction, data, addr, t_ns, run_delay)

    def _feed(self, name: str | None, direction: str, data: bytes, addr: tuple[str, int], t_ns: int,
              run_delay: int | None) -> None:
        mon = self.parts.get(name) if name is not None else None
        if name is not None and mon is not None:
            self._last[name] = max(self._last.get(name, t_ns), t_ns)
            self._data[name] = max(self._data.get(name, t_ns), t_ns)
            mon.observe(direction, data, addr, t_ns, run_delay)

    def run_delay(self, t_ns: int, node: int, run_delay_ns: int) -> None:
        """To the session current when the node was stopped (:meth:`RunMonitor.run_delay`):
        a record of that session, as the capture's reading is (``RUN_DELAY_METADATA``), so the
        session ends no earlier (``mcp-capture check`` ends a run's view at its readings), and,
        after its last datagram, no later (:func:`session_end`)."""
        with self._lock:
            if self.current is not None:
                self.current.run_delay(t_ns, node, run_delay_ns)
                if self._name is not None:
                    self._last[self._name] = max(self._last.get(self._name, t_ns), t_ns)
                    self._stop[self._name] = max(self._stop.get(self._name, t_ns), t_ns)

    def mark(self, t_ns: int) -> None:
        """A record of the current session that is not a datagram (a case mark); after the stop
        of the session's node, it does not make the session longer (:func:`session_end`)."""
        with self._lock:
            if self._name is not None:
                self._last[self._name] = max(self._last.get(self._name, t_ns), t_ns)

    def finish(self, t_ns: int | None = None) -> None:
        """Each session's monitor finished where its session ends (:func:`session_end`)."""
        with self._lock:
            for name, mon in self.parts.items():
                mon.finish(session_end(self._last.get(name), self._data.get(name), self._stop.get(name)))

    def verdicts(self) -> dict[int, dict[str, str]]:
        out: dict[int, dict[str, str]] = {}
        for mon in list(self.parts.values()):
            for node, table in mon.verdicts().items():
                merged = out.setdefault(node, {})
                for rule, verdict in table.items():
                    if _RANK.get(verdict, 0) >= _RANK.get(merged.get(rule, "not_observed"), 0):
                        merged[rule] = verdict
        return dict(sorted(out.items()))

    def violations(self, rule: str | None = None, node: int | None = None) -> list[Violation]:
        return [v for mon in list(self.parts.values()) for v in mon.violations(rule, node)]

    def verdict(self, node: int, rule: str) -> str:
        return self.verdicts().get(node, {}).get(rule, "not_observed")

    @property
    def errors(self) -> int:
        return sum(m.errors for m in self.parts.values())

    def to_json(self) -> dict[str, Any]:
        """The report's ``monitor`` section: the sessions' merged (datagram indexes of the
        evidence count over the whole run, in session order)."""
        sections = [(m.to_json(), m) for m in list(self.parts.values())]
        nodes: dict[int, dict[str, Any]] = {}
        violations: list[dict[str, Any]] = []
        vetoed: list[dict[str, Any]] = []
        base = 0
        for sec, _ in sections:
            for n in sec["nodes"]:
                have = nodes.get(n["id"])
                if have is None:
                    nodes[n["id"]] = dict(n)
                else:
                    have["datagrams"] += n["datagrams"]
                    have["addresses"] = sorted({*have["addresses"], *n["addresses"]})
            for into, key in ((violations, "violations"), (vetoed, "vetoed")):
                for v in sec[key]:
                    into.append({**v, "evidence": [{**e, "index": e["index"] + base} for e in v["evidence"]]})
            base += sec["datagrams"]
        return {"complete": all(sec["complete"] for sec, _ in sections) if sections else True,
                "datagrams": base, "nodes": [nodes[k] for k in sorted(nodes)], "violations": violations,
                "vetoed": vetoed, "rules": {str(k): v for k, v in self.verdicts().items()}}

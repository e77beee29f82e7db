"""One whole mission on a bad link: a manager and K drones through :class:`soak.medium.Medium`,
then judged twice (issue 22 item 4).

- The monitor judges each node's view (``judge.judging``: a node's own capture, complete for
  what it took part in; one MCAP per mission, one segment per node): no violation.
- Exactly-once on what the applications delivered (MCP-DUP-1, MCP-RTX-1): every drone's
  delivery log (``{record}``, the reference node's ``--record`` JSON: ``deliveries`` as
  ``[action, src, seq]``) holds what the manager sent that drone, once each, in order, never
  one (src, seq) twice -- what its record says it sent, or, for a manager without one, what
  its own view shows it sent (each command once, a broadcast to every drone); the manager
  exits 0 within the mission's deadline (the mission completed: every command ACKed).
- What a mission must hold is the suite's one judge's, not a list of the soak's own: the
  monitor's MCP-FLOW-2/3 and the challenge's MCP-FLOW-4/5/6 verdicts on the manager, passed
  (MCP-FLOW-6 asks for "the mission's obstacles as one Obstacles_List", not for it alone:
  ``mcp-conform`` passes a challenge 3 that sends the route as a WP_List too, so does the soak).

Nodes are commands with placeholders (``--manager`` / ``--drone``), run as subprocesses; the
reference ones by default (``python -m mcp_conform.reference_impl``), never imported. Each runs in a
process group of its own, and each mission names how every node ended (:class:`NodeEnd`:
exited by itself, with its code and when, exit 0 included; stopped by the soak's SIGTERM;
killed after the grace; never started). At the mission's end, or when the campaign is stopped
(``stop``: a SIGTERM or SIGINT to ``mcp-soak``), the soak ends every group still running:
SIGTERM, SIGKILL after 5 s, then SIGKILL to what is left in each group (a node's own
children). A leader is reaped only after that, so its group's id cannot have been reused.
"""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from mcp_conform.harness.impair import Impairment, ImpairSpec
from mcp_conform.harness.run_delay import run_delay_ns
from mcp_conform.soak.medium import MANAGER, Medium, view_name
from mcp_conform.spec.codec import BROADCAST_ID, PREAMBLE, Action, peek_header
from mcp_conform.spec.profiles import MCP
from mcp_conform.vehicle.ports import free_port

__all__ = ["DEFAULT_DRONE", "DEFAULT_MANAGER", "MissionResult", "MissionSetup", "NodeEnd", "run_mission"]

DEFAULT_MANAGER = ("{python} -m mcp_conform.reference_impl manager --challenge {challenge} --drones {drones} "
                   "--waypoints {waypoints} --obstacles {obstacles} --listen {target_host}:{target_port} "
                   "--target {listen_host}:{listen_port} --rto {rto} --json {record} -q")
# --linger: a drone keeps ACKing after End_Mission until the soak ends it (a lost ACK of
# End_Mission must not leave the manager retransmitting to a drone that is gone)
DEFAULT_DRONE = ("{python} -m mcp_conform.reference_impl drone --id {id} --listen {target_host}:{target_port} "
                 "--target {listen_host}:{listen_port} --rto {rto} --linger 600 --json {record} -q")

WAYPOINTS = """QGC WPL 110
0\t1\t0\t16\t0\t0\t0\t0\t35.771332\t-78.674421\t0.000000\t1
1\t0\t3\t22\t0.000000\t0.000000\t0.000000\t0.000000\t0.000000\t0.000000\t3.000000\t1
2\t0\t3\t19\t5.000000\t0.000000\t0.000000\t0.000000\t35.771103\t-78.674659\t3.000000\t1
3\t0\t3\t19\t5.000000\t0.000000\t0.000000\t0.000000\t35.771057\t-78.674421\t3.000000\t1
4\t0\t3\t20\t0.000000\t0.000000\t0.000000\t0.000000\t0.000000\t0.000000\t0.000000\t1
"""
OBSTACLES = """QGC WPL 110
0\t0\t3\t16\t2.000000\t0.000000\t0.000000\t0.000000\t35.771200\t-78.674500\t3.000000\t1
1\t0\t3\t16\t2.000000\t0.000000\t0.000000\t0.000000\t35.771150\t-78.674300\t3.000000\t1
2\t0\t3\t16\t3.000000\t0.000000\t0.000000\t0.000000\t35.770980\t-78.674550\t5.000000\t1
"""
FLOW = {1: "MCP-FLOW-4", 2: "MCP-FLOW-5", 3: "MCP-FLOW-6"}
#: the judge's rules of what each drone's mission holds: Start_Mission first (MCP-FLOW-2),
#: End_Mission last (MCP-FLOW-3), and the challenge's commands (:data:`FLOW`)
MISSION_RULES = ("MCP-FLOW-2", "MCP-FLOW-3")
_ACK = int(Action.ACK)


@dataclass
class MissionSetup:
    """What every mission of a campaign shares."""

    impair: ImpairSpec  # its seed is replaced by each mission's
    drones: tuple[int, ...] = (1, 2, 3)
    rto: float = 0.2
    timeout: float = 60.0  # the mission's deadline (s)
    manager_cmd: str = DEFAULT_MANAGER
    drone_cmd: str = DEFAULT_DRONE
    waypoints: Path | None = None
    obstacles: Path | None = None
    workdir: Path = Path("soak-out")
    strict: bool = True  # any monitor violation fails the mission (not only MUSTs)
    #: ``--live``: the campaign's Foxglove WebSocket server (``traceio.live.LiveServer``); each
    #: node's view is served as it is recorded, under its name (``/drone1/mcp/rx``)
    live: Any = None


@dataclass(frozen=True)
class NodeEnd:
    """How one node ended: ``exited`` by itself (``code``, ``at`` seconds into the mission),
    ``stopped`` by the soak's SIGTERM, ``killed`` (SIGKILL after the grace), ``not started``
    (``detail``: why)."""

    how: str
    code: int | None = None
    at: float | None = None
    detail: str = ""

    def describe(self) -> str:
        if self.how == "not started":
            return f"not started: {self.detail}"
        code = "" if self.code is None else (f" by signal {-self.code}" if self.code < 0 else f" with {self.code}")
        at = "" if self.at is None else f" at {self.at:.2f} s"
        return {"exited": f"exited{code}{at}", "stopped": f"stopped by the soak{at}, ended{code}",
                "killed": f"killed (SIGKILL) after the grace, stopped{at}"}.get(self.how, self.how)

    def to_json(self) -> dict[str, Any]:
        return {"how": self.how, "code": self.code, "at_s": None if self.at is None else round(self.at, 3),
                **({"detail": self.detail} if self.detail else {})}


@dataclass
class MissionResult:
    index: int
    seed: int
    challenge: int
    impair: str
    ok: bool = False
    outcome: str = "not run"
    reasons: list[str] = field(default_factory=list)
    mission_time: float | None = None
    retransmissions: int = 0
    duplicates: int = 0
    violations: list[str] = field(default_factory=list)
    capture: str | None = None
    logs: dict[str, str] = field(default_factory=dict)
    link: str = ""  # what the links did (dropped, duplicated, reordered)
    ended: dict[str, NodeEnd] = field(default_factory=dict)  # node view -> how it ended

    def to_json(self) -> dict[str, Any]:
        return {"index": self.index, "seed": self.seed, "challenge": self.challenge, "impair": self.impair,
                "ok": self.ok, "outcome": self.outcome, "reasons": self.reasons,
                "mission_time_s": None if self.mission_time is None else round(self.mission_time, 3),
                "retransmissions": self.retransmissions, "duplicates_discarded": self.duplicates,
                "link": self.link, "violations": self.violations, "capture": self.capture, "logs": self.logs,
                "ended": {v: e.to_json() for v, e in self.ended.items()}}


def link_summary(counts: dict[str, int]) -> str:
    """``412 dgrams: 120 lost, 40 dup, 70 reord, 3 corrupt`` (what the links did)."""
    lost = sum(v for k, v in counts.items() if k.startswith("drop:"))
    words = [f"{counts.get('datagrams', 0)} dgrams", f"{lost} lost"]
    for key, label in (("dup", "dup"), ("reorder", "reord"), ("corrupt", "corrupt"), ("cut", "cut")):
        if counts.get(key):
            words.append(f"{counts[key]} {label}")
    return ", ".join(words)


_PORTS_LOCK = threading.Lock()
_RECENT_PORTS: list[int] = []


def _free_port(host: str) -> int:
    """A port for a node to bind (``vehicle.ports.free_port``: below the ephemeral range, so a
    medium's bind(0) beside it cannot take it), never one handed to the last 512 nodes (missions
    side by side, ``--jobs``, pick while each other's nodes start)."""
    with _PORTS_LOCK:
        for _ in range(100):
            port = free_port(host)
            if port not in _RECENT_PORTS:
                break
        _RECENT_PORTS.append(port)
        del _RECENT_PORTS[:-512]
        return port


def _command(template: str, values: dict[str, Any]) -> list[str]:
    """``template`` split like a shell, each word's placeholders filled (a bad one: ValueError)."""
    try:
        return [w.format_map(values) for w in shlex.split(template)]
    except KeyError as exc:
        raise ValueError(f"unknown placeholder {{{exc.args[0]}}} in {template!r}; placeholders: "
                         + ", ".join("{" + k + "}" for k in sorted(values))) from None
    except (IndexError, ValueError) as exc:
        raise ValueError(f"bad command {template!r}: {exc}") from None


def placeholders() -> list[str]:
    return ["python", "id", "target_host", "target_port", "listen_host", "listen_port", "challenge",
            "drones", "waypoints", "obstacles", "rto", "record"]


def _run_delay(procs: dict[str, subprocess.Popen[bytes]], view: str) -> Callable[[], int | None]:
    """A reader of ``view``'s node's run delay (MCP-RTX-3's evidence of host load), once spawned."""
    def read() -> int | None:
        p = procs.get(view)
        return run_delay_ns(p.pid) if p is not None else None
    return read


def _spawn(cmd: list[str], log: Path) -> subprocess.Popen[bytes]:
    """``cmd`` in a session (a process group) of its own; OSError when it cannot start."""
    with open(log, "wb") as err:
        return subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=err, stderr=subprocess.STDOUT,
                                start_new_session=True)


def _exit_status(proc: subprocess.Popen[bytes]) -> int | None:
    """``proc``'s exit code if it ended (negative: the signal), None while it runs; the process
    is *not* reaped (``WNOWAIT``), so its pid, its group's id, stays its own until
    :func:`_end_nodes` has ended the group."""
    if proc.returncode is not None:
        return proc.returncode
    if not hasattr(os, "waitid"):  # not Linux: reaped here
        return proc.poll()
    try:
        info = os.waitid(os.P_PID, proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
    except ChildProcessError:
        return proc.poll()
    if info is None or info.si_pid == 0:
        return None
    return info.si_status if info.si_code == os.CLD_EXITED else -info.si_status


def _signal_group(proc: subprocess.Popen[bytes], sig: int) -> None:
    with contextlib.suppress(ProcessLookupError, PermissionError):
        os.killpg(proc.pid, sig)


def _end_nodes(procs: dict[str, subprocess.Popen[bytes]], ended: dict[str, NodeEnd], t0: float,
               grace: float = 5.0) -> None:
    """End every node still running (SIGTERM to its group, SIGKILL after ``grace``), record
    how each ended in ``ended``, SIGKILL what is left of every group, then reap."""
    running = []
    for v, p in procs.items():
        code = _exit_status(p)
        if v in ended:
            continue
        if code is not None:
            ended[v] = NodeEnd("exited", code, time.monotonic() - t0)
        else:
            running.append(v)
    at = time.monotonic() - t0
    for v in running:
        _signal_group(procs[v], signal.SIGTERM)
    deadline = time.monotonic() + grace
    while running:
        for v in list(running):
            code = _exit_status(procs[v])
            if code is not None:
                ended[v] = NodeEnd("stopped", code, at)
                running.remove(v)
        if not running or time.monotonic() >= deadline:
            break
        time.sleep(0.02)
    for v in running:
        _signal_group(procs[v], signal.SIGKILL)
    for p in procs.values():  # a node's own children, its group's leader not yet reaped
        _signal_group(p, signal.SIGKILL)
    for v, p in procs.items():
        with contextlib.suppress(subprocess.TimeoutExpired):
            code = p.wait(5)
            if v in running:
                ended[v] = NodeEnd("killed", code, at)


def _listening(port: int) -> bool | None:
    """Whether a UDP socket is bound to ``port`` (Linux's /proc/net/udp); None elsewhere."""
    lines: list[str] = []
    for table in ("/proc/net/udp", "/proc/net/udp6"):
        with contextlib.suppress(OSError):
            lines += Path(table).read_text().splitlines()[1:]
    if not lines:
        return None
    want = f":{port:04X}"
    return any(line.split()[1].endswith(want) for line in lines if len(line.split()) > 1)


def _wait_listening(port: int, proc: subprocess.Popen[bytes], limit: float = 10.0,
                    stop: threading.Event | None = None) -> None:
    """Until ``proc`` listens on ``port`` (or exits, or ``limit`` passes, or ``stop``)."""
    deadline = time.monotonic() + limit
    while time.monotonic() < deadline and _exit_status(proc) is None and not (stop and stop.is_set()):
        up = _listening(port)
        if up is None:
            time.sleep(0.5)  # no way to know here: give it a moment
            return
        if up:
            return
        time.sleep(0.01)


def _record(path: Path) -> dict[str, Any] | None:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def run_mission(setup: MissionSetup, index: int, seed: int, challenge: int,
                stop: threading.Event | None = None) -> MissionResult:
    """Mission ``index`` with impairment seed ``seed``; everything it wrote under
    ``setup.workdir/mission-<seed>-c<challenge>/``. ``stop`` set (the campaign was stopped):
    its nodes are ended at once, its views merged into its capture unjudged, and its outcome
    is ``interrupted`` (``stop.why``, when the event has one, names the signal)."""
    from mcp_conform.spec.mission import load_waypoints
    from mcp_conform.traceio.recorder import McapRecorder, run_metadata

    spec = setup.impair.__class__(**{**setup.impair.__dict__, "seed": seed})
    res = MissionResult(index, seed, challenge, spec.text())
    out = setup.workdir / f"mission-{seed}-c{challenge}"
    out.mkdir(parents=True, exist_ok=True)
    wp_file, ob_file = setup.waypoints, setup.obstacles
    if wp_file is None:  # the mission's own: missions side by side never write one another's
        wp_file = out / "mission.waypoints"
        wp_file.write_text(WAYPOINTS)
    if ob_file is None:
        ob_file = out / "obstacles.waypoints"
        ob_file.write_text(OBSTACLES)
    host = "127.0.0.1"
    ports = {MANAGER: _free_port(host), **{view_name(i): _free_port(host) for i in setup.drones}}
    views = [MANAGER, *(view_name(i) for i in setup.drones)]
    parts = {v: out / f"mission.{v}.mcap" for v in views}
    recorders = {}
    for v in views:
        node_id = 0 if v == MANAGER else int(v[5:])
        recorders[v] = McapRecorder(parts[v], library="mcp-soak", metadata=run_metadata(
            "mcp-soak", role=MCP.role_of_id(node_id).name, node_id=node_id, complete="true",
            parameters={"rto": setup.rto}, impair=spec.text(), challenge=challenge),
            live=setup.live.feed(v) if setup.live is not None else None)
    procs: dict[str, subprocess.Popen[bytes]] = {}
    medium = Medium(setup.drones, Impairment(spec), (host, ports[MANAGER]),
                    {i: (host, ports[view_name(i)]) for i in setup.drones}, recorders, host,
                    {v: _run_delay(procs, v) for v in views})
    common = {"python": sys.executable, "challenge": challenge, "drones": ",".join(map(str, setup.drones)),
              "waypoints": str(wp_file), "obstacles": str(ob_file), "rto": f"{setup.rto:g}"}
    t0 = time.monotonic()
    try:
        cmds = {v: _command(setup.manager_cmd if v == MANAGER else setup.drone_cmd, {
            **common, "id": 0 if v == MANAGER else int(v[5:]), "target_host": host, "target_port": ports[v],
            "listen_host": host,
            "listen_port": medium.front_addr[1] if v == MANAGER else medium.link_addr(int(v[5:]))[1],
            "record": str(out / f"{v}.json")}) for v in views}
        medium.start()
        t0 = time.monotonic()
        # the manager first, listening before any drone speaks: a drone's first Mission_Ready
        # must not depend on how fast the manager's process started (a seed replays only
        # if the link sees the same traffic)
        for v in views:
            if stop is not None and stop.is_set():
                break
            try:
                procs[v] = _spawn(cmds[v], out / f"{v}.log")
            except OSError as exc:
                res.ended[v] = NodeEnd("not started", detail=f"{cmds[v][0]}: {exc.strerror or exc}")
                res.reasons.append(f"{v} could not start: {res.ended[v].detail}")
                break
            if v == MANAGER:
                _wait_listening(ports[MANAGER], procs[v], stop=stop)
        if not res.reasons:
            _await_manager(res, procs, t0, setup.timeout, stop)
            if res.mission_time is not None and not (stop is not None and stop.is_set()):
                # the drones act on their last delivery before they are ended: End_Mission's
                # RTL (MCP-BLK-7) came after the ACK that let the manager exit, and a loaded
                # host's drone was stopped between the two ("no RTL asked", a correct drone)
                time.sleep(max(0.5, 2 * setup.rto))
    finally:
        _end_nodes(procs, res.ended, t0)
        res.ended = {v: res.ended[v] for v in views if v in res.ended}
        medium.stop()
        for r in recorders.values():
            r.close()
    res.retransmissions = sum(medium.retransmissions.values())
    res.duplicates = sum(medium.duplicates.values())
    res.link = link_summary(medium.impairment.counts)
    res.logs = {v: str(out / f"{v}.log") for v in procs}
    if res.outcome == "interrupted":
        with contextlib.suppress(Exception):  # what it has: the views so far, one capture
            from mcp_conform.traceio.merge import merge_captures

            merge_captures(list(parts.values()), out / "mission.mcap")
            res.capture = str(out / "mission.mcap")
        return res
    end = res.ended.get(MANAGER)
    if end is not None and end.how == "exited" and end.code != 0:
        res.reasons.append(f"the manager exited with {end.code}")

    items = tuple(load_waypoints(ob_file if challenge == 3 else wp_file))
    _judge(res, parts, out / "mission.mcap", setup, challenge, items)
    _check_deliveries(res, out, setup, Path(res.capture) if res.capture else None)
    res.ok = not res.reasons
    res.outcome = "complete" if res.ok else ("timeout" if res.mission_time is None else "failed")
    return res


def _await_manager(res: MissionResult, procs: dict[str, subprocess.Popen[bytes]], t0: float,
                   timeout: float, stop: threading.Event | None) -> None:
    """Until the manager exits (the mission's time), the deadline passes or ``stop``; a drone
    that exits by itself meanwhile is recorded when seen (within 20 ms), exit 0 included: a
    drone gone before the manager is named (``ended``), and a failure when its code is not 0."""
    deadline = t0 + timeout
    while True:
        now = time.monotonic()
        for v, p in procs.items():
            if v not in res.ended and (code := _exit_status(p)) is not None:
                res.ended[v] = NodeEnd("exited", code, now - t0)
                if v != MANAGER and code != 0:  # crashed, gave up: a finding
                    res.reasons.append(f"{v} exited with {code} during the mission")
        if MANAGER in res.ended:
            res.mission_time = res.ended[MANAGER].at
            return
        if stop is not None and stop.is_set():
            res.outcome = "interrupted"
            res.reasons.append(f"interrupted ({getattr(stop, 'why', None) or 'stopped'}) "
                               f"{now - t0:.1f} s into the mission")
            return
        if now >= deadline:
            res.reasons.append(f"the mission did not end within {timeout:g} s")
            return
        time.sleep(min(0.02, max(0.0, deadline - now)))


def _check_deliveries(res: MissionResult, out: Path, setup: MissionSetup, capture: Path | None) -> None:
    """Exactly-once on the applications' delivery logs (MCP-DUP-1, MCP-RTX-1): each drone got
    what the manager sent it (its record's ``sent``, else its own view in the mission's
    ``capture``: :func:`_sent_on_wire`),
    once each, in order. Whether that was the mission the challenge asks for is the judge's
    (MCP-FLOW-2..6, :func:`_judge`)."""
    manager = _record(out / f"{MANAGER}.json")
    sent: dict[int, list[str]] | None = None
    if manager is not None and isinstance(manager.get("sent"), list):
        sent = {}
        for action, drone in manager["sent"]:
            sent.setdefault(int(drone), []).append(_name(action))
        if manager.get("outcome") not in (None, "end_mission"):
            res.reasons.append(f"manager: outcome {manager.get('outcome')}")
    if sent is None:
        sent = _sent_on_wire(capture, setup.drones) if capture is not None else {}
    for i in setup.drones:
        rec = _record(out / f"{view_name(i)}.json")
        if rec is None or not isinstance(rec.get("deliveries"), list):
            res.reasons.append(f"drone{i}: no delivery log ({out / f'{view_name(i)}.json'})")
            continue
        if rec.get("deliveries_omitted"):
            res.reasons.append(f"drone{i}: its delivery log lists only the first {len(rec['deliveries'])} "
                               f"deliveries ({rec['deliveries_omitted']} more): exactly-once not checkable")
            continue
        got = [_name(d[0]) for d in rec["deliveries"]]
        keys = [(d[1], d[2]) for d in rec["deliveries"]]
        twice = sorted({k for k in keys if keys.count(k) > 1})
        if twice:
            res.reasons.append(f"drone{i}: delivered (src, seq) {twice[0]} {keys.count(twice[0])} times "
                               f"(MCP-DUP-1)")
        if sent.get(i, []) != got:
            res.reasons.append(f"drone{i}: delivered {_short(got)}, expected {_short(sent.get(i, []))} "
                               "(what the manager sent it, exactly once, in order)")
        if rec.get("rtl") is False and got and got[-1] == "End_Mission":  # the vehicle's record
            res.reasons.append(f"drone{i}: End_Mission delivered but no RTL asked of the autopilot (MCP-BLK-7)")


def _sent_on_wire(capture: Path, drones: tuple[int, ...]) -> dict[int, list[str]]:
    """What the manager sent each drone by its own view (the merged ``capture``'s manager
    segment: what it sent as it entered the link, ``soak.medium``): each command once, in the order of its first copy (a retransmission
    repeats its seq, MCP-SEQ-2), a broadcast to every drone (D-11). An unreadable capture: {}."""
    from mcp_conform.traceio.reader import CaptureError, open_capture

    out: dict[int, list[str]] = {}
    seen: set[tuple[int, int]] = set()
    with contextlib.suppress(CaptureError, OSError):
        for d in open_capture(capture, segment=MANAGER).datagrams():
            h = peek_header(d.data) if d.direction == "tx" and d.data[:len(PREAMBLE)] == PREAMBLE else None
            if h is None or h[3] == _ACK or (h[0], h[2]) in seen:
                continue
            seen.add((h[0], h[2]))
            name = _name(Action(h[3]).name if 0 <= h[3] <= 8 else h[3])
            for i in drones if h[0] == BROADCAST_ID else (h[0],):
                out.setdefault(i, []).append(name)
    return out


def _name(action: Any) -> str:
    """An action's name as the spec spells it (a log may write START_MISSION or start_mission)."""
    return _NAMES.get(str(action).lower(), str(action))


_NAMES = {n.lower(): n for n in ("Mission_Ready", "Start_Mission", "WP_List", "WP_On", "WP_Off",
                                 "Obstacles_List", "End_Mission", "Mav_Passthrough", "ACK")}


def _short(names: list[str]) -> str:
    text = ",".join(names)
    return text if len(text) <= 120 else text[:117] + "..."


def _judge(res: MissionResult, parts: dict[str, Path], capture: Path, setup: MissionSetup, challenge: int,
           items: tuple[Any, ...]) -> None:
    """The nodes' views merged into one capture (a segment each) and judged by the monitor."""
    from mcp_conform.judge.judging import CaptureError, Params, judge
    from mcp_conform.traceio.merge import merge_captures

    try:
        merge_captures(list(parts.values()), capture)
        res.capture = str(capture)
        j = judge(capture, Params(rto=setup.rto, ack_window=max(0.5, 2 * setup.rto), drones=setup.drones,
                                  challenge=challenge, waypoints=items,
                                  given=frozenset({"rto", "ack_window", "drones", "challenge"})))
    except (CaptureError, OSError, ValueError) as exc:
        res.reasons.append(f"capture not judged: {exc}")
        return
    # each view is exact for what its own node did (what it sent entered the link as sent;
    # its replies answer what the link delivered to it); the other end is seen through the
    # link (copies lost, duplicated, held back), so each node is judged in its own view only
    segments = j.segments or {MANAGER: j}
    bad = []
    for seg, sj in segments.items():
        party = 0 if seg == MANAGER else int(seg[5:]) if seg.startswith("drone") else None
        for v in (sj.shown_violations if setup.strict else sj.failing()):
            if v.node == party:
                bad.append(v)
    for v in bad:
        res.violations.append(f"{v.rule} node {v.node}: {v.actual}")
    if bad:
        v = bad[0]
        res.reasons.append(f"monitor: {len(bad)} violation(s), first {v.rule} by node {v.node}: {v.actual}")
    if res.mission_time is not None:  # the manager ended: the mission the judge holds it to
        verdicts = j.verdicts.get(0, {})
        for rule in (*MISSION_RULES, FLOW[challenge]):
            if verdicts.get(rule) != "passed":
                res.reasons.append(f"monitor: {rule} {verdicts.get(rule) or 'not judged'}")


def environment_note() -> str:
    """Why a reference-node command may fail to start: the interpreter running mcp-soak."""
    return f"{sys.executable} (PYTHONPATH={os.environ.get('PYTHONPATH', '')})"

"""``mcp-capture replay CAPTURE``: one side of a recorded conversation, played against a live node.

::

    mcp-capture replay CAPTURE --target HOST:PORT [--role drone|manager] [--listen HOST:PORT]
                       [--target-id N] [--spawn CMD] [--mavlink] [--rto S] [--ack-window S]
                       [--copies-tolerance N] [--capture OUT.mcap] [--json OUT]

The node under test has the role ``--role`` (default drone) and, in the capture, the MCP ID
``--target-id`` (default: the capture's drone for the drone role, the manager 0 for the
manager role). Replay plays every other sender of the capture — the manager and any other
IDs a runner used, or all the drones — from one UDP socket, with the runner's attach, spawn
and listen semantics and placeholders (it reuses ``harness.drone_session`` and
``harness.driver``): ``--listen`` is where it receives and sends from (all addresses on
the role's conventional port by default, an ephemeral one in spawn mode). For a manager
under test ``--spawn`` also fills ``{drones}``, ``{challenge}``, ``{waypoints}`` and
``{obstacles}`` from the capture (the drones it talked to, the challenge its commands show,
and its lists written as QGC WPL 110 files); ``--mavlink`` starts the simulated vehicle
(``{mavlink}``) for a drone.

It does not replay timestamps blindly. Before each datagram the capture's played side sent,
it waits until the live node has sent as many datagrams as the node had sent by that point
of the capture (so an ACK withheld for four copies of Mission_Ready is withheld for four
copies again), bounded by ``--answer-timeout``, and keeps the captured gap since its
previous send up to ``--max-gap``. It rewrites what the live node needs: datagrams go to the
live target, the node's ID is the live one, and the sequence number an ACK acknowledges is
mapped from the recorded node's numbering to the live node's (offset from its first seq,
MCP-SEQ-4: initial values are arbitrary). The played side's own seqs are kept.

Then the node's answers are checked with the diff (:mod:`captures.diff`: the capture as
golden, the replay's own traffic as candidate) and all the traffic with the trace monitor
(``judge.monitor``). Exit 0 same and no MUST violated; 1 different or violated; 2
unreadable capture or setup error (one line), a node that never answered at all included. :func:`replay` is the Python API (a list of
datagram records or raw bytes plus a target), which ``mcp-fuzz`` uses to reproduce findings.

This is MCP's replay (its capture tools, ``captures.mcp``); another protocol's capture is
replayed by its own (an Nsqd fuzz finding — ``finding-N/``, its repro.mcap or repro.pcap —
as ``mcp-fuzz --protocol nsqd --replay`` replays it: ``captures.nsqd``). A fuzz finding's ``repro.mcap`` (metadata record
from recorder ``mcp-fuzz``) is replayed as ``mcp-fuzz --replay`` replays it: its minimal sequence, with the campaign's pace and scenario,
judged by the fuzzer's oracles; exit 1 when the node still breaks the finding's rule, 0 when
it no longer does.
"""

from __future__ import annotations

import contextlib
import json
import sys
import tempfile
import time
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple, TextIO

from mcp_conform.captures.diff import (
    DiffOptions,
    DiffResult,
    diff_sides,
    in_time_order,
    print_report,
    side_from_datagrams,
)
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import HEADER_SIZE, MANAGER_ID, Action, peek_header
from mcp_conform.spec.profiles import MCP

__all__ = ["ReplayError", "ReplayResult", "Step", "plan", "register", "replay", "run", "run_replay"]

_PORTS = SPEC.protocol["ports"]
_ACK = int(Action.ACK)
_U16 = 0xFFFF


class ReplayError(Exception):
    """Replay cannot run (bad capture for the role, port in use, spawn failed); one line."""


class Step(NamedTuple):
    """One datagram the played side sends, and what must have happened before it."""

    data: bytes
    node_sent_before: int  # datagrams the node had sent by then, in the capture
    gap_s: float  # since the played side's previous send, in the capture


class Rec(NamedTuple):
    index: int  # type: ignore[assignment]
    t_ns: int
    src_addr: Any
    dst_addr: Any
    data: bytes


@dataclass
class ReplayResult:
    diff: DiffResult
    violations: list[Any] = field(default_factory=list)
    monitor: str = ""  # why the monitor did not judge, when it did not
    sent: int = 0
    received: int = 0
    notes: list[str] = field(default_factory=list)
    node_output: str = ""

    @property
    def ok(self) -> bool:
        return self.diff.same and not any(getattr(v, "level", "MUST") == "MUST" for v in self.violations)

    @property
    def exit_code(self) -> int:
        return 0 if self.ok else 1


# ---------------------------------------------------------------- the plan
def _src(data: bytes) -> int | None:
    h = peek_header(data, require_preamble=False)
    return None if h is None else h[1]


def node_id_for(records: Sequence[Any], role: str) -> int:
    """The node under test's ID in the capture: the one its role fixes (the manager's), or
    the drone talking to the manager."""
    fixed = MCP.role(role).fixed_id
    if fixed is not None:
        return fixed
    counts: dict[int, int] = {}
    for r in records:
        h = peek_header(r.data, require_preamble=False)
        if h is not None and h[1] not in (MANAGER_ID, SPEC.protocol["broadcast_id"]) and h[0] == MANAGER_ID:
            counts[h[1]] = counts.get(h[1], 0) + 1
    if not counts:
        raise ReplayError("the capture holds no drone talking to the manager (ID 0): "
                          "nothing to replay for --role drone (use --target-id)")
    return min(counts)


def involves(data: bytes, node: int) -> bool:
    """A datagram of the node's conversations: from it, to it, broadcast, or headerless."""
    h = peek_header(data, require_preamble=False)
    return h is None or node in (h[0], h[1]) or h[0] == SPEC.protocol["broadcast_id"]


def plan(records: Sequence[Any], node: int) -> tuple[list[Step], int]:
    """The played side's datagrams (everything to ``node``, broadcast or headerless, not sent
    by it), each with the node's count before it; and the node's total."""
    steps: list[Step] = []
    node_sent = 0
    last_t: int | None = None
    for r in records:
        if _src(r.data) == node:
            node_sent += 1
            continue
        if not involves(r.data, node):
            continue
        gap = 0.0 if last_t is None else max(0.0, (r.t_ns - last_t) / 1e9)
        last_t = r.t_ns
        steps.append(Step(bytes(r.data), node_sent, gap))
    return steps, node_sent


def _first_seqs(records: Iterable[Any]) -> dict[int, int]:
    out: dict[int, int] = {}
    for r in records:
        h = peek_header(r.data, require_preamble=False)
        if h is not None:
            out.setdefault(h[1], h[2])
    return out


def _remap(data: bytes, ids: dict[int, int]) -> bytes:
    """The datagram with header dst/src IDs mapped by ``ids``."""
    if len(data) < HEADER_SIZE or not ids:
        return data
    dst = int.from_bytes(data[9:11], "big")
    src = int.from_bytes(data[11:13], "big")
    nd, ns = ids.get(dst, dst), ids.get(src, src)
    if (nd, ns) == (dst, src):
        return data
    return data[:9] + nd.to_bytes(2, "big") + ns.to_bytes(2, "big") + data[13:]


def _remap_ack(data: bytes, node: int, offset: int | None) -> bytes:
    """An ACK to the node: its acknowledged seq in the live node's numbering."""
    if offset is None or len(data) != HEADER_SIZE + 2 or peek_header(data, require_preamble=False) is None:
        return data
    h = peek_header(data, require_preamble=False)
    assert h is not None
    if h[3] != _ACK or h[0] != node:
        return data
    acked = int.from_bytes(data[HEADER_SIZE:], "big")
    return data[:HEADER_SIZE] + ((acked + offset) & _U16).to_bytes(2, "big")


def _awaits_ack(data: bytes, node: int) -> bool:
    """A well-formed unicast non-ACK to the node: its sender retransmits it until ACKed."""
    from mcp_conform.spec.codec import DecodeError, decode

    try:
        m = decode(data)
    except DecodeError:
        return False
    return m.action != Action.ACK and m.dst == node


# ---------------------------------------------------------------- running
@dataclass
class ReplayConfig:
    role: str = MCP.default_role.name
    target: tuple[str, int] | None = None
    listen: tuple[str, int] | None = None
    target_id: int | None = None  # the live node's ID (default: the capture's)
    node_id: int | None = None  # the node's ID in the capture (default: from the role)
    spawn: str | None = None
    mavlink: bool = False
    rto: float = float(SPEC.params["timeout_s"])
    ack_window: float = 2.0
    answer_timeout: float | None = None  # default: 1.5 x rto + ack_window
    max_gap: float = 0.5
    timeout: float = 300.0
    copies_tolerance: int = 1
    capture: str | None = None
    rewrite_acks: bool = True


def _as_records(datagrams: Iterable[Any]) -> list[Rec]:
    out = []
    for n, d in enumerate(datagrams):
        if isinstance(d, (bytes, bytearray)):
            out.append(Rec(n, n, None, None, bytes(d)))
        else:
            out.append(Rec(n, int(d.t_ns), d.src_addr, d.dst_addr, bytes(d.data)))
    return in_time_order(out)


def _manager_placeholders(records: Sequence[Rec], node: int, tmp: Path) -> dict[str, str]:
    """{drones}, {challenge}, {waypoints}, {obstacles} for a manager under test, from the
    capture (QGC WPL 110 files of the lists and waypoints the recorded manager sent)."""
    from mcp_conform.spec.codec import DecodeError, decode
    from mcp_conform.spec.mission import save_waypoints

    drones: list[int] = []
    lists: dict[int, list[Any]] = {}
    for r in records:
        try:
            m = decode(r.data)
        except DecodeError:
            continue
        if m.src != node and m.src not in drones and m.src != SPEC.protocol["broadcast_id"]:
            drones.append(m.src)
        if m.src == node and m.action in (Action.WP_LIST, Action.OBSTACLES_LIST):
            lists.setdefault(int(m.action), list(m.payload))
        if m.src == node and m.action == Action.WP_ON:
            wps = lists.setdefault(int(Action.WP_ON), [])
            if m.payload not in wps:
                wps.append(m.payload)
    challenge = "1" if Action.WP_LIST in lists else "2" if Action.WP_ON in lists else \
        "3" if Action.OBSTACLES_LIST in lists else "1"
    waypoints = lists.get(int(Action.WP_LIST)) or lists.get(int(Action.WP_ON)) or []
    obstacles = lists.get(int(Action.OBSTACLES_LIST)) or []
    wp, ob = tmp / "replay.waypoints", tmp / "replay-obstacles.waypoints"
    save_waypoints(wp, waypoints or obstacles)  # a manager needs its waypoints file whatever the challenge
    save_waypoints(ob, obstacles or waypoints)
    return {"drones": ",".join(map(str, sorted(drones))), "challenge": challenge, "waypoints": str(wp),
            "obstacles": str(ob)}


def replay(datagrams: Iterable[Any], target: tuple[str, int] | None = None, **options: Any) -> ReplayResult:
    """Play every sender but the node under test against a live node (see the module doc).

    ``datagrams``: capture records (``t_ns``, ``src_addr``, ``dst_addr``, ``data``) or raw
    bytes (all sent by the played side, in order). ``options``: :class:`ReplayConfig` fields.
    Raises :class:`ReplayError` (one line) when it cannot run.
    """
    cfg = ReplayConfig(target=target, **options)
    if cfg.target is None and cfg.spawn is None:
        raise ReplayError("replay needs --target HOST:PORT or --spawn CMD")
    records = _as_records(datagrams)
    fixed = MCP.role(cfg.role).fixed_id  # a role whose ID the spec fixes is found by it in the capture
    node = cfg.node_id if cfg.node_id is not None else (
        cfg.target_id if cfg.target_id is not None and fixed is None else node_id_for(records, cfg.role))
    live_id = cfg.target_id if cfg.target_id is not None else node
    steps, node_total = plan(records, node)
    answer_timeout = cfg.answer_timeout if cfg.answer_timeout is not None else 1.5 * cfg.rto + cfg.ack_window
    with tempfile.TemporaryDirectory(prefix="mcp-replay-") as tmp:
        live = _run_live(cfg, records, steps, node_total, node, live_id, answer_timeout, Path(tmp))
    return live


def _run_live(cfg: ReplayConfig, records: list[Rec], steps: list[Step], node_total: int, node: int,
              live_id: int, answer_timeout: float, tmp: Path) -> ReplayResult:
    from mcp_conform.harness.driver import TargetDriver
    from mcp_conform.harness.errors import SetupError
    from mcp_conform.harness.session_base import (
        BROADCAST_ADDRESS,
        SpawnedNode,
        fill_placeholders,
        free_port,
    )

    role = MCP.role(cfg.role)
    peer = MCP.role(role.peer)  # the side replay plays: its port, its ID when the spec fixes one
    listen = cfg.listen or (("", 0) if cfg.spawn else ("", int(_PORTS[peer.name])))
    target = cfg.target or ("127.0.0.1", free_port())
    driver = TargetDriver(target, listen, our_id=-1 if peer.fixed_id is None else peer.fixed_id)
    driver.auto_ack = lambda d: False  # the capture's ACKs are replayed, at the capture's pace
    try:
        driver.open()
    except OSError as exc:
        raise ReplayError(str(exc)) from None
    vehicle = proc = recorder = None
    ids = {node: live_id} if live_id != node else {}
    back = {live_id: node} if live_id != node else {}
    notes: list[str] = []
    try:
        if cfg.capture:
            from mcp_conform.traceio.recorder import McapRecorder, RecorderError, run_metadata

            try:
                recorder = McapRecorder(cfg.capture, local=driver.listen, metadata=run_metadata(
                    "mcp-capture replay", role=cfg.role, target=f"{target[0]}:{target[1]}", spawn=cfg.spawn))
            except RecorderError as exc:
                raise ReplayError(str(exc)) from None
            driver.add_observer(recorder.datagram)
        if cfg.spawn:
            if cfg.mavlink:
                from mcp_conform.vehicle import SimVehicle

                vehicle = SimVehicle()
                vehicle.start("127.0.0.1", 0)
            lhost = driver.listen[0] or "127.0.0.1"
            values = {"target_host": target[0], "target_port": str(target[1]),
                      "listen_host": "127.0.0.1" if lhost == "0.0.0.0" else lhost,
                      "listen_port": str(driver.listen[1]), "broadcast": BROADCAST_ADDRESS,
                      "id": str(live_id), "mavlink": vehicle.url if vehicle is not None else ""}
            if role.parameters:  # a role run with mission parameters: {drones}, {challenge}, ... from the capture
                values.update(_manager_placeholders(records, node, tmp))
            try:
                proc = SpawnedNode(fill_placeholders(cfg.spawn, values))
            except SetupError as exc:
                raise ReplayError(str(exc)) from None
            driver.alive = proc.alive
        node_seq0 = _first_seqs(records).get(node)
        deadline = time.monotonic() + cfg.timeout

        def node_sent() -> list[Any]:
            return [d for d in driver.received() if d.header is not None and d.header[1] == live_id]

        def wait_node(count: int, limit_s: float, resend: bytes | None) -> None:
            """Until the node has sent ``count`` datagrams (bounded); meanwhile the played
            side's last unicast is retransmitted every rto, as its sender would (MCP-RTX-1)."""
            limit = min(time.monotonic() + limit_s, deadline)
            next_copy = time.monotonic() + cfg.rto
            while len(node_sent()) < count and time.monotonic() < limit:
                if proc is not None and not proc.alive():
                    return
                driver.wait_for(lambda d: False, 0.02, driver.mark())
                if resend is not None and time.monotonic() >= next_copy:
                    with contextlib.suppress(OSError):
                        sent = driver.send_raw(resend)
                        if not node_sent():  # knocking until the node is up: not part of the replay
                            knocks.add(sent.t_ns)
                    next_copy = time.monotonic() + cfg.rto

        knocks: set[int] = set()
        last_send = time.monotonic()
        offset: int | None = None
        startup = True  # the node's first answer may take its whole startup
        resend: bytes | None = None
        for step in steps:
            if time.monotonic() > deadline:
                notes.append(f"stopped at the --timeout of {cfg.timeout:g} s")
                break
            if proc is not None and not proc.alive():
                notes.append(f"the node exited with code {proc.returncode} during the replay")
                break
            if step.node_sent_before:
                wait_node(step.node_sent_before, max(20.0, answer_timeout) if startup else answer_timeout,
                          resend)
                startup = False
            gap = min(step.gap_s, cfg.max_gap) - (time.monotonic() - last_send)
            if gap > 0:
                time.sleep(gap)
            if offset is None and node_seq0 is not None:
                live_first = node_sent()
                if live_first:
                    offset = (live_first[0].header[2] - node_seq0) & _U16
            data = _remap(step.data, ids)
            if cfg.rewrite_acks:
                data = _remap_ack(data, live_id, offset)
            with contextlib.suppress(OSError):
                driver.send_raw(data)
            last_send = time.monotonic()
            resend = data if _awaits_ack(data, live_id) else None
        wait_node(node_total, max(20.0, answer_timeout) if startup else answer_timeout, resend)
        driver.quiet(gap=min(cfg.ack_window, 0.5), limit=cfg.ack_window + 0.5)
        if node_total and not node_sent():
            # not one answer: no node to compare (a dead port, a wrong address, a node that
            # did not start), a setup error rather than "different" (issue 19 item 8)
            why = (f"it exited with code {proc.returncode}" if proc is not None and not proc.alive()
                   else "is a node running there?")
            raise ReplayError(f"the node at {target[0]}:{target[1]} never answered ({len(driver.sent())} datagram(s) "
                              f"sent; it sent {node_total} in the capture): {why}")
        live = _live_records(driver, back, knocks)
        golden = [r for r in records if involves(r.data, node)]
        result = ReplayResult(diff_sides(side_from_datagrams("capture", golden),
                                         side_from_datagrams("replay", live),
                                         DiffOptions(copies_tolerance=cfg.copies_tolerance)),
                              sent=len(driver.sent()), received=len(driver.received()), notes=notes)
        result.violations, result.monitor = _monitor(cfg, live, node)
        if proc is not None:
            result.node_output = proc.output_tail(20)
        return result
    finally:
        if proc is not None:
            proc.close()
        if vehicle is not None:
            with contextlib.suppress(Exception):
                vehicle.close()
        driver.close()
        if recorder is not None:
            recorder.close()


def _live_records(driver: Any, back: dict[int, int], knocks: set[int]) -> list[Rec]:
    """What the replay sent and received, in time order, with the live node's ID mapped
    back to the capture's (so the diff compares like with like); without the copies sent
    before the node first answered (``knocks``: the node was not up yet)."""
    listen = driver.listen
    rows = [(s.t_ns, listen, s.addr, s.data) for s in driver.sent() if s.t_ns not in knocks]
    rows += [(d.t_ns, d.addr, listen, d.data) for d in driver.received()]
    rows.sort(key=lambda r: r[0])
    return [Rec(n, t, src, dst, _remap(data, back)) for n, (t, src, dst, data) in enumerate(rows)]


def _monitor(cfg: ReplayConfig, live: list[Rec], node: int) -> tuple[list[Any], str]:
    """The monitor over the replay's traffic; only the node's violations count (what the
    played side sent is the capture's, deliberate breaches of a runner's cases included)."""
    try:
        from mcp_conform.judge.monitor import Monitor
    except ImportError:
        return [], "the trace monitor (judge.monitor) is not installed"
    mon = Monitor(rto=cfg.rto, ack_window=cfg.ack_window)
    out: list[Any] = []
    for r in live:
        out += mon.advance(r.t_ns)
        out += mon.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data)
    if live:
        out += mon.finish(live[-1].t_ns)
    return [v for v in out if v.node == node], ""


# ---------------------------------------------------------------- command line
def _hostport(what: str, default_host: str) -> Any:
    import argparse

    from mcp_conform.harness.config import (
        parse_hostport,  # the runner's HOST:PORT parsing and messages
    )

    def parse(text: str) -> tuple[str, int]:
        try:
            return parse_hostport(text, what, default_host)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc)) from None
    return parse


def register(sub: Any) -> None:
    p = sub.add_parser("replay", help="play one side of a capture against a live node; diff its answers",
                       description="Play every sender of CAPTURE but the node under test against a "
                                   "live node (attach or spawn), then diff its answers with the capture "
                                   "and judge the traffic with the monitor.")
    p.add_argument("capture", metavar="CAPTURE", help="MCAP, pcap or pcapng capture")
    p.add_argument("--target", type=_hostport("--target", "127.0.0.1"), metavar="HOST:PORT", help="the live node's address")
    p.add_argument("--listen", type=_hostport("--listen", ""), metavar="HOST:PORT",
                   help="where replay receives and sends from (default: all addresses, the role's port; "
                        "spawn: an ephemeral port)")
    p.add_argument("--role", choices=MCP.role_names, default=MCP.default_role.name,
                   help=f"the node's role ({MCP.default_role.name})")
    p.add_argument("--target-id", type=int, metavar="N", help="the live node's MCP ID (default: the capture's)")
    p.add_argument("--node-id", type=int, metavar="N", help="the node's MCP ID in the capture (default: by role)")
    p.add_argument("--spawn", metavar="CMD", help="start the node (the runner's placeholders)")
    p.add_argument("--mavlink", action="store_true", help="spawn mode: start the simulated vehicle ({mavlink})")
    p.add_argument("--rto", type=float, default=float(SPEC.params["timeout_s"]), metavar="S",
                   help="the node's retransmission timeout (sizes the waits)")
    p.add_argument("--ack-window", type=float, default=2.0, metavar="S", help="how long silence is watched (2)")
    p.add_argument("--answer-timeout", type=float, metavar="S", help="longest wait for the node's answers")
    p.add_argument("--max-gap", type=float, default=0.5, metavar="S",
                   help="keep the capture's gaps between sends up to S seconds (0.5)")
    p.add_argument("--timeout", type=float, default=300.0, metavar="S", help="bound on the whole replay (300)")
    p.add_argument("--copies-tolerance", type=int, default=1, metavar="N", help="as in diff (1)")
    p.add_argument("--capture", dest="capture_out", metavar="FILE.mcap", help="record the replay to an MCAP file")
    from mcp_conform.traceio.grammar import deprecated

    deprecated(p, "--capture-out", "--capture", dest="capture_out")
    p.add_argument("--json", metavar="OUT", help="write the result as JSON")
    p.set_defaults(run=run)


def run(args: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """``mcp-capture replay``: the options checked, then the capture's protocol's replay."""
    from mcp_conform.captures.cli import capture_tools, check_writable
    from mcp_conform.traceio.reader import CaptureError

    err = err or sys.stderr
    check_writable(args.json, "--json")
    try:
        tools = capture_tools(args, args.capture)
    except CaptureError as exc:
        err.write(f"mcp-capture: error: replay: {exc}\n")
        return 2
    return int(tools.run_replay(args, out, err))


def run_replay(args: Any, out: TextIO | None = None, err: TextIO | None = None) -> int:
    """MCP's replay (``captures.mcp``): :func:`replay`, or a fuzz finding's reproduction."""
    from mcp_conform.captures.cli import to_terminal
    from mcp_conform.captures.diff import build_json
    from mcp_conform.traceio.reader import CaptureError, Datagram, Metadata, open_capture
    from mcp_conform.traceio.recorder import FUZZ_RECORDER

    out = out or sys.stdout
    err = err or sys.stderr
    try:
        everything = list(open_capture(args.capture))
    except CaptureError as exc:
        err.write(f"mcp-capture: error: replay: {exc}\n")
        return 2
    records = [r for r in everything if type(r) is Datagram]
    fuzz_meta = next((r.data for r in everything if type(r) is Metadata and r.data.get("recorder") == FUZZ_RECORDER),
                     None)
    if fuzz_meta is not None and args.role == fuzz_meta.get("role"):  # the finding's fuzzed role
        return _reproduce_finding(args, fuzz_meta, out, err)
    try:
        result = replay(records, args.target, role=args.role, listen=args.listen, target_id=args.target_id,
                        node_id=args.node_id, spawn=args.spawn, mavlink=args.mavlink, rto=args.rto,
                        ack_window=args.ack_window, answer_timeout=args.answer_timeout,
                        max_gap=args.max_gap, timeout=args.timeout, copies_tolerance=args.copies_tolerance,
                        capture=args.capture_out)
    except ReplayError as exc:
        err.write(f"mcp-capture: error: replay: {exc}\n")
        return 2
    # the file first: a piped terminal report (`| head -1`) loses neither it nor the verdict
    if args.json:
        body = {"diff": build_json(result.diff), "sent": result.sent, "received": result.received,
                "notes": result.notes, "monitor": result.monitor or None,
                "violations": [{"rule": v.rule, "level": v.level, "node": v.node, "expected": str(v.expected),
                                "actual": str(v.actual)} for v in result.violations],
                "ok": result.ok}
        from mcp_conform.traceio.grammar import write_text

        try:
            write_text(args.json, json.dumps(body, indent=1) + "\n")
        except OSError as exc:
            err.write(f"mcp-capture: error: replay: cannot write {args.json}: {exc.strerror}\n")
            return 2

    def terminal() -> None:
        out.write(f"replayed {result.sent} datagrams, received {result.received}\n")
        for note in result.notes:
            out.write(f"note: {note}\n")
        print_report(result.diff, out)
        if result.monitor:
            out.write(f"monitor: not judged: {result.monitor}\n")
        else:
            out.write(f"monitor: {len(result.violations)} violation(s)\n")
            for v in result.violations[:20]:
                out.write(f"  {v.rule} {v.level} node {v.node}: expected {v.expected}; actual {v.actual}\n")
        if result.node_output and not result.ok:
            out.write("node output (last lines):\n    " + result.node_output.replace("\n", "\n    ") + "\n")

    to_terminal(terminal)
    return result.exit_code


def _reproduce_finding(args: Any, meta: dict[str, str], out: TextIO, err: TextIO) -> int:
    """A finding's repro.mcap (metadata recorder ``mcp-fuzz``): its minimal sequence is
    replayed as ``mcp-fuzz --replay`` does (the same pace, scenario and oracles), since a
    diff against the campaign's traffic (probes, restarts) would judge the wrong thing.
    Exit 1 when the finding reproduces (the node still breaks the rule), 0 when not."""
    from mcp_conform.fuzz.config import FuzzConfig
    from mcp_conform.fuzz.findings import finding_from_metadata
    from mcp_conform.fuzz.replay_cli import reproduce

    f = finding_from_metadata(meta)
    if f is None:
        err.write("mcp-capture: error: replay: the capture is an mcp-fuzz finding without its sequence in the "
                  "metadata record; replay it with mcp-fuzz --replay FINDING-DIR\n")
        return 2
    if args.target is None and not args.spawn:
        err.write("mcp-capture: error: replay: a fuzz finding needs --target HOST:PORT or --spawn CMD\n")
        return 2
    out.write(f"{args.capture}: an mcp-fuzz finding ({f.rule}, {f.engine} engine, seed {f.seed}); "
              f"replaying its {len(f.datagrams)} datagram(s) as mcp-fuzz --replay does\n")
    out.flush()
    cfg = FuzzConfig(target=args.target, spawn=args.spawn, listen=args.listen, target_id=args.target_id,
                     mavlink=args.mavlink, rto=args.rto, ack_window=args.ack_window)
    return reproduce(f, cfg, prog="mcp-capture replay")

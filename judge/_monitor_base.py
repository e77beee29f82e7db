"""Records, constants and per-node state of the trace monitor (``judge.monitor``).

Everything here is plain data: the public records (:class:`Violation`, :class:`NodeFacts`,
:class:`VehicleEvent`), the spec-derived constants the rules use (never re-typed: levels,
texts and parameters come from ``spec/mcp.yaml``), and the small mutable state objects the
rule mixins share (:class:`_Node`, :class:`_Exchange`). Times are integer nanoseconds on
whatever clock the trace was taken with; evidence names datagrams by their index in the
order they were fed to the monitor.
"""

from __future__ import annotations

import heapq
import itertools
from collections import deque
from collections.abc import Callable
from typing import Any, NamedTuple

from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import HEADER, HEADER_SIZE, ITEM, MANAGER_ID, PREAMBLE, Action
from mcp_conform.spec.profiles import MCP

__all__ = [
    "byte_order_fault",
    "NodeFacts",
    "TESTER",
    "VehicleEvent",
    "Violation",
]

# ---------------------------------------------------------------- spec-derived constants
NS = 1_000_000_000
PARAMS = SPEC.params
MIN_COPIES = int(PARAMS["min_copies"])  # MCP-RTX-1: "at least 3 copies while the ACK is withheld"
MAX_ACK_COPIES = int(PARAMS["max_ack_copies"])  # copies a command may go unACKed (MCP-ACK-1)
RTX_TOLERANCE = float(PARAMS["rtx_spacing_tolerance"])  # ±20 % of the median gap (MCP-RTX-3)
RTX_MIN_GAP_NS = int(float(PARAMS["rtx_min_gap_s"]) * NS)  # no storm (MCP-RTX-3)
JITTER_NS = int(float(PARAMS["timing_jitter_s"]) * NS)  # timestamping allowance (MCP-RTX-3)
ACK_DEADLINE_NS = int(float(PARAMS["ack_deadline_s"]) * NS)  # MCP-ACK-7
ACK_SAMPLES = int(PARAMS["ack_latency_samples"])  # MCP-ACK-7: median of at least this many
LEVEL = {r.id: r.level for r in SPEC.rules}
VERDICT_OF_LEVEL = {"MUST": "failed", "SHOULD": "warned", "INFO": "info"}

HDR = HEADER_SIZE
PRE = PREAMBLE
PRE_LEN = len(PREAMBLE)
unpack_header = HEADER.unpack_from
pack_item = ITEM.pack
MANAGER = MANAGER_ID
MR = int(Action.MISSION_READY)
START = int(Action.START_MISSION)
END = int(Action.END_MISSION)
WP_LIST = int(Action.WP_LIST)
WP_ON = int(Action.WP_ON)
WP_OFF = int(Action.WP_OFF)
OBSTACLES = int(Action.OBSTACLES_LIST)
ACK = int(Action.ACK)
PASSTHROUGH = int(Action.MAV_PASSTHROUGH)
N_ACTIONS = sum(1 for a in SPEC.actions if a.on_wire)  # 9: codes 0-8 (MCP-HDR-3)
ACTION_NAME = {a.code: a.wire_name for a in SPEC.actions}
DRONE_SENDS = frozenset(a.code for a in SPEC.actions if a.on_wire and a.sent_by in ("drone", "any"))
MANAGER_SENDS = frozenset(a.code for a in SPEC.actions if a.on_wire and a.sent_by in ("manager", "any"))

#: The sender-side rule a payload that does not fit its action breaks, by action code. The
#: receiver-side rule of the same datagram is MCP-ROB-4 (D-4).
PAYLOAD_RULE = {MR: "MCP-PAY-2", START: "MCP-PAY-1", END: "MCP-PAY-1", WP_OFF: "MCP-PAY-1",
                WP_LIST: "MCP-PAY-3", OBSTACLES: "MCP-PAY-3", WP_ON: "MCP-PAY-5",
                ACK: "MCP-ACK-2", PASSTHROUGH: "MCP-PAY-6"}


def action_name(code: int) -> str:
    return ACTION_NAME.get(code, f"action {code}")


def _swapped(value: int) -> int:
    return ((value & 0xFF) << 8) | (value >> 8)


def byte_order_fault(origin: int, src: int, action: int) -> str | None:
    """MCP-HDR-2 (network byte order): why the header of a datagram known to come from node
    ``origin`` reads right only with its u16 fields byte-swapped (src is ``origin`` swapped,
    or the action code is a valid one swapped), else None. One diagnosis for the monitor and
    the runner's startup phase: a node writing its header little-endian breaks MCP-HDR-2, and
    the wrong src or action code that network order then reads (MCP-HDR-4/3) is not a fault
    of its own."""
    why = []
    if src != origin and _swapped(src) == origin:
        why.append(f"src {src} (0x{src:04x}) is ID {origin} byte-swapped")
    if action >= N_ACTIONS and _swapped(action) < N_ACTIONS:
        why.append(f"action code {action} (0x{action:04x}) is {action_name(_swapped(action))} byte-swapped")
    return "; ".join(why) or None


def role_of(node: int) -> str:
    """The MCP role of the node with this ID (``spec.profiles``: ID 0 is the manager's)."""
    return MCP.role_of_id(node).name


class _Tester:
    """The sentinel ``origin`` of datagrams the test harness sent on purpose."""

    _instance: _Tester | None = None

    def __new__(cls) -> _Tester:
        if cls._instance is None:
            cls._instance = super().__new__(cls)
        return cls._instance

    def __repr__(self) -> str:
        return "TESTER"


#: ``Monitor.datagram(..., origin=TESTER)``: the harness's own datagram (possibly faulty on
#: purpose). It is judged only as input to the other nodes; its sender is never blamed.
TESTER = _Tester()


# ---------------------------------------------------------------- public records
Evidence = tuple[tuple[int, int], ...]  # ((datagram index, t_ns), ...)


class Violation(NamedTuple):
    """One rule a node broke, as soon as the trace proves it.

    ``node`` is the MCP ID blamed; ``evidence`` the datagrams involved as ``(index, t_ns)``
    pairs (index = position in the monitor's input). ``level`` and :attr:`text` come from
    spec/mcp.yaml.
    """

    rule: str
    level: str
    node: int
    t_ns: int
    expected: str
    actual: str
    evidence: Evidence

    @property
    def text(self) -> str:
        """The rule's text, from the spec."""
        return SPEC.rule(self.rule).text


class NodeFacts(NamedTuple):
    """What the trace showed of one MCP node (for listings such as ``mcp-capture check``)."""

    id: int
    role: str  # "manager" (ID 0) or "drone"
    addresses: tuple[tuple[str, int], ...]  # source addresses it sent from
    datagrams: int  # datagrams attributed to it (sent)
    received: int  # datagrams addressed to its ID


class VehicleEvent(NamedTuple):
    """One observation on a drone's autopilot link (MAVLink), fed with ``Monitor.vehicle``.

    ``kind`` is one of :data:`VEHICLE_KINDS`:

    - ``link``: the drone's link to its autopilot is observed from here on (until a ``fix``
      the autopilot reports no GPS fix);
    - ``fix`` / ``fix_lost``: the autopilot started / stopped reporting a GPS fix;
    - ``arm``: the drone asked the autopilot to ARM (``ok``: whether it was accepted);
    - ``disarm``, ``takeoff``: likewise;
    - ``mode``: a mode change was requested (``mode``: its ArduCopter name);
    - ``rtl``: RTL was commanded (RTL mode or MAV_CMD_NAV_RETURN_TO_LAUNCH);
    - ``frame``: the drone wrote a MAVLink frame to its autopilot (``frame``: its bytes;
      ``token``: the passthrough-probe token when it is one);
    - ``busy`` / ``idle``: the autopilot started / stopped carrying out an earlier command a
      node may wait for (a take-off climbing, an AUTO mission flying; ``detail``: what), as the
      simulated vehicle records it (MCP-BLK-7's "finishes pending actions");
    - ``unparsed``: the drone wrote bytes that are no valid frame (a bad CRC, no start
      marker, an incomplete or unknown-id frame; ``frame``: the bytes, ``detail``: why), as
      a passthrough frame altered on its way arrives (MCP-PAY-8).
    """

    kind: str
    ok: bool | None = None
    mode: str | None = None
    frame: bytes | None = None
    token: str | None = None
    detail: str = ""


VEHICLE_KINDS = ("link", "fix", "fix_lost", "arm", "disarm", "takeoff", "mode", "rtl", "frame", "unparsed",
                 "busy", "idle")


# ---------------------------------------------------------------- shared state
#: kinds of wrong ACK (MCP-RTX-2): the wrong seq from the message's destination (a stale ACK is
#: one too), and the message's seq from another node
WRONG_SEQ, WRONG_SRC = 1, 2


class _Exchange:
    """One message (src, dst, seq) and its copies, with the ACKs naming it."""

    __slots__ = ("src", "dst", "seq", "action", "data", "payload", "copies", "acks",
                 "tester", "bcast", "flags", "deliveries", "last_t", "addr", "stale_ack", "moved_on",
                 "heard", "run_delays", "owed", "wrong_at", "maybe_answered")

    def __init__(self, src: int, dst: int, seq: int, action: int, data: bytes, payload: Any,
                 i: int, t: int, tester: bool, bcast: bool, rd: int | None = None) -> None:
        self.src = src
        self.dst = dst
        self.seq = seq
        self.action = action
        self.data = data
        self.payload = payload
        self.copies: list[tuple[int, int]] = [(i, t)]
        self.run_delays: list[int | None] = [rd]  # the sender's run delay at each copy (MCP-RTX-3)
        self.last_t = t  # time of the latest copy
        self.acks: list[tuple[int, int]] = []
        self.owed = 0  # copies that left before its first ACK came back, each owed an ACK
        #: (i, t_ns) of the latest ACK from its destination counted as a later copy's ACK of
        #: another message while a copy of this one waited: it may have answered that copy
        #: (naming a wrong seq), so the copy's MCP-ACK-1 is not proven after it
        self.maybe_answered: tuple[int, int] | None = None
        #: kind (WRONG_SEQ / WRONG_SRC) -> (i, t_ns) of the latest wrong ACK of that kind while
        #: it awaited its ACK (MCP-RTX-2's input): a copy well after one shows its sender
        #: ignores that kind (``_Node.ignores``)
        self.wrong_at: dict[int, tuple[int, int]] | None = None
        self.tester = tester
        self.bcast = bcast
        self.flags = 0  # bits: rules already reported on this exchange
        self.deliveries: tuple[tuple[int, int], ...] = ()  # (t_ns, copies seen by then) per forward
        self.addr: Any = None  # the source address of its first copy
        #: an ACK from its destination naming nothing sent to it, read after the sender's last
        #: command to that destination and before this message (MCP-RTX-2's input, like
        #: ``wrong_ack``: a sender that takes any ACK from the destination takes it for this one)
        self.stale_ack: tuple[int, int] | None = None
        self.moved_on: tuple[int, int] | None = None  # a new unicast sent right after a wrong ACK
        #: copies before this one may have gone unheard: its receiver showed itself only later
        #: (a node started after the message was first sent; MCP-ACK-1 counts from here)
        self.heard = 0

    @property
    def wrong_ack(self) -> tuple[int, int] | None:
        """The latest wrong ACK while it awaited its ACK, of either kind."""
        return max(self.wrong_at.values(), key=lambda a: a[1]) if self.wrong_at else None

    @property
    def first(self) -> tuple[int, int]:
        return self.copies[0]

    def copies_before(self, t: int) -> list[tuple[int, int]]:
        copies = self.copies
        if copies[-1][1] <= t:
            return copies
        return [c for c in copies if c[1] <= t]

    def describe(self) -> str:
        to = "broadcast" if self.bcast else f"ID {self.dst}"
        return f"{action_name(self.action)} seq {self.seq} from ID {self.src} to {to}"


#: Unparsed writes to an autopilot a node's record keeps (matched against passthroughs).
UNPARSED_KEPT = 64
#: Numbers taken by a node's ACKs within the MCP-SEQ-1 grace kept at most (a flood's bound).
TAKEN_KEPT = 1024


class _Node:
    """What the monitor knows of one MCP ID (as a sender and as a receiver)."""

    __slots__ = ("id", "sent", "received", "addresses", "real", "last_new", "acks_since",
                 "last_unicast", "ready", "ready_ex", "start", "end", "end_acked", "lists", "wp_active", "wp_items",
                 "unanswered",
                 "vehicle", "fix", "forwards", "first_command", "first_seq", "last_command_t",
                 "actions", "last_command", "seen", "delivered_from", "seq_gap", "unparsed", "taken",
                 "taken_before", "ignores", "busy", "busy_end")

    def __init__(self, node_id: int) -> None:
        self.id = node_id
        self.sent = 0
        self.received = 0
        self.addresses: dict[tuple[str, int], None] = {}
        self.real = False  # sent at least one datagram that was not the harness's
        self.last_new: _Exchange | None = None  # its latest new non-ACK message (MCP-SEQ-1)
        self.acks_since = 0  # ACKs (D-5) and malformed datagrams it sent since then
        #: MCP-SEQ-1 gap awaiting numbers taken by ACKs read late: [lo, hi, still needed, report]
        self.seq_gap: list[Any] | None = None
        #: (t_ns, seq) of the numbers its ACKs and malformed datagrams took, read within
        #: the grace (MCP-SEQ-1): of those read before a new message, the ones numbered
        #: after it explain the gap after it (``taken_before``, at the latest new message)
        self.taken: deque[tuple[int, int]] = deque(maxlen=TAKEN_KEPT)
        self.taken_before: tuple[int, ...] = ()
        self.last_unicast: _Exchange | None = None  # its latest new unicast (MCP-BLK-1)
        #: bits WRONG_SEQ / WRONG_SRC: kinds of wrong ACK it was seen to ignore (a copy of the
        #: message well after one), or both once it was seen moving on with no ACK to take
        #: (MCP-BLK-1/3): it is not taken to have taken one of that kind (MCP-RTX-2)
        self.ignores = 0
        self.first_seq: int | None = None  # MCP-SEQ-4
        self.actions: set[int] = set()  # action codes of its new messages so far
        self.seen: set[str] = set()  # rules observed on it (judged, violated or not)
        # as a drone, the mission as the trace shows it
        self.ready: tuple[int, int] | None = None  # its Mission_Ready (first copy) this mission
        self.ready_ex: _Exchange | None = None
        self.start: _Exchange | None = None  # Start_Mission sent to it
        self.end: _Exchange | None = None  # End_Mission sent to it
        self.end_acked: int | None = None
        self.last_command_t = 0  # first copy of the latest command to it other than End_Mission
        self.last_command: _Exchange | None = None  # the manager's latest command to it
        self.lists: dict[int, _Exchange] = {}  # WP_List / Obstacles_List sent to it, by action
        self.wp_active: _Exchange | None = None  # challenge 2: the WP_On not yet followed by WP_Off
        #: what its autopilot shows in progress of an earlier command (a ``busy`` event's
        #: detail; None: nothing, or no such events), and when that last ended (``idle``)
        self.busy: str | None = None
        self.busy_end: int | None = None
        #: challenge 2: the item each WP_On to it carried (None: one that could not be decoded),
        #: for MCP-FLOW-5's "every waypoint in a WP_On" (``judge.waypoints``)
        self.wp_items: list[Any] = []
        #: commands to it the manager moved on from with no answer yet (it may have given it up:
        #: excused from MCP-FLOW-5's every waypoint as the manager case excuses it)
        self.unanswered: list[_Exchange] = []
        # as a drone with an observed autopilot link
        self.vehicle = False
        self.fix: bool | None = None
        self.forwards: list[tuple[int, Any]] = []  # (t_ns, "RTL") RTLs on its autopilot link
        self.delivered_from: dict[int, _Exchange] = {}  # the last message delivered, by src
        #: (t_ns, bytes, why) the latest bytes written to its autopilot that were no frame
        self.unparsed: deque[tuple[int, bytes, str]] = deque(maxlen=UNPARSED_KEPT)
        # as the manager
        self.first_command: tuple[int, int] | None = None  # its first command to any drone

    @property
    def role(self) -> str:
        return role_of(self.id)


class _Timers:
    """Deadlines (t_ns, order, callback, args); callbacks run, in time order, when time
    reaches them. One mechanism, two lanes: ``at`` takes any time (a heap); ``after`` takes a
    stream of deadlines each no earlier than the one before (one fixed delay, as MCP-RTX-1's
    for every unicast), kept first in first out at O(1) on the hot path."""

    def __init__(self) -> None:
        self.heap: list[tuple[int, int, Callable[..., None], tuple[Any, ...]]] = []
        self.fifo: deque[tuple[int, int, Callable[..., None], tuple[Any, ...]]] = deque()
        self._order = itertools.count()

    def at(self, t_ns: int, fn: Callable[..., None], *args: Any) -> None:
        heapq.heappush(self.heap, (t_ns, next(self._order), fn, args))

    def after(self, t_ns: int, fn: Callable[..., None], *args: Any) -> None:
        """A deadline no earlier than every one given to ``after`` before it."""
        self.fifo.append((t_ns, next(self._order), fn, args))

    def pending(self, now: int) -> bool:
        heap, fifo = self.heap, self.fifo
        return bool((heap and heap[0][0] <= now) or (fifo and fifo[0][0] <= now))

    def due(self, now: int) -> list[tuple[Callable[..., None], tuple[Any, ...]]]:
        out: list[tuple[Callable[..., None], tuple[Any, ...]]] = []
        heap, fifo = self.heap, self.fifo
        while True:
            h = heap[0] if heap and heap[0][0] <= now else None
            f = fifo[0] if fifo and fifo[0][0] <= now else None
            if h is None and f is None:
                return out
            if f is None or (h is not None and h[:2] < f[:2]):
                heapq.heappop(heap)
                out.append((h[2], h[3]))  # type: ignore[index]
            else:
                fifo.popleft()
                out.append((f[2], f[3]))


def late_ack_wait_ns(rto_ns: int, window_ns: int) -> int:
    """How long a copy of an ACKed message waits to be ACKed again (MCP-ACK-1: "ACKed again,
    however late"; its latency is MCP-ACK-7's): the monitor's deadline, and the manager-role
    case's wait for the ACK of its copy of a Mission_Ready (one judge: a loaded host's manager
    ACKed that copy 287 ms later, past the case's 0.2 s --rto, and the case alone failed it)."""
    return max(4 * window_ns, 2 * rto_ns, NS)


def late_ack_wait_s(rto: float, ack_window: float) -> float:
    """``late_ack_wait_ns`` from the runner's --rto and --ack-window in seconds."""
    return late_ack_wait_ns(int(rto * NS), int(ack_window * NS)) / NS


def median(values: list[int]) -> int:
    s = sorted(values)
    n = len(s)
    return s[n // 2] if n % 2 else (s[n // 2 - 1] + s[n // 2]) // 2


def gaps(copies: list[tuple[int, int]]) -> list[int]:
    return [b[1] - a[1] for a, b in zip(copies, copies[1:], strict=False)]


def fmt_s(ns: int) -> str:
    return f"{ns / NS:.3f} s"


def fmt_ms(ns: int) -> str:
    return f"{ns / 1e6:.1f} ms"

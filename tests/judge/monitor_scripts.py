"""Scripted MCP conversations for testing the trace monitor (and anything that reads traces).

A :class:`Script` plays a Mission Manager (ID 0) and drones on a virtual clock and records
every datagram as it would appear on a capture taken on the one host where they all run:
the manager at 127.0.0.1:7889, drone *d* at 127.0.0.(10+d):7890 and the manager's messages
to drones sent to the loopback broadcast 127.255.255.255:7890, as the description does.
Autopilot-link events (``VehicleEvent``) can be recorded beside the datagrams.

    s = Script(drones=(1, 2), challenge=1, seed=3)
    s.mission()                        # a whole clean mission, every drone ACKing
    trace = s.datagrams()              # [(t_ns, src_addr, dst_addr, data, origin)]
    violations = s.judge()             # feed a fresh Monitor, finish, return violations
    s.write_pcap(path)                 # the same datagrams as a pcap (scapy: Ether/IP/UDP)

Faulty conversations are written step by step with the same building blocks
(:meth:`Script.exchange`, :meth:`Script.send`, :meth:`Script.ack`, :meth:`Script.raw`,
:meth:`Script.vehicle`); ``tests/judge/monitor_faults.py`` holds ``FAULTY``, one
conversation per fault with the one rule it must raise. Other tests (``mcp-capture check``)
import both modules.
"""

from __future__ import annotations

import random
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, NamedTuple

from mcp_conform.judge.monitor import TESTER, Monitor, VehicleEvent
from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import Action, Message, build_datagram, encode
from mcp_conform.spec.mavframe import heartbeat_frame
from mcp_conform.spec.mission import load_waypoints

__all__ = ["BROADCAST_ID", "OBSTACLES", "TESTER", "WAYPOINTS", "Record", "Script", "clean_script", "write_pcap"]

NS = 1_000_000_000
DATA = Path(__file__).resolve().parents[1] / "reference_impl" / "data"
WAYPOINTS = load_waypoints(DATA / "challenge.waypoints")
OBSTACLES = load_waypoints(DATA / "obstacles.waypoints")
MANAGER_ADDR = ("127.0.0.1", int(SPEC.protocol["ports"]["manager"]))
BROADCAST_ADDR = (str(SPEC.protocol["broadcast_address"]), int(SPEC.protocol["ports"]["drone"]))
T0_NS = 1_700_000_000 * NS
BROADCAST_ID = int(SPEC.protocol["broadcast_id"])


class Record(NamedTuple):
    """One datagram (``drone`` is None) or one autopilot-link event (``event`` set)."""

    t_ns: int
    src_addr: tuple[str, int] | None
    dst_addr: tuple[str, int] | None
    data: bytes
    origin: Any = None
    drone: int | None = None
    event: VehicleEvent | None = None


def drone_addr(d: int) -> tuple[str, int]:
    return (f"127.0.0.{10 + d}", BROADCAST_ADDR[1])


class Script:
    """A conversation on a virtual clock (see the module docstring).

    ``rto``: retransmission timeout of every node (s); ``ack_delay``: how long a node takes
    to ACK; ``seqs``: initial sequence numbers by node (random from ``seed`` otherwise);
    ``ack_numbers``: ACKs take a sequence number of their own (D-5).
    """

    def __init__(self, drones: Iterable[int] = (1, 2), *, challenge: int = 1, rto: float = 0.2,
                 ack_window: float = 0.25, ack_delay: float = 0.004, seed: int = 0,
                 seqs: dict[int, int] | None = None, ack_numbers: bool = True,
                 waypoints: tuple[Any, ...] | None = None, vehicle: bool = True,
                 vary: Callable[[], dict[str, Any]] | None = None) -> None:
        self.drones = tuple(drones)
        self.challenge = challenge
        self.rto = rto
        self.ack_window = ack_window
        self.ack_delay = ack_delay
        self.rng = random.Random(seed)
        self.seq = {n: self.rng.randrange(65536) for n in (0, *self.drones)}
        self.seq.update(seqs or {})
        self.ack_numbers = ack_numbers
        self.items = waypoints if waypoints is not None else (OBSTACLES if challenge == 3 else WAYPOINTS)
        self.with_vehicle = vehicle
        self.vary = vary  # per exchange: default deaf / lost_acks / ack_delay (property tests)
        self.t = 0.0
        self.records: list[Record] = []

    # ------------------------------------------------------------------ primitives
    def tick(self, dt: float) -> None:
        self.t += dt

    def addr(self, node: int) -> tuple[str, int]:
        return MANAGER_ADDR if node == 0 else drone_addr(node)

    def next_seq(self, node: int) -> int:
        s = self.seq.get(node, 0)
        self.seq[node] = (s + 1) & 0xFFFF
        return s

    def raw(self, src: int, data: bytes, *, to: int = 0, origin: Any = None) -> bytes:
        """Record ``data`` as sent by node ``src`` towards node ``to`` now."""
        dst_addr = MANAGER_ADDR if to == 0 else BROADCAST_ADDR
        self.records.append(Record(int(T0_NS + self.t * NS), self.addr(src), dst_addr, data, origin))
        return data

    def send(self, src: int, dst: int, action: Action, payload: Any = None, *, seq: int | None = None,
             origin: Any = None, hdr_src: int | None = None) -> tuple[int, bytes]:
        """One new message (a fresh number unless ``seq``); ``hdr_src`` fakes the header's src."""
        seq = self.next_seq(src) if seq is None else seq
        data = encode(Message(dst, src if hdr_src is None else hdr_src, seq, action, payload))
        self.raw(src, data, to=dst, origin=origin)
        return seq, data

    def ack(self, src: int, dst: int, named: int, *, origin: Any = None, little: bool = False,
            hdr_dst: int | None = None, hdr_src: int | None = None) -> bytes:
        own = self.next_seq(src) if self.ack_numbers else self.seq.get(src, 0)
        payload = named.to_bytes(2, "little" if little else "big")
        data = build_datagram(dst if hdr_dst is None else hdr_dst, src if hdr_src is None else hdr_src,
                              own, int(Action.ACK), payload)
        return self.raw(src, data, to=dst, origin=origin)

    def exchange(self, src: int, dst: int, action: Action, payload: Any = None, *, deaf: int = 0,
                 lost_acks: int = 0, ack_delay: float | None = None, origin: Any = None,
                 acker_origin: Any = None, gaps: list[float] | None = None, seq: int | None = None,
                 ack_hook: Callable[[int, int, bytes], bool] | None = None,
                 on_delivery: Callable[[], None] | None = None) -> int:
        """A unicast sent and retransmitted every ``rto`` until ACKed. The receiver misses the
        first ``deaf`` copies; the first ``lost_acks`` of its ACKs never reach the sender (they
        are on the capture). ``gaps`` overrides the spacing of the copies; ``ack_hook(k,
        seq, data)`` replaces the receiver's ACK of copy k (return True when it ended it);
        ``on_delivery()`` runs just after the receiver's first ACK (it acts on the message)."""
        if self.vary is not None and not deaf and not lost_acks and ack_delay is None:
            v = self.vary()
            deaf, lost_acks, ack_delay = v.get("deaf", 0), v.get("lost_acks", 0), v.get("ack_delay")
        seq, data = self.send(src, dst, action, payload, seq=seq, origin=origin)
        delay = self.ack_delay if ack_delay is None else ack_delay
        k = 0
        while True:
            if k >= deaf:
                self.tick(delay)
                if ack_hook is not None:
                    if ack_hook(k, seq, data):
                        return seq
                else:
                    self.ack(dst, src, seq, origin=acker_origin)
                    if k == deaf and on_delivery is not None:
                        self.tick(0.002)
                        on_delivery()
                        self.tick(-0.002)
                    if k - deaf >= lost_acks:
                        return seq
                self.tick(-delay)
            self.tick(gaps[k] if gaps is not None and k < len(gaps) else self.rto)
            k += 1
            self.raw(src, data, to=dst, origin=origin)

    def vehicle(self, drone: int, kind: str, **kw: Any) -> None:
        if self.with_vehicle:
            self.records.append(Record(int(T0_NS + self.t * NS), None, None, b"", None, drone,
                                       VehicleEvent(kind, **kw)))

    # ------------------------------------------------------------------ mission phases
    def ready(self, drone: int, **kw: Any) -> int:
        """The drone connects to its autopilot, gets a fix, says Mission_Ready."""
        self.vehicle(drone, "link")
        self.tick(0.01)
        self.vehicle(drone, "fix")
        self.tick(0.01)
        seq = self.exchange(drone, 0, Action.MISSION_READY, **kw)
        self.tick(0.02)
        return seq

    def start(self, drone: int, **kw: Any) -> int:
        """Start_Mission; the drone arms once it has it."""
        return self.exchange(0, drone, Action.START_MISSION,
                             on_delivery=lambda: self.vehicle(drone, "arm", ok=True), **kw)

    def challenge_steps(self, drones: Iterable[int] | None = None, **kw: Any) -> None:
        drones = self.drones if drones is None else tuple(drones)
        if self.challenge == 1:
            for d in drones:
                self.exchange(0, d, Action.WP_LIST, tuple(self.items), **kw)
                self.tick(0.01)
        elif self.challenge == 2:
            for wp in self.items:
                for d in drones:
                    self.exchange(0, d, Action.WP_ON, wp, **kw)
                    self.tick(0.01)
                for d in drones:
                    self.exchange(0, d, Action.WP_OFF, **kw)
                    self.tick(0.01)
        else:
            for d in drones:
                self.exchange(0, d, Action.OBSTACLES_LIST, tuple(self.items), **kw)
                self.tick(0.01)

    def broadcast(self, action: Action, payload: Any = None) -> int:
        """A broadcast of the manager (dst the broadcast ID, D-1): sent once, never ACKed
        (MCP-RTX-4, MCP-ACK-4); D-11: a command to each drone whose mission is on. It goes
        2 ms after what came before (an ACK the manager reads first: no datagram is answered at
        the instant it leaves)."""
        self.tick(0.002)
        seq, _ = self.send(0, BROADCAST_ID, action, payload)
        self.tick(0.01)
        return seq

    def passthrough(self, drone: int, frame: bytes | None = None, **kw: Any) -> int:
        """A Mav_Passthrough the drone ACKs and writes to its autopilot once."""
        frame = heartbeat_frame() if frame is None else frame
        return self.exchange(0, drone, Action.MAV_PASSTHROUGH, frame,
                             on_delivery=lambda: self.vehicle(drone, "frame", frame=frame), **kw)

    def end(self, drone: int, **kw: Any) -> int:
        """End_Mission; the drone commands RTL once it has it."""
        return self.exchange(0, drone, Action.END_MISSION,
                             on_delivery=lambda: self.vehicle(drone, "rtl", ok=True), **kw)

    def mission(self, *, passthrough: bool = True, **kw: Any) -> None:
        """A whole clean mission: every drone ready, started, the challenge, a passthrough
        each, End_Mission each. ``kw`` goes to every command's :meth:`exchange`."""
        for d in self.drones:
            self.ready(d)
        for d in self.drones:
            self.start(d, **kw)
        self.challenge_steps(**kw)
        if passthrough:
            for d in self.drones:
                self.passthrough(d, **kw)
        for d in self.drones:
            self.end(d, **kw)

    # ------------------------------------------------------------------ output
    def datagrams(self) -> list[Record]:
        return [r for r in self.records if r.event is None]

    def end_ns(self, tail: float = 10.0) -> int:
        return int(T0_NS + (self.t + tail) * NS)

    def monitor(self, *, complete: bool = True, declare: bool = True, **kw: Any) -> Monitor:
        return Monitor(rto=self.rto, ack_window=self.ack_window,
                       drones=self.drones if declare else None, challenge=self.challenge,
                       waypoints=self.items, complete=complete, **kw)

    def judge(self, monitor: Monitor | None = None, *, records: Iterable[Record] | None = None,
              tail: float = 10.0, **kw: Any) -> list[Any]:
        """Feed every record (sorted by time) to ``monitor`` (default :meth:`monitor`) and
        finish ``tail`` seconds after the last; returns every violation."""
        m = monitor if monitor is not None else self.monitor(**kw)
        out: list[Any] = []
        recs = sorted(self.records if records is None else records, key=lambda r: r.t_ns)
        for r in recs:
            if r.event is not None:
                out += m.vehicle(r.t_ns, r.drone, r.event)
            else:
                out += m.datagram(r.t_ns, r.src_addr, r.dst_addr, r.data, r.origin)
        out += m.finish(self.end_ns(tail))
        self.last_monitor = m
        return out

    def write_pcap(self, path: str | Path) -> Path:
        return write_pcap(path, self.datagrams())


def write_pcap(path: str | Path, records: Iterable[Record]) -> Path:
    """Write datagram records as a pcap (Ethernet/IPv4/UDP, loopback addresses) with scapy."""
    from scapy.layers.inet import IP, UDP
    from scapy.layers.l2 import Ether
    from scapy.packet import Raw
    from scapy.utils import wrpcap

    pkts = []
    for r in records:
        if r.event is not None or r.src_addr is None or r.dst_addr is None:
            continue
        p = (Ether(src="00:00:00:00:00:00", dst="ff:ff:ff:ff:ff:ff") / IP(src=r.src_addr[0], dst=r.dst_addr[0])
             / UDP(sport=r.src_addr[1], dport=r.dst_addr[1]) / Raw(load=r.data))
        p.time = r.t_ns / NS
        pkts.append(p)
    out = Path(path)
    wrpcap(str(out), pkts)
    return out


def clean_script(challenge: int = 1, drones: Iterable[int] = (1, 2), seed: int = 0, **kw: Any) -> Script:
    """A whole clean mission (see :meth:`Script.mission`)."""
    s = Script(drones, challenge=challenge, seed=seed, **kw)
    s.mission()
    return s


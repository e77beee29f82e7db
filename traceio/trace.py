"""A capture's datagrams as a conversation: who sent what to whom, copies and ACK pairing.

The view ``mcp-capture show``, the sequence charts and the HTML reports share. It names
nodes by MCP ID (the header's src and dst; manager 0, D-1's broadcast ID), never by address,
and learns each node's addresses from the datagrams it sent. It judges nothing (that is the
monitor's business, ``judge.monitor``); it only marks what a reader of the trace wants
to see at a glance:

- a copy: a unicast message with the (src, dst, seq) and bytes of an earlier one, i.e. a
  retransmission (MCP-RTX-1, MCP-SEQ-2: "A retransmission repeats the original's sequence
  number and bytes exactly");
- ACK pairing: an ACK from B to A carrying seq s answers A's latest copy of s to B
  ("replies are matched to requests by sequence number", D-6);
- unanswered: a copy of a unicast message that no ACK answered before the next copy or the
  end of the trace.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.spec import SPEC
from mcp_conform.spec.codec import (
    BROADCAST_ID,
    MANAGER_ID,
    Action,
    DecodeError,
    MissionItem,
    decode,
    peek_header,
)
from mcp_conform.spec.mavframe import FrameError, parse_frame
from mcp_conform.spec.profiles import MCP
from mcp_conform.traceio.reader import Datagram

__all__ = ["Entry", "Node", "Trace", "action_name", "describe_payload", "lifeline_of", "node_role"]

_ACK = int(Action.ACK)
_WILDCARD = ("", "0.0.0.0", "::")  # a socket bound to all addresses: no address of its own


_WIRE_NAMES = {a.code: a.wire_name for a in SPEC.actions}


def action_name(code: int | None) -> str:
    """The description's name of an action code (``WP_List``), from the spec."""
    if code is None:
        return "?"
    return _WIRE_NAMES.get(code, f"action {code}")


def node_role(node_id: int, broadcast_id: int = BROADCAST_ID) -> str:
    """The MCP role of the node with this ID (``spec.profiles``), or ``broadcast``."""
    return "broadcast" if node_id == broadcast_id else MCP.role_of_id(node_id).name


def _item(item: MissionItem) -> str:
    return f"#{item.seq} cmd {item.command} ({item.x:.6g}, {item.y:.6g}, {item.z:.6g})"


def describe_payload(msg: Any) -> str:
    """A short human-readable payload of a decoded :class:`spec.codec.Message`."""
    action, payload = msg.action, msg.payload
    if action == Action.ACK:
        return f"acks seq {payload}"
    if payload is None:
        return ""
    if action == Action.MISSION_READY:
        return f"id {payload}"
    if isinstance(payload, MissionItem):
        return _item(payload)
    if isinstance(payload, tuple):
        shown = ", ".join(_item(i) for i in payload[:3])
        more = f", +{len(payload) - 3} more" if len(payload) > 3 else ""
        return f"{len(payload)} item(s): {shown}{more}"
    if isinstance(payload, (bytes, bytearray)):
        try:
            frame = parse_frame(bytes(payload))
            return f"MAVLink {frame.get_type()} ({len(payload)} bytes)"
        except (FrameError, Exception):  # noqa: BLE001 - a description, never an error
            return f"{len(payload)} bytes"
    return repr(payload)


@dataclass(slots=True)
class Entry:
    """One datagram with what the trace says about it."""

    dgram: Datagram
    header: tuple[int, int, int, int] | None  # dst, src, seq, action (even when malformed)
    msg: Any  # spec.codec.Message, or None when it does not decode
    error: str | None  # "MCP-ROB-2: ..." when it does not decode
    src: str = "?"  # lifeline keys (see lifeline_of)
    dst: str = "?"
    copy: int = 0  # 0 the first send, k the k-th retransmission
    first: int | None = None  # index of the first copy, for a retransmission
    ack_of: int | None = None  # for an ACK: the index of the copy it answers
    acked_by: int | None = None  # for a unicast copy: the index of the ACK that answered it
    unanswered: bool = False
    violations: list[Any] = field(default_factory=list)

    @property
    def index(self) -> int:
        return self.dgram.index

    @property
    def label(self) -> str:
        """What a chart arrow says: action and seq."""
        if self.header is None:
            return f"{len(self.dgram.data)} bytes"
        label = f"{action_name(self.header[3])} #{self.header[2]}"
        if self.header[3] == _ACK and self.msg is not None:
            label += f" of {self.msg.payload}"  # the seq it acknowledges
        return label


@dataclass
class Node:
    id: int
    role: str
    addresses: set[tuple[str, int]] = field(default_factory=set)
    sent: int = 0
    received: int = 0
    sent_by_recorder: int = 0  # datagrams recorded as "tx": sent by the recording runner

    @property
    def is_runner(self) -> bool:
        """Every datagram of this ID came from the recording host (mcp-conform playing it)."""
        return self.sent > 0 and self.sent_by_recorder == self.sent

    def address_text(self) -> str:
        return ", ".join(f"{h}:{p}" for h, p in sorted(self.addresses)) or "-"

    def to_json(self) -> dict[str, Any]:
        return {"id": self.id, "role": self.role,
                "addresses": [f"{h}:{p}" for h, p in sorted(self.addresses)],
                "datagrams": {"sent": self.sent, "received": self.received}}


def lifeline_of(node_id: int | None, addr: tuple[str, int] | None) -> str:
    """The lifeline key: ``"0"``, ``"3"``, ``"65535"`` for MCP IDs, ``"host:port"`` else."""
    if node_id is not None:
        return str(node_id)
    return f"{addr[0]}:{addr[1]}" if addr else "?"


class Trace:
    """Entries of a list of datagrams, annotated (see the module docstring)."""

    def __init__(self, datagrams: Iterable[Datagram], broadcast_id: int = BROADCAST_ID) -> None:
        self.broadcast_id = broadcast_id
        self.entries: list[Entry] = []
        self.nodes: dict[int, Node] = {}
        self.by_index: dict[int, Entry] = {}
        self._positions: dict[int, int] | None = None  # index -> position in entries (around)
        for d in datagrams:
            self._add(d)
        self._pair()

    # ------------------------------------------------------------------ building
    def _node(self, node_id: int) -> Node:
        node = self.nodes.get(node_id)
        if node is None:
            node = self.nodes[node_id] = Node(node_id, node_role(node_id, self.broadcast_id))
        return node

    def _add(self, d: Datagram) -> None:
        msg = error = None
        try:
            msg = decode(d.data)
        except DecodeError as exc:
            error = f"{exc.rule}: {exc.reason}"
        header = (msg.dst, msg.src, msg.seq, int(msg.action)) if msg is not None else \
            peek_header(d.data, require_preamble=False)
        e = Entry(d, header, msg, error)
        if header is not None:
            dst, src, _seq, _action = header
            sender = self._node(src)
            sender.sent += 1
            if d.direction == "tx":
                sender.sent_by_recorder += 1
            if d.src_addr is not None:
                sender.addresses.add(d.src_addr)
            if dst != self.broadcast_id:
                self._node(dst).received += 1
            e.src, e.dst = str(src), str(dst)
        self.entries.append(e)
        self.by_index[d.index] = e

    def _owners(self) -> dict[tuple[str, int], str]:
        """Each address's node: the first (in order of appearance) that sent from it. One
        pass over the nodes, so naming a headerless datagram's ends is a lookup, not a scan
        of every node (a noisy capture's random headers make a node per datagram)."""
        owners: dict[tuple[str, int], str] = {}
        for node in self.nodes.values():
            for addr in node.addresses:
                owners.setdefault(addr, str(node.id))
        return owners

    def _pair(self) -> None:
        owners = self._owners()
        latest: dict[tuple[int, int, int], list[Entry]] = {}  # (src, dst, seq) -> its copies
        broadcasts: dict[tuple[int, int], Entry] = {}  # (src, seq) -> the latest broadcast
        for e in self.entries:
            if e.header is None:  # no header: lifelines by address, or the owner of it
                src_addr, dst_addr = e.dgram.src_addr, e.dgram.dst_addr
                e.src = (src_addr is not None and owners.get(src_addr)) or lifeline_of(None, src_addr)
                e.dst = (dst_addr is not None and owners.get(dst_addr)) or lifeline_of(None, dst_addr)
                continue
            if e.msg is None:
                continue
            dst, src, seq, action = e.header
            if action == _ACK:
                copies = latest.get((dst, src, e.msg.payload))
                if copies:
                    target = next((c for c in reversed(copies) if c.acked_by is None), copies[-1])
                    e.ack_of = target.index
                    if target.acked_by is None:
                        target.acked_by = e.index
                elif (dst, e.msg.payload) in broadcasts:  # an ACK of a broadcast (MCP-ACK-4's)
                    e.ack_of = broadcasts[(dst, e.msg.payload)].index
                continue
            if dst == self.broadcast_id:
                broadcasts[(src, seq)] = e
                continue
            key = (src, dst, seq)
            copies = latest.get(key)
            if copies and copies[0].dgram.data == e.dgram.data:
                e.copy, e.first = len(copies), copies[0].index
                copies.append(e)
            else:
                latest[key] = [e]
        for copies in latest.values():
            for c in copies:
                c.unanswered = c.acked_by is None

    # ------------------------------------------------------------------ views
    def mark(self, violations: Iterable[Any]) -> None:
        """Attach each violation to the datagrams of its evidence that its node sent (an ACK
        of a broadcast, not the broadcast it answers: MCP-ACK-4); to all of its evidence
        when the node sent none of it (a message it left unanswered, MCP-ACK-1)."""
        for v in violations:
            found = [e for e in (self.by_index.get(i) for i in evidence_indexes(v)) if e is not None]
            node = getattr(v, "node", None)
            own = [e for e in found if node is not None and e.header is not None and e.header[1] == node]
            for e in own or found:
                if v not in e.violations:
                    e.violations.append(v)

    def window(self, start_ns: int | None = None, end_ns: int | None = None) -> list[Entry]:
        return [e for e in self.entries
                if (start_ns is None or e.dgram.t_ns >= start_ns) and (end_ns is None or e.dgram.t_ns <= end_ns)]

    def around(self, indexes: Iterable[int], context: int = 4, limit: int = 60) -> list[Entry]:
        """Entries from a few before the first of ``indexes`` to a few after the last."""
        pos = self._positions
        if pos is None:  # once, not once per violation (an HTML report charts each)
            pos = self._positions = {e.index: n for n, e in enumerate(self.entries)}
        hit = sorted(pos[i] for i in indexes if i in pos)
        if not hit:
            return []
        lo, hi = max(0, hit[0] - context), min(len(self.entries), hit[-1] + context + 1)
        if hi - lo > limit:  # keep the evidence, drop the middle's context
            keep: set[int] = set()
            for h in hit:
                keep.update(range(max(lo, h - 2), min(hi, h + 3)))
            return [self.entries[n] for n in sorted(keep)][:limit]
        return self.entries[lo:hi]

    def lifelines(self, entries: Iterable[Entry]) -> list[str]:
        """Lifeline keys in a stable order: manager, drones by ID, broadcast, addresses."""
        keys = set()
        for e in entries:
            keys.add(e.src)
            keys.add(e.dst)

        def order(k: str) -> tuple[int, int, str]:
            if k.isdigit():
                n = int(k)
                return (2, n, k) if n == self.broadcast_id else (0 if n == MANAGER_ID else 1, n, k)
            return (3, 0, k)
        return sorted(keys, key=order)

    def lifeline_title(self, key: str) -> tuple[str, str]:
        """(title, subtitle) of a lifeline: "manager 0" and its addresses, ..."""
        if key.isdigit():
            n = int(key)
            if n == self.broadcast_id:
                return (f"broadcast {n}", "all drones")
            node = self.nodes.get(n)
            role = node_role(n, self.broadcast_id)
            if node is not None and node.is_runner:  # mcp-conform playing this ID
                return (f"runner as {role} {n}", "mcp-conform " + ", ".join(
                    f"{'' if h in _WILDCARD else h}:{p}" for h, p in sorted(node.addresses)))
            return (f"{role} {n}", node.address_text() if node else "-")
        return ("no MCP header", key)


def evidence_indexes(violation: Any) -> list[int]:
    """The datagram indexes of a violation's evidence (ints, or records with ``.index``)."""
    out = []
    for item in getattr(violation, "evidence", None) or ():
        if type(item) is tuple and item and type(item[0]) is int:  # the monitor's (index, t_ns): first
            out.append(item[0])
        elif isinstance(item, int):
            out.append(item)
        elif hasattr(item, "index") and isinstance(item.index, int):
            out.append(item.index)
        elif isinstance(item, dict) and isinstance(item.get("index"), int):
            out.append(item["index"])
        elif isinstance(item, (tuple, list)) and item and isinstance(item[0], int):
            out.append(item[0])
    return out

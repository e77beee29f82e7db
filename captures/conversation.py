"""A capture as MCP conversations: what ``mcp-capture diff`` and ``replay`` compare.

A *conversation* is the traffic between two MCP IDs (the manager 0 and a drone; a sender
and the broadcast ID), whatever addresses and ports carried it. Each is a sequence of
:class:`Entry` — one message as a protocol event: who sent it to whom, the action, the
decoded payload — with its retransmissions folded into a copy count.

Sequence numbers are normalised per sender: "initial values are arbitrary" (MCP-SEQ-4), so
a message's ``nseq`` is its seq minus the first seq that sender used in the capture (mod
2^16), and an ACK's payload is normalised with the numbering of the sender it acknowledges.
Entries are aligned on their ``key``, which holds no sequence number at all: a message by
its sender, receiver, action and decoded payload, an ACK by the key of the message it
acknowledges (None: no message of the conversation has that seq). So two recordings with
different initial seqs read the same, and one message more or less shifts nothing after it.
Whether the numbers themselves follow the rules is the monitor's question (MCP-SEQ-*).

Passthrough probe tokens are normalised the same way. A runner names each probe it sends
(``vehicle.probe``: a STATUSTEXT frame ``MCPPROBE:<token>`` in a Mav_Passthrough) so the
vehicle can count its deliveries; the name is the runner's, and part of it changes from run
to run: ``conformance.drone_case.Case.probe`` names a probe ``<case id>-<n>-<seq>``, the case's
n-th probe and the driver's next seq, which depends on how the cases of a batch interleaved
(``…-1-1323`` in one run, ``…-1-1322`` in the next). A probe's key holds no token but a
:class:`ProbeKey`: the token's *stem* (a runner's token without its seq: which case's which
probe; None for another naming) and the token's order of first appearance among the tokens
of that stem in its sender's stream of the conversation (#1, #2, ...; a token sent again is
the same number), with the frame's own header fields. So two runs agree, while a probe
repeated where the other run sent a new one, another case's probe, or a frame changed
otherwise still differs. The order is counted per stem, not over all of a sender's probes:
the cases of a batch run side by side, so which case's probe came first is a race. Only
frames exactly as ``vehicle.make_probe`` builds them are read this way; any other
passthrough payload is compared byte for byte.

ACKs of messages in flight together are put in the order of those messages. When the
runner's batch (``conformance._batch``) runs cases side by side, two of them may each send a
command to the node within a fraction of a millisecond, and which ACK leaves first is the
node's race (the reference drone ACKed the second of two such Mav_Passthroughs first in one
run of four): a run of one sender's ACKs with nothing else of the conversation between them,
each acknowledging a message sent before the run began, reads in the order of the messages
they acknowledge. An ACK sent before the next command, or one of nothing known, keeps its
place; how fast each came is the monitor's question (MCP-ACK-7).

Folding: a datagram that repeats the sender's latest entry in the conversation (same seq,
action and payload: a retransmission, MCP-RTX-1, or the ACK of one) adds a copy to that
entry instead of a new one. Malformed datagrams are entries too (action ``None``, their
``DecodeError`` rule as the payload, the raw bytes compared but for the seq field's), in the
conversation their header names, or in ``(None, None)`` when they have no whole header. A
header cut short keeps its seq field out too (bytes 13–14, as far as they go): the runner's
MCP-ROB-1 inputs include a header cut at 16 bytes (``spec.generators.malformed_corpus``)
numbered from the runner's counter, which the batch's other cases draw from meanwhile (two
whole-suite runs differed by that one byte).
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from functools import lru_cache
from typing import Any, NamedTuple

from mcp_conform.spec.codec import (
    BROADCAST_ID,
    HEADER_SIZE,
    Action,
    DecodeError,
    MissionItem,
    decode,
    peek_header,
)

__all__ = ["Conversation", "Entry", "ProbeKey", "build_conversations", "describe", "entry_fields",
           "peers_of", "peers_text", "probe_frame"]

Addr = tuple[str, int] | None
_ACK = Action.ACK
_PASSTHROUGH = int(Action.MAV_PASSTHROUGH)
#: conformance.drone_case.Case.probe's tokens: ``<case id tail>-<n>-<the driver's next seq>``
_RUNNER_TOKEN = re.compile(r"(.+-[0-9]+)-[0-9]+")
_NAMES = {int(a): a.name for a in Action}


class Entry(NamedTuple):
    """One message of a conversation, retransmissions folded in."""

    src: int | None
    dst: int | None
    action: int | None  # None: malformed
    nseq: int | None  # seq minus the sender's first seq (mod 2^16)
    payload: Any  # decoded payload; an ACK's normalised seq; a malformed datagram's rule
    key: tuple[Any, ...]  # what alignment compares: sender, receiver, action, content (no seq)
    copies: int
    t_ns: int  # first copy
    t_last_ns: int  # last copy
    src_addr: Addr
    dst_addr: Addr
    index: int  # type: ignore[assignment]  # the first copy's datagram index in its capture
    seq: int | None  # the wire seq, not normalised
    data: bytes  # the first copy's bytes


class ProbeKey(NamedTuple):
    """What a passthrough probe's key holds instead of its frame (module docstring)."""

    stem: str | None  # a runner's token without its run-dependent seq; None: another naming
    ordinal: int  # the token's order of first appearance among its stem's: 1, 2, ...
    version: int  # MAVLink 1 or 2
    sysid: int
    compid: int
    mavseq: int  # the frame's own sequence byte


@lru_cache(maxsize=4096)
def probe_frame(frame: bytes) -> tuple[str, int, int, int, int] | None:
    """``(token, version, sysid, compid, mavseq)`` of a probe frame exactly as
    ``vehicle.make_probe`` builds it (so those fields say everything the bytes say), else None."""
    from mcp_conform.spec.mavframe import FrameError, parse_frame
    from mcp_conform.vehicle.probe import PROBE_PREFIX, make_probe, probe_token

    if PROBE_PREFIX.encode() not in frame:
        return None
    try:
        msg = parse_frame(frame)
    except FrameError:
        return None
    token = probe_token(msg.text) if msg.get_type() == "STATUSTEXT" else None
    if token is None:
        return None
    h = msg.get_header()
    version = 2 if frame[0] == 0xFD else 1
    try:
        canonical = make_probe(token, h.srcSystem, h.srcComponent, h.seq, version=version)
    except ValueError:
        return None
    return (token, version, h.srcSystem, h.srcComponent, h.seq) if canonical == frame else None


class Conversation(NamedTuple):
    peers: tuple[Any, Any]  # (lower ID, higher ID); broadcast as BROADCAST_ID
    entries: list[Entry]


def peers_of(src: int | None, dst: int | None) -> tuple[Any, Any]:
    if src is None or dst is None:
        return (None, None)
    return (src, dst) if src <= dst else (dst, src)


def build_conversations(datagrams: Iterable[Any]) -> tuple[dict[tuple[Any, Any], Conversation], int]:
    """Fold datagrams (objects with ``index``, ``t_ns``, ``src_addr``, ``dst_addr``,
    ``data``) into conversations; also returns the first datagram's ``t_ns`` (0 if none)."""
    convs: dict[tuple[Any, Any], Conversation] = {}
    first_seq: dict[int, int] = {}
    latest: dict[tuple[Any, Any], tuple[int, tuple[Any, ...]]] = {}  # (peers, sender) -> (pos, fold key)
    by_seq: dict[tuple[Any, Any, int], int] = {}  # (peers, sender, seq) -> entry position
    tokens: dict[tuple[Any, ...], dict[str, int]] = {}  # (peers, sender, stem) -> token -> ordinal
    acks: dict[tuple[Any, Any], dict[int, int]] = {}  # peers -> ACK's position -> acknowledged's
    t0: int | None = None
    ack_of: int | None = None  # an ACK's acknowledged entry
    payload: Any
    key: tuple[Any, ...]
    _decode, _peek = decode, peek_header
    for d in datagrams:
        data = d.data
        if t0 is None:
            t0 = d.t_ns
        try:
            msg = _decode(data)
        except DecodeError as exc:
            header = _peek(data, require_preamble=False)
            if header is None:  # no whole header: where a seq would be is still the runner's
                src = dst = seq = nseq = None
                rest = data[:13] + data[15:]
            else:
                dst, src, seq, _action = header
                nseq = (seq - first_seq.setdefault(src, seq)) & 0xFFFF
                rest = data[:13] + data[15:]  # all but the seq field
            action = None
            payload = exc.rule
            peers = peers_of(src, dst)
            key = (src, dst, None, payload, rest)
            fold: tuple[Any, ...] = key
        else:
            src, dst, seq, action = msg.src, msg.dst, msg.seq, int(msg.action)
            nseq = (seq - first_seq.setdefault(src, seq)) & 0xFFFF
            payload = msg.payload
            peers = peers_of(src, dst)
            if action == _ACK:
                acked = payload
                base = first_seq.get(dst)
                payload = ("?", acked) if base is None else (acked - base) & 0xFFFF
                pos = by_seq.get((peers, dst, acked))
                ack_of = pos
                conv = convs.get(peers)
                what = conv.entries[pos].key if (pos is not None and conv is not None) else None
                if what is not None and what[2] == _ACK:  # an ACK is never ACKed: one that names an
                    pos = ack_of = what = None  # ACK's number names nothing, as one naming no message
                key = (src, dst, action, ("ack", what))
                fold = (src, dst, action, acked)
            else:
                content = payload
                if action == _PASSTHROUGH and isinstance(payload, bytes):
                    probe = probe_frame(payload)
                    if probe is not None:
                        token = probe[0]
                        runner = _RUNNER_TOKEN.fullmatch(token)
                        stem = runner.group(1) if runner else None
                        names = tokens.setdefault((peers, src, stem), {})
                        content = ProbeKey(stem, names.setdefault(token, len(names) + 1), *probe[1:])
                key = (src, dst, action, content)
                fold = (src, dst, action, seq, payload)
        conv = convs.get(peers)
        if conv is None:
            conv = convs[peers] = Conversation(peers, [])
        entries = conv.entries
        last = latest.get((peers, src))
        if last is not None and last[1] == fold:
            e = entries[last[0]]
            entries[last[0]] = e._replace(copies=e.copies + 1, t_last_ns=d.t_ns)
            continue
        pos = len(entries)
        latest[(peers, src)] = (pos, fold)
        if seq is not None:
            by_seq[(peers, src, seq)] = pos
        if action == _ACK and ack_of is not None:
            acks.setdefault(peers, {})[pos] = ack_of
        entries.append(Entry(src, dst, action, nseq, payload, key, 1, d.t_ns, d.t_ns,
                             d.src_addr, d.dst_addr, d.index, seq, data))
    for peers, acked in acks.items():
        _order_acks_in_flight(convs[peers].entries, acked)
    return convs, (t0 or 0)


def _order_acks_in_flight(entries: list[Entry], acked: dict[int, int]) -> None:
    """Each run of one sender's consecutive ACKs, all of messages sent before the run, in the
    order of those messages (module docstring)."""
    i, n = 0, len(entries)
    while i < n:
        e = entries[i]
        j = i + 1
        if i in acked and acked[i] < i:
            while (j < n and j in acked and acked[j] < i and entries[j].src == e.src
                   and entries[j].dst == e.dst):
                j += 1
            if j - i > 1:
                run = sorted(range(i, j), key=acked.__getitem__)
                entries[i:j] = [entries[k] for k in run]
        i = j


def _name(action: int | None) -> str:
    return "malformed" if action is None else _NAMES.get(action, str(action))


def _item_text(item: MissionItem) -> str:
    return f"#{item.seq} cmd {item.command} ({item.x:.6f}, {item.y:.6f}, {item.z:g})"


def describe(e: Entry | None, broadcast_id: int = BROADCAST_ID) -> str:
    """One line: ``0→1 WP_LIST seq+2 [3 items] ×2``."""
    if e is None:
        return "(nothing)"
    dst = "*" if e.dst == broadcast_id else e.dst
    head = f"{e.src}→{dst} {_name(e.action)}"
    if e.nseq is not None and e.action != _ACK:
        head += f" seq+{e.nseq}"
    p = e.payload
    if e.action is None:
        body = f" {p} ({len(e.data)} B)"
    elif e.action == _ACK:
        what = e.key[3][1]  # the acknowledged message's key
        body = (f" of seq+{p}" if isinstance(p, int) else f" of seq {p[1]}") + \
            (f" ({_name(what[2])})" if what is not None else " (no such message)")
    elif isinstance(p, MissionItem):
        body = f" {_item_text(p)}"
    elif isinstance(e.key[3], ProbeKey):
        probe = e.key[3]
        body = f" probe {probe.stem + ' ' if probe.stem else ''}#{probe.ordinal}"
    elif isinstance(p, tuple):
        body = f" [{len(p)} items]"
    elif isinstance(p, bytes):
        body = f" [{len(p)}-byte MAVLink frame]"
    elif p is not None:
        body = f" {p}"
    else:
        body = ""
    copies = f" ×{e.copies}" if e.copies > 1 else ""
    return head + body + copies


def entry_fields(e: Entry) -> dict[str, Any]:
    """The comparable fields of an entry, flattened (``payload.items[2].x``)."""
    out: dict[str, Any] = {"src": e.src, "dst": e.dst, "action": _name(e.action), "seq": e.nseq}
    p = e.payload
    if isinstance(p, MissionItem):
        for k, v in p._asdict().items():
            out[f"payload.{k}"] = v
    elif isinstance(p, tuple) and p and isinstance(p[0], MissionItem):
        out["payload.count"] = len(p)
        for i, item in enumerate(p):
            for k, v in item._asdict().items():
                out[f"payload.items[{i}].{k}"] = v
    elif isinstance(p, tuple) and not p:
        out["payload.count"] = 0
    elif isinstance(e.key[3], ProbeKey):
        for k, v in e.key[3]._asdict().items():
            out[f"payload.probe.{k}"] = v
        found = probe_frame(p)
        out["token"] = found[0] if found else None  # shown, not compared (module docstring)
    elif isinstance(p, bytes):
        out["payload"] = p.hex()
    else:
        out["payload"] = p if not isinstance(p, tuple) else list(p)
    if e.action is None:
        out["bytes"] = e.data[HEADER_SIZE:].hex() if len(e.data) >= HEADER_SIZE else e.data.hex()
    return out


def peers_text(peers: tuple[Any, Any]) -> str:
    """A conversation's two MCP IDs as text (``0 ↔ 1``, ``0 ↔ broadcast``)."""
    from mcp_conform.spec.codec import BROADCAST_ID

    if peers == (None, None):
        return "datagrams without an MCP header"
    a, b = peers
    return f"{a} ↔ {'broadcast' if b == BROADCAST_ID else b}"

"""Reply attribution: which command a datagram from the node answers.

A reply is first tied to a command by what it is, then its form is judged, so one fault is
reported under the one rule it breaks (MCP-ACK-1 only when the node sent nothing the runner
can attribute; a wrong payload is MCP-ACK-2's, a wrong dst or src MCP-ACK-3's). An
ACK-like datagram (a whole header with the ACK action code, well-formed or not) arriving at
the runner is attributed, in this order:

1. **by seq**: its payload names, big-endian (as MCP-ACK-2 wants), the seq of a command
   with a copy not yet answered, sent recently (within three horizons of its last copy for a
   command the node should answer, one for a datagram a silence check watches, so a node's
   arbitrary payload is not taken for the ACK of an old broadcast); the latest such wins;
2. **by seq, little-endian**: the same with the two payload bytes swapped;
3. **by timing**: it names no such command, and arrived after the latest command and before
   any other was sent (ACKs the runner sends do not count), and that command has a copy not
   yet answered. The attribution says what the payload named instead ("seq 1311 (0x051f),
   an earlier command's, already answered").

A command is "open" while fewer replies were attributed to it than copies of it were sent,
so a correct node's ACK of every copy is always attributed by seq, and a stale seq (a node
that names the previous command) is never taken for an ACK of that earlier command. A timing
attribution is **ambiguous** when another command the node should answer (well-formed, to
its ID, not an ACK) is open and had a copy sent within the horizon (the larger of --rto
and the ACK window) before the reply: the reply could be that command's late answer. The
ambiguity is stated, never resolved by guessing: the ACK cases do not judge the form of an
ambiguous reply; liveness (any attributable reply) accepts it.

Sans-I/O: the driver feeds it every datagram sent and received, in order, under its lock.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Protocol

from mcp_conform.spec.codec import (
    BROADCAST_ID,
    HEADER_SIZE,
    Action,
    DecodeError,
    decode,
    peek_header,
)

_ACK = int(Action.ACK)
_U16BE = struct.Struct("!H")
_U16LE = struct.Struct("<H")

#: Commands remembered (the older half is forgotten beyond this) and how far back, in
#: horizons, the ambiguity check looks for another unanswered command.
MAX_COMMANDS = 20_000
SCAN_HORIZONS = 10

BY_SEQ = "seq"
BY_SEQ_LE = "seq-le"
BY_TIMING = "timing"


class _SentLike(Protocol):
    @property
    def t(self) -> float: ...

    @property
    def data(self) -> bytes: ...

    @property
    def dst(self) -> int: ...

    @property
    def src(self) -> int: ...

    @property
    def seq(self) -> int: ...

    @property
    def action(self) -> int: ...


class _ReceivedLike(Protocol):
    @property
    def t(self) -> float: ...

    @property
    def data(self) -> bytes: ...

    @property
    def header(self) -> tuple[int, int, int, int] | None: ...


@dataclass(frozen=True)
class Attribution:
    """Which command (its id: the index of its first copy among the runner's sends) a reply
    answers, how that was decided, and what makes it uncertain."""

    command: int
    seq: int  # the command's seq
    how: str  # BY_SEQ, BY_SEQ_LE or BY_TIMING
    named: str  # what the reply's payload names, in words
    ambiguous: str | None = None  # why the reply could answer another command

    def describe(self) -> str:
        how = {BY_SEQ: "its payload names the command's seq",
               BY_SEQ_LE: "its payload names the command's seq little-endian",
               BY_TIMING: "it arrived after the command and before any other was sent"}[self.how]
        text = f"attributed to seq {self.seq}: {how}"
        if self.how == BY_TIMING:
            text += f" (its payload names {self.named})"
        if self.ambiguous:
            text += f"; ambiguous: {self.ambiguous}"
        return text


@dataclass
class _Command:
    id: int
    seq: int
    src: int
    dst: int
    expects_reply: bool  # a correct node ACKs it (well-formed, to the node's ID, not an ACK)
    is_ack: bool
    copies: list[float] = field(default_factory=list)  # send times
    answers: int = 0  # replies attributed to it
    live: bool = True  # in ``Attributor._live``: a reply may still name it (``Attributor._named_by``)

    def open_at(self, t: float) -> bool:
        """A copy sent by ``t`` has no reply attributed to it yet."""
        return sum(1 for c in self.copies if c <= t) > self.answers

    def recent(self, t: float, horizon: float) -> bool:
        """Could a reply at ``t`` still answer it? A command the node should answer stays
        answerable for 3 horizons after its last copy (a node may be deaf while busy, D-6);
        one it should not answer (a silence check) for one horizon, the window it is watched."""
        return t - self.copies[-1] <= (3 * horizon if self.expects_reply else horizon)


def payload_seq(data: bytes, order: struct.Struct = _U16BE) -> int | None:
    """The seq an ACK-like datagram's first two payload bytes name (None when shorter)."""
    return order.unpack_from(data, HEADER_SIZE)[0] if len(data) >= HEADER_SIZE + 2 else None


class Attributor:
    """Incremental attribution of replies to the runner's commands (see the module doc)."""

    def __init__(self, our_id: int = 0, *, horizon: float = 2.0, peer_id: int | None = None) -> None:
        self.our_id = our_id
        self.horizon = horizon  # --rto or the ACK window, the larger (set by the session)
        self.peer_id = peer_id  # the node's MCP ID, once known
        self.broadcast_id = BROADCAST_ID  # the run's (--broadcast-id), set by the session
        self._commands: list[_Command] = []
        self._by_tx: dict[int, _Command] = {}  # tx index of each copy -> its command
        self._by_seq: dict[int, list[_Command]] = {}
        #: per seq, the commands of ``_by_seq`` a reply may still name (``_named_by``): a fuzz
        #: campaign's programs send hundreds of commands with each seq near the wrap (65535,
        #: 0, 1, ...), and scanning them all for each ACK took as much CPU as the campaign's
        #: cases (``_named_by`` drops the ones that can no longer be named)
        self._live: dict[int, list[_Command]] = {}
        self._dropped_t = float("-inf")  # the latest reply time at which ``_named_by`` dropped one
        self._dropped_h = float("inf")  # the shortest horizon it dropped one at
        self._latest: _Command | None = None  # the latest non-ACK datagram sent

    # ------------------------------------------------------------------ input
    def sent(self, tx_index: int, sent: _SentLike, copy_of: int | None = None) -> int:
        """Note one datagram the runner sent; returns its command id (``copy_of``'s for a
        retransmission, else ``tx_index``)."""
        cmd = self._by_tx.get(copy_of) if copy_of is not None else None
        if cmd is None:
            is_ack = sent.action == _ACK
            dst, src, seq = sent.dst, sent.src, sent.seq
            if seq < 0:  # a malformed input (a bad preamble): a node may still ACK its seq
                hdr = peek_header(sent.data, require_preamble=False)
                if hdr is not None:
                    dst, src, seq, _ = hdr
            cmd = _Command(tx_index, seq, src, dst, self._expects_reply(sent, is_ack), is_ack)
            self._commands.append(cmd)
            if seq >= 0:
                self._by_seq.setdefault(seq, []).append(cmd)
                self._live.setdefault(seq, []).append(cmd)
            if len(self._commands) > MAX_COMMANDS:
                self._forget_oldest()
        cmd.copies.append(sent.t)
        self._relive(cmd)
        self._by_tx[tx_index] = cmd
        if not cmd.is_ack:
            self._latest = cmd
        return cmd.id

    def on_wire(self, tx_index: int, t: float, delays: Sequence[float]) -> None:
        """The runner's own impaired link (``--impair``) on copy ``tx_index``, sent at ``t``:
        the copies of it that left, each ``delay`` s later -- none when the link dropped it,
        two when it duplicated it. A command is open while fewer replies were attributed to it
        than copies of it reached the node's side, so a dropped copy is owed no reply: the
        runner's link knows what it made (issue 38), as a node on it cannot."""
        cmd = self._by_tx.get(tx_index)
        if cmd is None or t not in cmd.copies:
            return
        cmd.copies.remove(t)
        cmd.copies.extend(t + d for d in delays)
        cmd.copies.sort()
        self._relive(cmd)

    def received(self, d: _ReceivedLike) -> Attribution | None:
        """Attribute one datagram that arrived (None: not ACK-like, or nothing to tie it to)."""
        if d.header is None or d.header[3] != _ACK:
            return None
        cmd: _Command | None
        for how, order in ((BY_SEQ, _U16BE), (BY_SEQ_LE, _U16LE)):
            seq = payload_seq(d.data, order)
            if seq is None:
                break
            cands = [c for c in self._named_by(seq, d.t)
                     if c.open_at(d.t) and c.recent(d.t, self.horizon) and self._addressed(c, d)]
            if cands:  # the one sent from the src the reply is addressed to, else the latest
                cmd = max(cands, key=lambda c: (c.src == d.header[0], c.id))  # type: ignore[index]  # header: not None (above)
                cmd.answers += 1
                return Attribution(cmd.id, cmd.seq, how, self._named(d, cmd))
        cmd = self._latest
        if cmd is None or not cmd.open_at(d.t):
            return None
        cmd.answers += 1
        others = []
        for c in reversed(self._commands):  # newest first; stop long before the horizon
            if not c.copies:
                continue  # every copy dropped by the runner's own link: nothing to answer
            if d.t - c.copies[0] > SCAN_HORIZONS * self.horizon:
                break
            if c is not cmd and c.expects_reply and c.open_at(d.t) and d.t - c.copies[-1] <= self.horizon:
                others.append(c)
        others.reverse()
        ambiguous = None
        if others:
            seqs = ", ".join(str(c.seq) for c in others[-3:])
            ambiguous = (f"command(s) with seq {seqs}, sent less than {self.horizon:g} s earlier, "
                         "were also unanswered, and the payload names none of them")
        return Attribution(cmd.id, cmd.seq, BY_TIMING, self._named(d, cmd), ambiguous)

    def answerable_until(self, now: float) -> float:
        """When the last command with a copy still unanswered stops being answerable (a reply
        until then may still be tied to it by its seq: ``_Command.recent``); ``now`` when none
        is. The runner's schedule waits for it before it runs a thrown-away batch's cases
        again, as a serial run's next case meets only answered or expired commands."""
        end = now
        for c in self._commands[-2000:]:
            if c.copies and c.open_at(now) and c.recent(now, self.horizon):
                end = max(end, c.copies[-1] + (3 * self.horizon if c.expects_reply else self.horizon))
        return end

    # ------------------------------------------------------------------ helpers
    def _named_by(self, seq: int, t: float) -> Sequence[_Command]:
        """The commands with ``seq`` a reply at ``t`` may be tied to by seq: every one of
        ``_by_seq`` but those dropped here, which no reply at ``t`` or later can be tied to
        while their copies stay as they are (every copy answered: ``open_at`` is False
        whatever the time; no copy within its horizon by ``t``: ``recent`` is False at every
        later time, the horizon no larger). A new copy puts a command back (``_relive``: a
        retransmission, the runner's link's copies); a reply time before the latest drop, or a
        horizon grown since, is answered from every command, as before the drops."""
        if self.horizon > self._dropped_h:  # every command back: a drop was for a shorter horizon
            self._dropped_h, self._dropped_t = float("inf"), float("-inf")
            self._live = {s: list(cmds) for s, cmds in self._by_seq.items()}
            for c in self._commands:
                c.live = True
        if t < self._dropped_t:
            return self._by_seq.get(seq, ())
        live = self._live.get(seq, [])
        keep = [c for c in live if c.copies and len(c.copies) > c.answers and c.recent(t, self.horizon)]
        if len(keep) < len(live):
            for c in live:
                c.live = False
            for c in keep:
                c.live = True
            self._live[seq] = keep
            self._dropped_t, self._dropped_h = max(self._dropped_t, t), min(self._dropped_h, self.horizon)
        return keep

    def _relive(self, cmd: _Command) -> None:
        """``cmd``'s copies changed: a reply may name it again (``_named_by``)."""
        if not cmd.live and cmd.seq >= 0:
            cmd.live = True
            self._live.setdefault(cmd.seq, []).append(cmd)

    def _forget_oldest(self) -> None:
        """Keep memory and lookups bounded on long runs (a fuzz campaign): the older half of
        the commands can no longer be answered (they are far beyond every horizon)."""
        keep = self._commands[len(self._commands) // 2:]
        ids = {id(c) for c in keep}
        self._commands = keep
        self._by_tx = {i: c for i, c in self._by_tx.items() if id(c) in ids}
        self._by_seq = {}
        for c in keep:
            if c.seq >= 0:
                self._by_seq.setdefault(c.seq, []).append(c)
        self._live = {s: [c for c in cmds if c.live] for s, cmds in self._by_seq.items()}

    def _expects_reply(self, sent: _SentLike, is_ack: bool) -> bool:
        if is_ack or sent.dst == self.broadcast_id:
            return False
        if self.peer_id is not None and sent.dst != self.peer_id:
            return False
        try:
            decode(sent.data)
        except DecodeError:
            return False
        return True

    def _addressed(self, cmd: _Command, d: _ReceivedLike) -> bool:
        """An ACK of a command sent under another src must be addressed to that src (so two
        sources' equal seqs are told apart); for the runner's own src the dst is MCP-ACK-3's."""
        assert d.header is not None
        return cmd.src == self.our_id or d.header[0] == cmd.src

    def _named(self, d: _ReceivedLike, cmd: _Command) -> str:
        """What the payload names, in words, relative to ``cmd``."""
        payload = d.data[HEADER_SIZE:]
        if len(payload) != 2:
            return f"nothing: {len(payload)} payload bytes ({payload[:8].hex(' ') or 'empty'})"
        seq = _U16BE.unpack(payload)[0]
        text = f"seq {seq} (0x{seq:04x})"
        if seq == cmd.seq:
            return text + ", the command's seq"
        if _U16LE.unpack(payload)[0] == cmd.seq:
            return text + ", the command's seq in little-endian order"
        assert d.header is not None
        if seq in (d.header[2], (d.header[2] + 1) & 0xFFFF):
            return text + ", the node's own sequence number"
        earlier = [c for c in self._by_seq.get(seq, ()) if c is not cmd]
        if earlier:
            return text + ", an earlier command's, already answered"
        return text + ", which no command of the runner carried"

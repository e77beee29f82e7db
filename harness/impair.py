"""A bad link on demand: a seeded, sans-I/O impairment schedule (issue 22).

MCP exists because radio links lose, duplicate and reorder datagrams; retransmission until
ACK plus duplicate discard must turn such a link into exactly-once delivery. An
:class:`Impairment` decides, for each datagram of each direction, what the link does to it:

- ``loss`` — dropped with probability p (independent losses);
- ``burst`` — Gilbert–Elliott burst loss ``P_GB/P_BG[/LOSS_BAD]``: a two-state chain, good
  (no loss but ``loss``) and bad (loss ``LOSS_BAD``, default 1), entered with probability
  ``P_GB`` per datagram and left with ``P_BG``;
- ``dup`` — duplicated with probability p (``copies`` extra copies, default 1);
- ``delay`` — every copy delayed by a uniform draw in ``LO-HI`` (``0-50ms``; jitter);
- ``reorder`` — with probability p a copy is held back past the delay range (``HI`` plus up to
  ``HI`` more, at least 10 ms), so datagrams sent after it arrive first;
- ``corrupt`` — with probability p one to three bit flips, or (one time in four) a cut:
  the datagram truncated to a random shorter length;
- ``rate`` — a rate limit in datagrams per second per direction (``rate=200``): a datagram
  that would exceed it is dropped (a full queue).

The syntax is one string everywhere (``--impair``): ``loss=0.3,dup=0.1,reorder=0.2,
delay=0-50ms,corrupt=0.01,burst=0.05/0.3,rate=500,seed=7``; :func:`parse_impairment` says in
one line what is wrong with a bad one.

Same seed and same traffic, same decisions — and the same decision for a datagram whatever
the host's timing did around it. A datagram's decision is drawn from a random stream seeded
from ``seed``, the direction's name and the datagram's *identity* in its direction, never
from the wall clock (only ``rate`` looks at the times given, and the Gilbert–Elliott chain at
the order of the datagrams). The identity is protocol-aware, read from the MCP header
(``spec.codec.peek_header``): an ACK is "the c-th ACK naming the r-th distinct seq this
direction ACKed", any other message "the c-th copy of the r-th distinct message of its action
code", anything else "the c-th copy of these bytes". So a retransmission timer that fires once
more on a loaded host (one more copy, one more ACK of it) shifts nothing for the other
datagrams, a node's random initial seq (MCP-SEQ-4) changes nothing, and a soak mission's seed
replays its failure.

A link holds delayed copies in a :class:`DelayQueue` with a cap, in copies and in bytes (each
copy charged its length plus the queue's own bookkeeping): past it a copy is dropped, as a full
router buffer drops, and the drop is counted and recorded (``dropped="queue"``). Without a cap a
60 s delay with duplication under a flood grew ``mcp-impair`` by ~120 MB/s."""

from __future__ import annotations

import dataclasses
import hashlib
import heapq
import itertools
import random
import re
from collections import OrderedDict, deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Generic, TypeVar

from mcp_conform.spec.codec import HEADER_SIZE, Action, peek_header

T = TypeVar("T")

__all__ = ["DelayQueue", "Decision", "Delivery", "Impairment", "ImpairmentError", "ImpairSpec",
           "parse_impairment"]


class ImpairmentError(ValueError):
    """A bad impairment spec (one line, names the key)."""


@dataclass(frozen=True)
class ImpairSpec:
    """What the link does, as parsed from ``loss=...,seed=N`` (all probabilities 0..1)."""

    loss: float = 0.0
    dup: float = 0.0
    copies: int = 1
    reorder: float = 0.0
    delay_lo_s: float = 0.0
    delay_hi_s: float = 0.0
    corrupt: float = 0.0
    burst_gb: float = 0.0  # Gilbert-Elliott: good -> bad per datagram
    burst_bg: float = 0.0  # bad -> good
    burst_loss: float = 1.0  # loss in the bad state
    rate: float | None = None  # datagrams per second per direction
    seed: int = 0

    @property
    def active(self) -> bool:
        return any((self.loss, self.dup, self.reorder, self.delay_hi_s, self.corrupt,
                    self.burst_gb, self.rate is not None))

    def text(self) -> str:
        """The spec back as its one-string form (what a reproducing command repeats)."""
        parts = []
        for key, value in (("loss", self.loss), ("dup", self.dup), ("reorder", self.reorder),
                           ("corrupt", self.corrupt)):
            if value:
                parts.append(f"{key}={value:g}")
        if self.dup and self.copies != 1:
            parts.append(f"copies={self.copies}")
        if self.delay_hi_s:
            parts.append(f"delay={self.delay_lo_s * 1000:g}-{self.delay_hi_s * 1000:g}ms")
        if self.burst_gb:
            parts.append(f"burst={self.burst_gb:g}/{self.burst_bg:g}/{self.burst_loss:g}")
        if self.rate is not None:
            parts.append(f"rate={self.rate:g}")
        parts.append(f"seed={self.seed}")
        return ",".join(parts)


_PROB_KEYS = ("loss", "dup", "reorder", "corrupt")
_KEYS = (*_PROB_KEYS, "copies", "delay", "burst", "rate", "seed")
_DURATION = re.compile(r"^\s*([0-9]*\.?[0-9]+)\s*(ms|s)?\s*$")


def _prob(key: str, text: str) -> float:
    try:
        p = float(text)
    except ValueError:
        raise ImpairmentError(f"--impair: {key}={text!r} is not a number") from None
    if not 0.0 <= p <= 1.0:
        raise ImpairmentError(f"--impair: {key}={text} is not a probability 0..1")
    return p


def _seconds(key: str, text: str) -> float:
    m = _DURATION.match(text)
    if m is None:
        raise ImpairmentError(f"--impair: {key}: {text!r} is not a duration (50ms, 0.05s)")
    value = float(m.group(1))
    return value / 1000.0 if m.group(2) in (None, "ms") else value


def parse_impairment(text: str) -> ImpairSpec:
    """``loss=0.3,dup=0.1,reorder=0.2,delay=0-50ms,seed=7`` -> :class:`ImpairSpec`, or
    :class:`ImpairmentError` naming what is wrong."""
    values: dict[str, Any] = {}
    if not text or not text.strip():
        raise ImpairmentError("--impair: empty; e.g. loss=0.3,dup=0.1,reorder=0.2,delay=0-50ms,seed=7")
    for word in text.split(","):
        key, sep, value = word.strip().partition("=")
        key = key.strip().lower()
        if not sep or not value.strip():
            raise ImpairmentError(f"--impair: {word.strip()!r} is not KEY=VALUE")
        if key in values:
            raise ImpairmentError(f"--impair: {key} given twice")
        value = value.strip()
        if key in _PROB_KEYS:
            values[key] = _prob(key, value)
        elif key == "copies":
            if not value.isdigit() or not 1 <= int(value) <= 10:
                raise ImpairmentError(f"--impair: copies={value!r} is not 1..10")
            values[key] = int(value)
        elif key == "delay":
            lo, dash, hi = value.partition("-")
            if dash and _DURATION.match(lo) and not lo.strip().endswith("s"):
                m = _DURATION.match(hi)  # "0-50ms": the low end takes the high end's unit
                lo += (m.group(2) or "ms") if m else ""
            lo_s = _seconds("delay", lo)
            hi_s = _seconds("delay", hi) if dash else lo_s
            if hi_s < lo_s or hi_s > 60:
                raise ImpairmentError(f"--impair: delay={value}: LO-HI with LO <= HI <= 60 s")
            values["delay_lo_s"], values["delay_hi_s"] = lo_s, hi_s
        elif key == "burst":
            parts = value.split("/")
            if len(parts) not in (2, 3):
                raise ImpairmentError(f"--impair: burst={value}: P_GB/P_BG[/LOSS_BAD] (e.g. 0.05/0.3)")
            values["burst_gb"] = _prob("burst P_GB", parts[0])
            values["burst_bg"] = _prob("burst P_BG", parts[1])
            if len(parts) == 3:
                values["burst_loss"] = _prob("burst LOSS_BAD", parts[2])
            if values["burst_gb"] > 0 and values["burst_bg"] == 0:
                raise ImpairmentError(f"--impair: burst={value}: P_BG 0 would never leave the bad state")
        elif key == "rate":
            try:
                rate = float(value.removesuffix("/s"))
            except ValueError:
                raise ImpairmentError(f"--impair: rate={value!r} is not datagrams per second") from None
            if not rate > 0:
                raise ImpairmentError(f"--impair: rate={value}: must be > 0")
            values["rate"] = rate
        elif key == "seed":
            try:
                values["seed"] = int(value, 0)
            except ValueError:
                raise ImpairmentError(f"--impair: seed={value!r} is not an integer") from None
        else:
            raise ImpairmentError(f"--impair: unknown key {key!r}; keys: {', '.join(_KEYS)}")
    return ImpairSpec(**values)


@dataclass(frozen=True)
class Delivery:
    """One copy to deliver ``delay_s`` after the datagram reached the link."""

    delay_s: float
    data: bytes
    kinds: tuple[str, ...] = ()  # what was done to this copy: dup, delay, reorder, corrupt, cut


@dataclass(frozen=True)
class Decision:
    """What the link did to datagram number ``n`` of ``direction``: its copies (none:
    dropped, and ``dropped`` says why: loss, burst or rate). ``dropped="queue"``: the link's
    :class:`DelayQueue` was full and refused copies; the ones it held are still listed."""

    direction: str
    n: int
    size: int
    deliveries: tuple[Delivery, ...]
    dropped: str | None = None

    @property
    def kinds(self) -> tuple[str, ...]:
        """Every kind of impairment applied (``drop:loss`` for a drop), for counting."""
        out = [f"drop:{self.dropped}"] if self.dropped else []
        for d in self.deliveries:
            out.extend(d.kinds)
        return tuple(out)

    def to_json(self) -> dict[str, Any]:
        return {"direction": self.direction, "n": self.n, "size": self.size, "dropped": self.dropped,
                "deliveries": [{"delay_ms": round(d.delay_s * 1000, 3), "size": len(d.data),
                                "kinds": list(d.kinds)} for d in self.deliveries]}


#: how many distinct messages a direction remembers the rank and copy count of (least
#: recently seen forgotten first): a retransmission follows its original within a few
#: timeouts, and a flood of distinct datagrams does not grow the memory
COPY_MEMORY = 4096
_ACK = int(Action.ACK)


def _identity(data: bytes) -> tuple[str, bytes]:
    """(kind, key): copies of one message share both; see the module's docstring."""
    head = peek_header(data)
    if head is None:
        return "raw", data
    action = head[3]
    if action == _ACK and len(data) == HEADER_SIZE + 2:
        return "ack", f"{head[0]}:{head[1]}:".encode() + data[HEADER_SIZE:]  # dst, src, named seq
    return f"a{action}", data


@dataclass
class _Direction:
    key: bytes  # seed and direction name
    n: int = 0
    bad: bool = False  # Gilbert-Elliott state
    sent: deque[float] = field(default_factory=deque)  # times of the last second's datagrams
    seen: OrderedDict[tuple[str, bytes], list[int]] = field(default_factory=OrderedDict)  # -> [rank, copies]
    ranks: dict[str, int] = field(default_factory=dict)  # kind -> distinct messages so far

    def rng(self, data: bytes) -> random.Random:
        """The datagram's own random stream, from its identity (kind, rank, copy)."""
        ident = _identity(data)
        entry = self.seen.pop(ident, None)
        if entry is None:
            rank = self.ranks.get(ident[0], 0)
            self.ranks[ident[0]] = rank + 1
            entry = [rank, 0]
        else:
            entry[1] += 1
        self.seen[ident] = entry
        if len(self.seen) > COPY_MEMORY:
            self.seen.popitem(last=False)
        name = f"{ident[0]}:{entry[0]}:{entry[1]}".encode()
        return random.Random(hashlib.blake2b(name, digest_size=16, key=self.key).digest())


class Impairment:
    """The schedule: ``decide(direction, data, now)`` for each datagram entering the link."""

    def __init__(self, spec: ImpairSpec) -> None:
        self.spec = spec
        self._dirs: dict[str, _Direction] = {}
        self.counts: dict[str, int] = {}

    def _direction(self, name: str) -> _Direction:
        d = self._dirs.get(name)
        if d is None:
            d = self._dirs[name] = _Direction(hashlib.sha256(f"{self.spec.seed}:{name}".encode()).digest()[:32])
        return d

    def decide(self, direction: str, data: bytes, now: float = 0.0) -> Decision:
        """What happens to ``data`` entering the link in ``direction`` at ``now`` (seconds,
        any clock; only the rate limit looks at it)."""
        s = self.spec
        d = self._direction(direction)
        n, rng = d.n, d.rng(data)
        d.n += 1
        draws = [rng.random() for _ in range(9)]
        dropped = None
        if s.burst_gb:
            d.bad = (draws[0] >= s.burst_bg) if d.bad else (draws[0] < s.burst_gb)
            if d.bad and draws[1] < s.burst_loss:
                dropped = "burst"
        if dropped is None and draws[2] < s.loss:
            dropped = "loss"
        if dropped is None and s.rate is not None:
            while d.sent and d.sent[0] <= now - 1.0:
                d.sent.popleft()
            if len(d.sent) >= s.rate:
                dropped = "rate"
            else:
                d.sent.append(now)
        if dropped is not None:
            return self._count(Decision(direction, n, len(data), (), dropped))
        copies = 1 + (s.copies if draws[3] < s.dup else 0)
        out = []
        for c in range(copies):
            r = draws if c == 0 else [rng.random() for _ in range(9)]
            kinds: list[str] = ["dup"] if c else []
            delay = s.delay_lo_s + (s.delay_hi_s - s.delay_lo_s) * r[4]
            if s.delay_hi_s:
                kinds.append("delay")
            if r[5] < s.reorder:
                hold = max(s.delay_hi_s, 0.010)
                delay = s.delay_hi_s + hold * (1.0 + r[6])
                kinds.append("reorder")
            body = data
            if r[7] < s.corrupt and data:
                body, how = _corrupt(data, r[8], rng)
                kinds.append(how)
            out.append(Delivery(delay, body, tuple(kinds)))
        return self._count(Decision(direction, n, len(data), tuple(out)))

    def carry(self, direction: str, data: bytes, now: float, queue: DelayQueue[T],
              held: Callable[[Delivery], T]) -> Decision:
        """:meth:`decide`, then each copy held in ``queue`` until ``now`` plus its delay, as
        ``held(copy)``; the decision as the link carried it out (:meth:`refused`: the copies a
        full queue refused are dropped and counted). The whole link of a datagram entering it,
        on whatever clock ``now`` reads: ``mcp-impair``'s and ``mcp-soak``'s medium, and the
        simulator's on its virtual clock (``sim.link``)."""
        decision = self.decide(direction, data, now)
        kept = tuple(d for d in decision.deliveries if queue.push(now + d.delay_s, len(d.data), held(d)))
        return self.refused(decision, kept)

    def refused(self, decision: Decision, kept: tuple[Delivery, ...]) -> Decision:
        """``decision`` as the link carried it out when its delay queue held only ``kept`` of
        its copies: ``dropped="queue"``, each refused copy counted (``drop:queue``)."""
        lost = len(decision.deliveries) - len(kept)
        if lost <= 0:
            return decision
        self.counts["drop:queue"] = self.counts.get("drop:queue", 0) + lost
        return dataclasses.replace(decision, deliveries=kept, dropped="queue")

    def _count(self, decision: Decision) -> Decision:
        self.counts["datagrams"] = self.counts.get("datagrams", 0) + 1
        for k in decision.kinds:
            self.counts[k] = self.counts.get(k, 0) + 1
        return decision

    def summary(self) -> str:
        """``1000 datagrams: 298 dropped (loss), 101 duplicated, ...`` for a person (``queue``:
        copies a full delay queue refused)."""
        c = self.counts
        drops = {k.split(":", 1)[1]: v for k, v in c.items() if k.startswith("drop:")}
        words = [f"{c.get('datagrams', 0)} datagrams"]
        if drops:
            words.append(f"{sum(drops.values())} dropped (" +
                         ", ".join(f"{v} {k}" for k, v in sorted(drops.items())) + ")")
        for key, label in (("dup", "duplicated"), ("reorder", "reordered"), ("delay", "delayed"),
                           ("corrupt", "corrupted"), ("cut", "truncated")):
            if c.get(key):
                words.append(f"{c[key]} {label}")
        return ", ".join(words)


def _corrupt(data: bytes, r: float, rng: random.Random) -> tuple[bytes, str]:
    """One to three bit flips, or (r < 0.25) a cut to a shorter length."""
    if r < 0.25 and len(data) > 1:
        return data[:rng.randrange(1, len(data))], "cut"
    body = bytearray(data)
    for _ in range(1 + rng.randrange(3)):
        bit = rng.randrange(len(body) * 8)
        body[bit // 8] ^= 1 << (bit % 8)
    return bytes(body), "corrupt"


#: the default cap of a link's delay queue: copies held at once, and bytes held (each copy's
#: length plus HELD_OVERHEAD). At the defaults the held copies take at most 16 MiB (about 10,000
#: copies of 1,400 bytes, or 20,000 small ones: a 60 s delay at 330 datagrams a second)
MAX_HELD = 20_000
MAX_HELD_BYTES = 16 << 20
#: what holding one copy costs beside its bytes: the heap entry, its tuples, the bytes object's
#: header (measured with tracemalloc: ~215 bytes on CPython 3.10-3.12, rounded up)
HELD_OVERHEAD = 256


class DelayQueue(Generic[T]):
    """Copies held until they are due, in due order (ties: the order pushed), bounded:
    :meth:`push` refuses a copy past ``max_count`` copies or ``max_bytes`` bytes held and
    counts it (``refused``, ``refused_bytes``); the caller records the drop.

    Held as two runs keyed ``(due, order pushed)``: a FIFO of the copies pushed in due order
    (a clean or constant-delay link's every copy: an append and a popleft, not a heap's log n
    compares of tuples -- the simulated MCP-ROB-7 flood holds 10,000 at one instant), kept as
    parallel deques (due, order, cost, item: no tuple per copy for the garbage collector to
    walk while it is held), and a heap of the others; :meth:`pop_due` takes the lesser key of
    the two heads, so the order out is the one heap's it replaces."""

    def __init__(self, max_count: int = MAX_HELD, max_bytes: int = MAX_HELD_BYTES) -> None:
        if max_count < 1 or max_bytes < 1:
            raise ImpairmentError("the delay queue's cap must be >= 1 copy and >= 1 byte")
        self.max_count, self.max_bytes = max_count, max_bytes
        self.held_bytes = 0
        self.peak_count = self.peak_bytes = 0
        self.refused = self.refused_bytes = 0
        self._heap: list[tuple[float, int, int, T]] = []
        # the FIFO run, due (then order) ascending
        self._due: deque[float] = deque()
        self._ord: deque[int] = deque()
        self._cost: deque[int] = deque()
        self._item: deque[T] = deque()
        self._order = itertools.count()

    def __len__(self) -> int:
        return len(self._heap) + len(self._due)

    def cap_text(self) -> str:
        return f"{self.max_count} copies, {self.max_bytes / (1 << 20):g} MiB"

    def push(self, due: float, size: int, item: T) -> bool:
        """Hold ``item`` (a copy of ``size`` bytes) until ``due``; False: the queue is full."""
        cost = size + HELD_OVERHEAD
        dues = self._due
        count = len(self._heap) + len(dues)
        held = self.held_bytes + cost
        if count >= self.max_count or held > self.max_bytes:
            self.refused += 1
            self.refused_bytes += size
            return False
        if not dues or dues[-1] <= due:  # in due order: the FIFO's tail (its order is the latest)
            dues.append(due)
            self._ord.append(next(self._order))
            self._cost.append(cost)
            self._item.append(item)
        else:
            heapq.heappush(self._heap, (due, next(self._order), cost, item))
        self.held_bytes = held
        count += 1
        if count > self.peak_count:
            self.peak_count = count
        if held > self.peak_bytes:
            self.peak_bytes = held
        return True

    def next_due(self) -> float | None:
        heap, dues = self._heap, self._due
        if heap:
            return heap[0][0] if not dues or heap[0][0] <= dues[0] else dues[0]
        return dues[0] if dues else None

    def pop_due(self, now: float) -> list[T]:
        """Every copy due by ``now``, in order."""
        out: list[T] = []
        heap, dues, ords, costs, items = self._heap, self._due, self._ord, self._cost, self._item
        held = self.held_bytes
        while dues or heap:
            if dues and (not heap or dues[0] < heap[0][0] or (dues[0] == heap[0][0] and ords[0] < heap[0][1])):
                if dues[0] > now:
                    break
                dues.popleft()
                ords.popleft()
                held -= costs.popleft()
                out.append(items.popleft())
            else:
                if heap[0][0] > now:
                    break
                _, _, cost, item = heapq.heappop(heap)
                held -= cost
                out.append(item)
        self.held_bytes = held
        return out

    def clear(self) -> None:
        self._heap.clear()
        for run in (self._due, self._ord, self._cost, self._item):
            run.clear()
        self.held_bytes = 0


def replace_seed(spec: ImpairSpec, seed: int) -> ImpairSpec:
    """The same impairment with another seed (one seed per soak mission, per link)."""
    return dataclasses.replace(spec, seed=seed)

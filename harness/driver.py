"""The target driver: the runner's one UDP socket, a background receiver, sends and waits.

Case hygiene (docs/design.md): one background receiver timestamps every datagram as it
arrives -- with the kernel's receive time where the system gives one (Linux
``SO_TIMESTAMPNS``), so the gaps between a node's copies (MCP-RTX-3) and its ACK latency
(MCP-ACK-7) are the node's, not the runner's own scheduling delay on a loaded machine;
replies are tied to the commands they answer by ``judge.attribution`` (by the seq they
name, else by timing); the runner sends from the socket it listens on, so a node that
replies to the datagram's source reaches it too. The driver knows nothing of cases or
rules. Recording hooks (``add_observer``) feed captures, with the spawned node's run delay.

While the session allows it, the receiver answers the node as a correct Mission Manager
would: it ACKs every well-formed unicast non-ACK message addressed to the runner's ID
(MCP-ACK-1), so a node never retransmits forever because of the runner.
"""

from __future__ import annotations

import contextlib
import dataclasses
import socket
import struct
import threading
from collections.abc import Callable, Iterable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.harness.clock import REAL, Clock, clock_offset_ns  # noqa: F401 (its old home)
from mcp_conform.harness.errors import NodeLost
from mcp_conform.harness.run_delay import delay_for, takes_run_delay
from mcp_conform.harness.rx_queue import read_backlog
from mcp_conform.harness.stamps import SO_TIMESTAMPNS, arrival_ns, kernel_timestamps, recv_stamped  # noqa: F401 (their old home)
from mcp_conform.harness.transport import Transport, UdpTransport
from mcp_conform.judge.attribution import Attribution, Attributor
from mcp_conform.spec.codec import (
    PREAMBLE,
    Action,
    DecodeError,
    Message,
    build_datagram,
    decode,
    encode,
    peek_header,
)

Address = tuple[str, int]
#: (direction "tx"|"rx", data, addr, t_ns); keyword ``run_delay`` (ns) too when it is known
Observer = Callable[..., None]
#: (direction, cycle of distinct datagrams, count, peer addr, first_t_ns, last_t_ns, local addr)
BurstObserver = Callable[[str, list[bytes], int, Address, int, int, Address], None]
_ACK = int(Action.ACK)
PREAMBLE_LEN = len(PREAMBLE)
MAX_QUEUED_NS = 10 * 10**9  # a kernel time older than this is not believed (a clock step)
MAX_UNHEARD = 100_000  # notifications kept for the first observers (``add_observers``), at most


_U16BE = struct.Struct("!H")
_U16LE = struct.Struct("<H")


def read_header(data: bytes) -> tuple[int, int, int, int] | None:
    """The header fields of any datagram of 17+ bytes, whatever its preamble."""
    return peek_header(data, require_preamble=False)


@dataclass(frozen=True)
class Datagram:
    """One datagram the runner received, as it arrived."""

    index: int
    t: float  # the driver's clock's monotonic() at arrival
    t_ns: int  # its time_ns() at arrival: the run clock of captures and reports
    data: bytes
    addr: Address
    msg: Message | None  # decoded, when well-formed
    error: DecodeError | None  # why it is not, otherwise
    header: tuple[int, int, int, int] | None  # (dst, src, seq, action) when 17+ bytes long
    preamble_ok: bool = True  # the first 9 bytes are the preamble (MCP-HDR-1)
    run_delay: int | None = None  # the node's run delay (ns) as it came, when known (MCP-RTX-3)

    @property
    def action(self) -> int | None:
        return self.header[3] if self.header else None

    @property
    def is_ack_like(self) -> bool:
        """Has a whole header whose action code is ACK (well-formed or not)."""
        return self.header is not None and self.header[3] == _ACK

    def acked_seq(self) -> int | None:
        """The seq a (possibly malformed) ACK names: its first two payload bytes, big-endian."""
        return _U16BE.unpack_from(self.data, 17)[0] if self.is_ack_like and len(self.data) >= 19 else None

    def names_seq(self, seq: int) -> bool:
        """Lenient attribution: an ACK-like datagram whose payload names ``seq`` in any byte
        order. Used so a malformed ACK is judged by MCP-ACK-2, not taken for silence."""
        return (self.is_ack_like and len(self.data) >= 19
                and seq in (_U16BE.unpack_from(self.data, 17)[0], _U16LE.unpack_from(self.data, 17)[0]))

    def describe(self) -> str:
        if self.msg is not None:
            m = self.msg
            return f"{Action(m.action).name} dst={m.dst} src={m.src} seq={m.seq} payload={m.payload!r} ({len(self.data)} B)"
        if self.header is not None:
            dst, src, seq, action = self.header
            return f"malformed action={action} dst={dst} src={src} seq={seq} ({len(self.data)} B): {self.error}"
        return f"malformed {len(self.data)} B: {self.error} [{self.data[:24].hex()}]"


@dataclass(frozen=True)
class Sent:
    """One datagram the runner sent."""

    t: float
    t_ns: int
    data: bytes
    addr: Address
    dst: int
    src: int
    seq: int
    action: int
    command: int = -1  # the command it is a copy of: the runner's send index of its first copy


@dataclass
class Exchange:
    """A unicast command sent as a manager would: retransmitted every ``rto`` until ACKed."""

    copies: list[Sent] = field(default_factory=list)
    ack: Datagram | None = None  # the first reply attributed to it (possibly malformed)
    attribution: Attribution | None = None  # how ``ack`` was tied to the command

    @property
    def seq(self) -> int:
        return self.copies[0].seq

    @property
    def first(self) -> Sent:
        return self.copies[0]

    @property
    def acked(self) -> bool:
        """The node answered: a reply is attributed to the command (its form is judged by
        the ACK cases alone, judge.attribution)."""
        return self.ack is not None

    def latency(self) -> float | None:
        """ACK arrival minus the send time of the copy it answers; only when unambiguous
        (the ACK came before any retransmission)."""
        if self.ack is None:
            return None
        later = [c for c in self.copies[1:] if c.t <= self.ack.t]
        return None if later else self.ack.t - self.copies[0].t


class TargetDriver:
    """The runner's endpoint facing one node under test: a UDP socket on the host's clock by
    default; ``clock`` and ``transport`` (``harness.clock``, ``harness.transport``) another
    clock and far end (the simulator's: a node model on virtual time)."""

    def __init__(self, target: Address, listen: Address, *, our_id: int = 0,
                 rcvbuf: int = 8 * 1024 * 1024, clock: Clock = REAL,
                 transport: Transport | None = None) -> None:
        self.target = target
        self.listen = listen
        self.our_id = our_id
        self.clock = clock
        self._transport = transport or UdpTransport(rcvbuf)
        self._kernel_times = False  # the kernel timestamps what this socket receives
        self._sock: Transport | None = None
        self._thread: Any = None
        self._stop = clock.event()
        self._cond = clock.condition()
        self._rx: list[Datagram] = []
        self._tx: list[Sent] = []
        self._rx_attr: list[Attribution | None] = []  # parallel to _rx
        self.attributor = Attributor(our_id)
        self._observers: list[tuple[Observer, bool]] = []  # (observer, it takes ``run_delay``)
        self._unheard: list[tuple[str, bytes, Address, int, int | None]] | None = []  # add_observers
        #: held while the observers hear of a datagram; whoever else feeds them holds it too (one order)
        self.notify_lock = threading.RLock()
        self._burst_observers: list[BurstObserver] = []
        self._seq: dict[int, int] = {}
        self.auto_ack: Callable[[Datagram], bool] = lambda d: True
        self.alive: Callable[[], bool] = lambda: True
        #: called in the receiver thread for every datagram, after it is recorded (the
        #: manager role's drone players answer from here)
        self.on_datagram: Callable[[Datagram], None] | None = None
        # liveness (harness.liveness): hooks on every datagram, and a check that raises
        # NodeLost in the waiting thread once the node is declared lost
        self.rx_hooks: list[Callable[[Datagram], None]] = []
        self.tx_hooks: list[Callable[[Sent], None]] = []
        #: entered around each send in the sending thread, outside the lock (the seq taken and
        #: the datagram sent under it): it may hold a thread back (conformance._batch)
        self.tx_gate: Callable[[], AbstractContextManager[Any]] = contextlib.nullcontext
        self.check: Callable[[], None] = lambda: None
        self._seq_lock = threading.Lock()
        self.link: Any = None  # ``--impair``: the runner's socket edge through a bad link
        #: the spawned node's run delay now (``harness.run_delay``; MCP-RTX-3); None: unknown
        self.run_delay: Callable[[], int | None] | None = None

    # ------------------------------------------------------------------ lifecycle
    def open(self) -> Address:
        """Bind the listen address (all addresses when its host is empty); return it."""
        tr = self._transport
        self.listen = tr.bind(self.listen)
        self._kernel_times = tr.kernel_times
        self._sock = tr
        self._thread = self.clock.start_thread(self._receive_loop, "mcp-conform-rx")
        return self.listen

    def close(self) -> None:
        self._stop.set()
        if self.link is not None:
            self.link.close()
        if self._thread is not None:
            self._thread.join(timeout=1.0)
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def remove_observer(self, observer: Observer) -> None:
        self._observers = [o for o in self._observers if o[0] != observer]

    def add_observers(self, observers: Iterable[Observer] = (), bursts: Iterable[BurstObserver] = ()) -> None:
        """``observers`` hear every datagram sent ("tx") and received ("rx"), from any thread;
        ``bursts`` each :meth:`flood` once. The first call (none given too) first hands ``observers``,
        in order, what the driver sent and received since :meth:`open` (the receiver runs from
        there: the capture and the run's monitor added after, ``observe_run``, lose nothing)."""
        with self.notify_lock:
            added = [(o, takes_run_delay(o)) for o in observers]
            self._observers, unheard, self._unheard = self._observers + added, self._unheard or [], None
            self._burst_observers.extend(bursts)
            for item in unheard:
                self._notify(*item, to=added)

    def add_observer(self, observer: Observer) -> None:
        self.add_observers([observer])

    # ------------------------------------------------------------------ receiving
    def _receive_loop(self) -> None:
        assert self._sock is not None
        sock = self._sock
        while not self._stop.is_set():
            try:
                data, addr, arrived = sock.recv()
            except TimeoutError:
                continue
            except OSError:
                if self._stop.is_set():
                    return
                self.clock.sleep(0.01)
                continue
            if self.link is not None:
                # observers (the capture, the run's monitor) hold the node's side of the
                # link: what it sent, once, as it sent it; the cases what the runner got
                self._notify("rx", data, addr, arrived or self.clock.time_ns(), delay_for(data, self.run_delay))
                if not self.link.receive(data, (str(addr[0]), int(addr[1])), self._arrive):
                    self._lost(data)
            else:
                self._arrive(data, addr, arrived)

    def _lost(self, data: bytes) -> None:
        """A datagram the node sent that the runner's own impaired link dropped: the cases
        never see it, but a reply the node made still answered a copy (``judge.attribution``
        credits it), so a later reply naming that command is not taken for its late answer:
        a node whose every ACK names the command before (ack-previous-seq) had those ACKs
        explained so, and passed MCP-ACK-2 through ``--impair``."""
        t, t_ns = self.clock.monotonic(), self.clock.time_ns()
        with self._cond:
            self.attributor.received(Datagram(-1, t, t_ns, data, self.target, None, None, read_header(data),
                                              data[:PREAMBLE_LEN] == PREAMBLE, None))

    def _arrive(self, data: bytes, addr: Address, arrived: int | None = None) -> None:
        """One datagram reaches the runner (from the socket, or from the impaired link's
        timer thread for a delayed copy): logged, observed (on a clean link), answered.
        ``arrived``: the kernel's receive time (ns, the wall clock), when it gave one."""
        if self._stop.is_set():
            return
        t, t_ns = self.clock.monotonic(), self.clock.time_ns()
        if arrived is not None and 0 <= t_ns - arrived < MAX_QUEUED_NS:
            t, t_ns = (arrived - self.clock.offset_ns()) / 1e9, arrived
        try:
            msg: Message | None = decode(data)
            err = None
        except DecodeError as exc:
            msg, err = None, exc
        rd = delay_for(msg, self.run_delay)
        with self._cond:
            d = Datagram(len(self._rx), t, t_ns, data, addr, msg, err, read_header(data),
                         data[:PREAMBLE_LEN] == PREAMBLE, rd)
            self._rx.append(d)
            self._rx_attr.append(self.attributor.received(d))
            for hook in self.rx_hooks:
                hook(d)
            self._cond.notify_all()
        if self.link is None:
            self._notify("rx", data, addr, t_ns, rd)
        if self.on_datagram is not None:
            self.on_datagram(d)
        if (msg is not None and msg.action != Action.ACK and msg.dst == self.our_id
                and self.auto_ack(d)):
            self.send_ack(msg.seq, dst=msg.src)  # to the node's receive address (MCP-TRN-2)

    def _notify(self, direction: str, data: bytes, addr: Address, t_ns: int, rd: int | None = None,
                to: list[tuple[Observer, bool]] | None = None) -> None:
        with self.notify_lock:
            if to is None and self._unheard is not None:  # kept for the first observers (add_observers)
                if len(self._unheard) < MAX_UNHEARD:
                    self._unheard.append((direction, data, addr, t_ns, rd))
                return
            for obs, takes in self._observers if to is None else to:  # run_delay only to those that take it, when known
                try:
                    obs(direction, data, addr, t_ns, run_delay=rd) if takes and rd is not None else obs(direction, data, addr, t_ns)
                except Exception:  # a broken recorder must not stop the run
                    pass

    def mark(self) -> int:
        """Index of the next datagram to arrive: 'from now on'."""
        with self._cond:
            return len(self._rx)

    def received(self, since: int = 0, until: int | None = None) -> list[Datagram]:
        with self._cond:
            return self._rx[since:until]

    def last_heard(self, since: int = 0) -> str:
        """For a setup error's one line: what the runner received from index ``since`` on (the
        node's start), and how long ago the last of it came ("; the last of its 3 datagram(s) to
        the runner, MISSION_READY, came 0.52 s before"), or that nothing did."""
        with self._cond:
            got = self._rx[since:]
        if not got:
            return "; it had sent the runner nothing"
        last = got[-1]
        try:
            kind = Action(last.action).name if last.action is not None else "unreadable"
        except ValueError:
            kind = f"action {last.action}"
        return (f"; the last of its {len(got)} datagram(s) to the runner, {kind}, came "
                f"{self.clock.monotonic() - last.t:.2f} s before")

    def attribution(self, d: Datagram) -> Attribution | None:
        """The command ``d`` was attributed to on arrival (judge.attribution)."""
        with self._cond:
            return self._rx_attr[d.index] if 0 <= d.index < len(self._rx_attr) else None

    def settle_attribution(self, limit: float) -> None:
        """Wait (at most ``limit`` s) until no command with a copy unanswered can still take a
        reply (``Attributor.answerable_until``); replies meanwhile are tied as they come."""
        deadline = self.clock.monotonic() + limit
        while True:
            now = self.clock.monotonic()
            with self._cond:
                until = self.attributor.answerable_until(now)
            if until <= now or now >= deadline:
                return
            self.pause(min(until, deadline) - now)

    def attribute_external(self, d: Datagram) -> Attribution | None:
        """Attribute a datagram that arrived on another socket (MCP-TRN-2's side socket)."""
        with self._cond:
            return self.attributor.received(d)

    def answers(self, sents: Iterable[Sent], since: int = 0) -> list[tuple[Datagram, Attribution]]:
        """Replies at index >= ``since`` attributed to the commands of ``sents``."""
        cmds = {s.command for s in sents}
        with self._cond:
            return [(d, a) for d, a in zip(self._rx[since:], self._rx_attr[since:], strict=True)
                    if a is not None and a.command in cmds]

    def sent(self) -> list[Sent]:
        with self._cond:
            return list(self._tx)

    def wait_for(self, predicate: Callable[[Datagram], bool], timeout: float,
                 since: int = 0) -> Datagram | None:
        """First datagram at index >= ``since`` matching ``predicate``, waiting up to
        ``timeout`` seconds. None is an observation (nothing came), not an error."""
        deadline = self.clock.monotonic() + max(0.0, timeout)
        i = since
        with self._cond:
            while True:
                while i < len(self._rx):
                    if predicate(self._rx[i]):
                        return self._rx[i]
                    i += 1
                self.check()
                left = deadline - self.clock.monotonic()
                if left <= 0:
                    return None
                self._cond.wait(min(left, 0.05))
                self.check()
                if not self.alive():
                    # give the last datagrams a moment, then stop waiting for a dead node
                    self._cond.wait(0.05)
                    while i < len(self._rx):
                        if predicate(self._rx[i]):
                            return self._rx[i]
                        i += 1
                    return self.check()  # None, or NodeLost: a death not declared yet is named here

    def pause(self, seconds: float) -> None:
        """Sleep ``seconds``, but raise at once (``check``) if the node is declared lost."""
        deadline = self.clock.monotonic() + max(0.0, seconds)
        with self._cond:
            while True:
                self.check()
                left = deadline - self.clock.monotonic()
                if left <= 0:
                    return
                self._cond.wait(min(left, 0.05))

    def quiet(self, gap: float = 0.05, limit: float = 1.0) -> int:
        """Wait until nothing has arrived for ``gap`` s (at most ``limit`` s); return a mark."""
        deadline = self.clock.monotonic() + limit
        while self.clock.monotonic() < deadline:
            with self._cond:
                last = self._rx[-1].t if self._rx else 0.0
            if self.clock.monotonic() - last >= gap:
                break
            self.clock.sleep(gap / 2)
        return self.mark()

    # ------------------------------------------------------------------ sending
    def next_seq(self, src: int | None = None) -> int:
        src = self.our_id if src is None else src
        with self._seq_lock:  # the liveness watcher sends probes from its own thread
            seq = self._seq.get(src, 0)
            self._seq[src] = (seq + 1) & 0xFFFF
        return seq

    @property
    def seq_lock(self) -> Any:
        """Held to reserve a run of seqs at once (``peek_seq`` then ``set_seq``) while other
        threads send (``next_seq`` takes it too)."""
        return self._seq_lock

    def peek_seq(self, src: int | None = None) -> int:
        return self._seq.get(self.our_id if src is None else src, 0)

    def sent_as(self, src: int) -> bool:
        """Whether the runner has numbered messages as ``src`` in this run (its seq set or taken)."""
        return src in self._seq

    def set_seq(self, value: int, src: int | None = None) -> None:
        self._seq[self.our_id if src is None else src] = value & 0xFFFF

    def send_raw(self, data: bytes, addr: Address | None = None, *, dst: int = -1, src: int = -1,
                 seq: int = -1, action: int = -1, sock: socket.socket | None = None,
                 copy_of: Sent | None = None) -> Sent:
        """Send one datagram; ``copy_of``: it is a retransmission of that command."""
        with self.tx_gate():
            return self._send_raw(data, addr, dst=dst, src=src, seq=seq, action=action, sock=sock,
                                  copy_of=copy_of)

    def _send_raw(self, data: bytes, addr: Address | None, *, dst: int, src: int, seq: int, action: int,
                  sock: socket.socket | None = None, copy_of: Sent | None = None) -> Sent:
        assert self._sock is not None, "driver not open"
        addr = addr or self.target
        hdr = peek_header(data)
        if hdr is not None and dst == -1:
            dst, src, seq, action = hdr
        with self._cond:
            # logged (and stamped) before it leaves: a reply within the same tick must find it
            t, t_ns = self.clock.monotonic(), self.clock.time_ns()
            index = len(self._tx)
            s = Sent(t, t_ns, data, addr, dst, src, seq, action, index)
            command = self.attributor.sent(index, s, copy_of.command if copy_of is not None else None)
            if command != index:
                s = dataclasses.replace(s, command=command)
            self._tx.append(s)
            for hook in self.tx_hooks:
                hook(s)
        if self.link is not None:  # observed as the node is sent each copy (see _receive_loop)
            delays = self.link.send(sock or self._sock, data, addr,
                                    lambda body: self._notify("tx", body, addr, self.clock.time_ns()))
            if delays != [0.0]:  # the runner's own link knows which copies the node was sent
                with self._cond:
                    self.attributor.on_wire(index, t, delays)
        else:
            (sock or self._sock).sendto(data, addr)  # type: ignore[union-attr]  # asserted above
            self._notify("tx", data, addr, t_ns)
        return s

    def send(self, action: Action, payload: Any = None, dst: int | None = None, *,
             src: int | None = None, seq: int | None = None, addr: Address | None = None,
             sock: socket.socket | None = None) -> Sent:
        """Encode and send one new message (a fresh seq unless ``seq`` is given)."""
        src = self.our_id if src is None else src
        dst = 0 if dst is None else dst
        with self.tx_gate():  # a thread held back takes its seq once let go: the node sees them in order
            seq = self.next_seq(src) if seq is None else seq
            data = encode(Message(dst, src, seq, action, payload))
            return self._send_raw(data, addr, dst=dst, src=src, seq=seq, action=int(action), sock=sock)

    def send_datagram(self, dst: int, seq: int, action: int, payload: bytes, *,
                      src: int | None = None, addr: Address | None = None) -> Sent:
        """Send raw header fields + payload bytes (for malformed input)."""
        src = self.our_id if src is None else src
        return self.send_raw(build_datagram(dst, src, seq, action, payload), addr,
                             dst=dst, src=src, seq=seq, action=action)

    def send_ack(self, seq: int, *, dst: int, src: int | None = None, addr: Address | None = None) -> Sent:
        return self.send(Action.ACK, seq, dst, src=src, addr=addr)

    def resend(self, sent: Sent, sock: socket.socket | None = None) -> Sent:
        """A retransmission: the same bytes (and so the same seq) again."""
        return self.send_raw(sent.data, sent.addr, dst=sent.dst, src=sent.src, seq=sent.seq,
                             action=sent.action, sock=sock, copy_of=sent)

    def ack_for(self, sent: Sent) -> Callable[[Datagram], bool]:
        """Predicate: a reply naming ``sent``'s seq in either byte order (verdicts: ``answered``)."""
        seq, src = sent.seq, sent.src

        def match(d: Datagram) -> bool:
            if not d.names_seq(seq):
                return False
            assert d.header is not None
            return d.header[0] == src or src == self.our_id
        return match

    def answered(self, sent: Sent) -> Callable[[Datagram], bool]:
        """Predicate (evaluated under the lock, by ``wait_for``): a reply attributed to the
        command ``sent`` belongs to."""
        command = sent.command

        def match(d: Datagram) -> bool:
            a = self._rx_attr[d.index] if d.index < len(self._rx_attr) else None
            return a is not None and a.command == command
        return match

    def exchange(self, first: Sent, *, rto: float, copies: int, tail: float | None = None) -> Exchange:
        """Await a reply attributed to ``first``, retransmitting it every ``rto`` up to
        ``copies`` copies in all (MCP-ACK-1 as observed by a manager, D-6); after the last
        copy wait ``tail``."""
        ex = Exchange([first])
        since = self.mark_before(first)
        match = self.answered(first)
        for n in range(copies):
            wait = rto if n < copies - 1 else (rto if tail is None else max(rto, tail))
            try:
                got = self.wait_for(match, wait, since)
            except NodeLost as exc:  # say which exchange went unanswered
                exc.exchange = ex
                raise
            if got is None and n == copies - 1 and self._kernel_times:
                end = self.clock.monotonic()  # a reply that came by now, read late (``read_backlog``)
                if read_backlog(self.listen[0] or "0.0.0.0", self.listen[1]):
                    got = self.wait_for(lambda d, end=end: d.t <= end and match(d), 0.2, since)  # type: ignore[misc]  # mypy: a default argument
            if got is not None:
                ex.ack, ex.attribution = got, self.attribution(got)
                return ex
            if not self.alive() or n == copies - 1:
                return ex
            ex.copies.append(self.resend(first))
        return ex

    def mark_before(self, sent: Sent) -> int:
        """Index of the first datagram that arrived after ``sent`` left."""
        with self._cond:
            i = len(self._rx)
            while i > 0 and self._rx[i - 1].t >= sent.t:
                i -= 1
            return i

    def flood(self, datagrams: list[bytes], count: int, *, sock: socket.socket | None = None,
              limit: float = 30.0) -> int:
        """Send ``count`` datagrams as fast as the socket takes them, cycling through
        ``datagrams``, for at most ``limit`` seconds; return how many left. Too fast to record
        one by one: burst observers get one summary (MCP-ROB-7's flood)."""
        assert self._sock is not None, "driver not open"
        out = sock or self._sock
        addr = self.target
        deadline = self.clock.monotonic() + limit
        first_ns, sent, n = self.clock.time_ns(), 0, len(datagrams)
        many = getattr(out, "sendto_many", None) if getattr(self.clock, "virtual", False) else None
        if many is not None and count > 0 and n and self.clock.monotonic() < deadline:
            # the simulator's socket (sim.transport) on a virtual clock: no time passes and no
            # send is refused within the loop below, so its every datagram at once, in order
            sent = many(datagrams, count, addr)
        while sent < count and n and self.clock.monotonic() < deadline:
            try:
                out.sendto(datagrams[sent % n], addr)
                sent += 1
            except OSError:  # BlockingIOError included: the buffer is full, let it drain
                self.clock.sleep(0.001)
        last_ns = self.clock.time_ns()
        local = out.getsockname()[:2]
        for obs in self._burst_observers:
            try:
                obs("tx", list(datagrams), sent, addr, first_ns, last_ns, local)
            except Exception:  # a broken recorder must not stop the run
                pass
        return sent

    def open_side_socket(self, host: str = "127.0.0.1") -> socket.socket:
        """A second socket on another source port (MCP-TRN-2). Caller closes it."""
        return self._transport.side_socket(host)  # type: ignore[no-any-return]  # a socket, or the transport's

"""The one judgement of what an Nsqd backend sends (NSQD-FRM-1, NSQD-MSG-2), live and offline.

The runner's connections (``harness.nsqd_session.Conn.violation``), the fuzzer (through
them) and ``mcp-capture check`` on a capture (MCAP or a pcap's reassembled TCP streams) all
call :func:`decode_frame` on each frame the backend sent and :func:`sender_violation` on a
connection's frames, so the same bytes get the same verdict wherever they were seen.

:class:`StreamMonitor` is the offline side: fed each connection's backend-to-client bytes in
order (any split), keeps per connection a deframer and its first violations (nothing else:
memory is bounded whatever the capture's length), and judges each connection as
``Conn.violation`` does at its end: per-rule verdicts ``failed`` (with the connections and
evidence), ``passed`` (frames seen, none broke the rule) or ``not_observed``. A connection whose backend stream cannot be
framed from its start (the capture joined it mid-stream, or lost bytes of it) is not judged
after that point, and the monitor says so: a gap is never a framing violation.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from mcp_conform.spec.nsqd import StreamSpec
from mcp_conform.spec.nsqd_codec import BodyError, Deframer, Frame, FramingError, decode_body

__all__ = ["RULES", "ConnVerdict", "Received", "SenderViolation", "StreamMonitor", "decode_frame",
           "sender_violation"]

#: The rules a backend's frames show without the runner's cases (what a capture can judge).
RULES = ("NSQD-FRM-1", "NSQD-MSG-2")


@dataclass(frozen=True)
class Received:
    """A frame from the backend, when it came, and what it decoded to (``problem``: why not)."""

    t: float
    frame: Frame
    values: dict[str, Any] | None
    problem: str | None = None


@dataclass(frozen=True)
class SenderViolation:
    """What the backend sent that breaks a rule binding its frames (NSQD-FRM-1, NSQD-MSG-2):
    the one judgement of them, for the runner's cases, the fuzzer and the capture tools."""

    rule: str
    expected: str
    actual: str
    evidence: tuple[str, ...] = ()


def decode_frame(spec: StreamSpec, frame: Frame) -> tuple[dict[str, Any] | None, str | None]:
    """(field values, problem) of one frame the backend sent (NSQD-MSG-2's layout)."""
    if not spec.has_message(frame.msg_id):
        return None, f"message id {frame.msg_id} names no message"
    try:
        d = decode_body(spec, frame.msg_id, frame.body, check_text=False)
    except BodyError as exc:
        return None, str(exc)
    values = d.as_dict()
    return values, (f"{d.name}: {d.extra} bytes after its last field" if d.extra else None)


def sender_violation(spec: StreamSpec, frames: list[Received], framing_error: FramingError | None,
                     ) -> SenderViolation | None:
    """The first rule the backend's frames on one connection break, if any: a length out of
    bounds (NSQD-FRM-1), then a frame a backend does not send or not in its layout, or an
    UPDATE.state that is no flight state (NSQD-MSG-2)."""
    if framing_error is not None:
        fe = framing_error
        return SenderViolation("NSQD-FRM-1", "frames whose 32-bit length counts itself, 5..8192",
                               f"a frame from the backend with {fe.reason} (prefix {fe.raw.hex(' ')})")
    allowed = {spec.message("ERROR").id, spec.message("UPDATE").id}
    states = set(spec.states.values())
    for r in frames:
        ev = (f"frame: {r.frame.raw[:48].hex(' ')}",)
        if r.frame.msg_id not in allowed:
            return SenderViolation("NSQD-MSG-2", "a backend sends only ERROR and UPDATE",
                                   f"a frame with id {r.frame.msg_id}", ev)
        if r.problem is not None:
            return SenderViolation("NSQD-MSG-2", "each message with exactly its layout", r.problem, ev)
        if r.values is not None and "state" in r.values and r.values["state"] not in states:
            return SenderViolation("NSQD-MSG-2", "UPDATE.state one of the flight states",
                                   f"state {r.values['state']} (0x{r.values['state'] & 0xFFFFFFFF:08x})", ev)
    return None


@dataclass
class ConnVerdict:
    """One connection as the monitor saw it: its verdict is :func:`sender_violation`'s over
    all its frames, as ``Conn.violation`` gives it at the connection's end (a length out of
    bounds first: the frames misread before it are its consequence, not NSQD-MSG-2's)."""

    conn: int
    frames: int = 0
    framing: tuple[SenderViolation, int] | None = None  # NSQD-FRM-1 and when
    first_bad: tuple[SenderViolation, int] | None = None  # the first frame breaking NSQD-MSG-2
    unjudged: str | None = None  # why the rest of its backend stream was not judged
    _deframer: Any = None

    @property
    def violation(self) -> tuple[SenderViolation, int] | None:
        return self.framing or self.first_bad


class StreamMonitor:
    """Offline judge of the backends' frames, one connection at a time (see the module).

    At most :data:`MAX_TRACKED` connections are followed at once (the least recently active
    is then judged as it stands and folded into the totals), and at most
    :data:`MAX_EXAMPLES` failing connections are kept per rule (the rest counted)."""

    MAX_TRACKED = 65536
    MAX_EXAMPLES = 1000

    def __init__(self, spec: StreamSpec) -> None:
        self.spec = spec
        self.conns: dict[int, ConnVerdict] = {}
        self.failed: dict[str, list[ConnVerdict]] = {r: [] for r in RULES}
        self.failed_count: dict[str, int] = dict.fromkeys(RULES, 0)
        self.judged = {r: 0 for r in RULES}  # connections with frames judged under the rule
        self.folded = 0

    def _conn(self, conn: int) -> ConnVerdict:
        c = self.conns.pop(conn, None)
        if c is None:
            c = ConnVerdict(conn, _deframer=Deframer(self.spec))
            if len(self.conns) >= self.MAX_TRACKED:
                self._fold(self.conns.pop(next(iter(self.conns))))
        self.conns[conn] = c  # the most recently active last
        return c

    def _fold(self, c: ConnVerdict) -> None:
        self.folded += 1
        c._deframer = None
        if c.frames:
            self.judged["NSQD-FRM-1"] += 1
            if c.framing is None:
                self.judged["NSQD-MSG-2"] += 1
        v = c.violation
        if v is not None:
            rule = v[0].rule
            self.failed_count[rule] += 1
            if len(self.failed[rule]) < self.MAX_EXAMPLES:
                self.failed[rule].append(c)

    def backend_bytes(self, conn: int, data: bytes, t_ns: int) -> None:
        """Bytes the backend sent on ``conn``, in stream order; each frame judged as it
        completes (nothing kept but the first violation of each kind: bounded memory)."""
        c = self._conn(conn)
        if c.unjudged is not None or c.framing is not None:
            return
        for item in c._deframer.feed(data):
            if isinstance(item, FramingError):
                c.framing = (sender_violation(self.spec, [], item), t_ns)  # type: ignore[assignment]
                return
            c.frames += 1
            if c.first_bad is None:
                values, problem = decode_frame(self.spec, item)
                v = sender_violation(self.spec, [Received(t_ns / 1e9, item, values, problem)], None)
                if v is not None:
                    c.first_bad = (v, t_ns)

    def unjudgeable(self, conn: int, why: str) -> None:
        """The rest of ``conn``'s backend stream cannot be framed (a gap, joined mid-stream)."""
        c = self._conn(conn)
        if c.unjudged is None:
            c.unjudged = why

    def verdict_of(self, conn: int) -> ConnVerdict | None:
        """A connection still followed (None once folded into the totals)."""
        return self.conns.get(conn)

    def verdicts(self) -> dict[str, tuple[str, list[ConnVerdict], int]]:
        """rule -> (passed | failed | not_observed, failing connections kept, how many failed);
        every connection still followed is judged as it stands (the capture's end)."""
        while self.conns:
            self._fold(self.conns.pop(next(iter(self.conns))))
        out: dict[str, tuple[str, list[ConnVerdict], int]] = {}
        for rule in RULES:
            n = self.failed_count[rule]
            state = "failed" if n else ("passed" if self.judged[rule] else "not_observed")
            out[rule] = (state, sorted(self.failed[rule], key=lambda c: c.conn), n)
        return out

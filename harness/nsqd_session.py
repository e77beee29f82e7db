"""The runner's session with a stream-protocol node (``--protocol nsqd``: the node is a
backend, the runner its client), the TCP counterpart of ``harness.drone_session``.

The node is embedded (the reference backend on a free loopback port, spawned), attached
(``--target HOST:PORT``) or spawned (``--spawn CMD`` with ``{target_host}``,
``{target_port}``). The session is the shared core's (``harness.stream_session.
ConnSessionBase``: connections opened for the cases, a spawned process watched -- a death
reported with its signal, a sanitizer's summary line and the tail of stderr, and the backend
restarted for the next case -- and the backend live when a new connection is accepted and an
UPDATE received: NSQD-CON-1, NSQD-MSG-1); its connection the core's
(``harness.stream_conn.StreamConn``: bytes out in any split, frames in, timestamps kept) with
Nsqd's framing (:class:`NsqdFraming`: the spec's deframer) and Nsqd's reading of the frames.
"""

from __future__ import annotations

from functools import partial
from typing import Any

from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.session_base import Death, reference_command
from mcp_conform.harness.stream_conn import StreamConn
from mcp_conform.harness.stream_session import ConnSessionBase
from mcp_conform.judge.nsqd_monitor import Received, SenderViolation, decode_frame, sender_violation
from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd import StreamSpec
from mcp_conform.spec.nsqd_codec import Deframer, Frame, FramingError
from mcp_conform.spec.profiles import pick

__all__ = ["Conn", "Death", "NsqdFraming", "Received", "SenderViolation", "StreamSession"]

#: The embedded reference backend's UPDATE period (the description's is 0.4 s: D-8).
EMBEDDED_UPDATE_PERIOD = 0.05


class NsqdFraming:
    """Nsqd as a connection's protocol (``harness.stream_conn.StreamFraming``): the spec's
    deframer (NSQD-FRM-1), each frame decoded (``judge.nsqd_monitor.decode_frame``) and
    recorded with its message's id, name, fields and problem."""

    def __init__(self, spec: StreamSpec) -> None:
        self.spec = spec
        self.deframer = Deframer(spec)  # the connection's: what a read cut short waits for the next

    def _name(self, msg_id: int | None) -> str | None:
        return self.spec.message(msg_id).name if msg_id is not None and self.spec.has_message(msg_id) else None

    def sent(self, data: bytes) -> dict[str, Any]:
        head = Deframer(self.spec).feed(data)
        whole = len(head) == 1 and isinstance(head[0], Frame) and len(head[0].raw) == len(data)
        msg_id = head[0].msg_id if whole else None  # type: ignore[union-attr]
        return {"msg_id": msg_id, "name": self._name(msg_id)}

    def deframe(self, data: bytes, t: float) -> list[tuple[Frame | FramingError, Received | None, dict[str, Any]]]:
        return [self._received(item, t) for item in self.deframer.feed(data)]

    def _received(self, item: Frame | FramingError, t: float) -> tuple[Frame | FramingError, Received | None,
                                                                       dict[str, Any]]:
        if isinstance(item, FramingError):
            return item, None, {"problem": item.reason}
        values, problem = decode_frame(self.spec, item)
        return item, Received(t, item, values, problem), {"msg_id": item.msg_id, "name": self._name(item.msg_id),
                                                          "fields": values, "problem": problem}


class Conn(StreamConn):
    """One client connection of the runner to the backend: the core's, with Nsqd's framing
    and its reading of the backend's frames."""

    frames: list[Received]
    framing_error: FramingError | None

    def __init__(self, transport: str, address: tuple[str, int], recorder: Any = None, *, spec: StreamSpec = NSQD,
                 **kw: Any) -> None:
        self.spec = spec
        super().__init__(NsqdFraming(spec), transport, address, recorder, **kw)

    def violation(self) -> SenderViolation | None:
        """The first rule the backend's frames on this connection break, if any (the one
        judgement: ``judge.nsqd_monitor.sender_violation``)."""
        return sender_violation(self.spec, self.frames, self.framing_error)

    def updates(self, since: float = 0.0) -> list[Received]:
        return [r for r in self.received(since, "UPDATE") if r.values is not None]

    def errors(self, since: float = 0.0) -> list[Received]:
        return self.received(since, "ERROR")

    signs = updates  # the frame that shows the backend serving (NSQD-CON-1)


def embedded_command() -> str:
    """The reference backend as the embedded default, at a short UPDATE period."""
    return reference_command(*pick("nsqd", "backend"),
                             f"--listen {{target_host}}:{{target_port}} --update-period {EMBEDDED_UPDATE_PERIOD:g}")


class StreamSession(ConnSessionBase):
    """The backend under test over the whole run, and the connections of its cases."""

    subject = "the backend"
    startup_note = ("startup: the runner connects to the backend and waits for its first UPDATE",
                    "startup: connecting and waiting for the first UPDATE")
    first_sign, first_rule, gap_param = "UPDATE", "NSQD-CON-1", "update_gap_max_s"
    conns: list[Conn]
    #: a command this backend was seen to take the effect of (found once per run by a case)
    proven_probe: tuple[str, int] | None = None

    def __init__(self, cfg: RunConfig, recorder: Any = None, spec: StreamSpec = NSQD) -> None:
        super().__init__(cfg, recorder, spec, embedded_command)
        self.link_class = partial(Conn, spec=spec)
        #: the commands ``StreamCaseContext.settle`` saw not to take their effect on this backend,
        #: tried after the others for the rest of the run (until seen to land)
        self.settle_missed: list[str] = []

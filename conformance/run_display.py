"""What the runner shows while it works: ``-v`` traffic lines and the progress line.

- ``TrafficPrinter`` (``mcp-conform -v``, ``--mcp-verbose-traffic``): every datagram the
  runner sends or receives, as it happens, on stderr: time since the run began, direction,
  peer address, and the decoded header and payload (or the rule a malformed datagram
  breaks, as ``spec.codec`` names it). Lines are held ``HOLD_S`` and printed in time order:
  the receiving thread may report a reply before the sender reports the datagram it
  answers, and a reply is never printed before its request.
- ``Tee``: hands each capture event to the MCAP recorder and to the printer, so the session
  sees one recorder whatever is switched on.
- ``WaitStatus``: a rich status line for the startup phase and for any wait longer than
  2 s (a node with the description's 5 s timeout keeps the runner waiting for half a
  minute at startup); on a terminal only, so CI logs stay clean — except the wait for the
  node's first datagram (``FirstDatagram``, bounded by ``--startup-timeout``), which off a
  terminal prints a plain line when it begins and every ``PLAIN_EVERY_S`` after, so a log
  shows what an attach to a silent target waits for.
"""

from __future__ import annotations

import contextlib
import heapq
import threading
import time
from typing import Any

from rich.console import Console
from rich.markup import escape

from mcp_conform.spec.codec import Action, DecodeError, MissionItem, decode

__all__ = ["FirstDatagram", "TrafficPrinter", "Tee", "WaitStatus", "listen_text"]

SHOW_AFTER_S = 2.0
HOLD_S = 0.2  # how long a -v line waits for earlier datagrams reported later
PLAIN_EVERY_S = 10.0


def _describe(data: bytes) -> str:
    try:
        msg = decode(data)
    except DecodeError as exc:
        return f"malformed ({exc.rule}: {exc}) {len(data)} bytes"
    try:
        name = Action(msg.action).name
    except ValueError:
        name = f"action {msg.action}"
    payload = msg.payload
    if isinstance(payload, MissionItem):
        shown = f" item cmd={payload.command} lat={payload.x:.6f} lon={payload.y:.6f} alt={payload.z:g}"
    elif isinstance(payload, (list, tuple)):
        shown = f" [{len(payload)} item(s)]"
    elif isinstance(payload, bytes):
        shown = f" {payload[:16].hex()}{'…' if len(payload) > 16 else ''}" if payload else ""
    elif payload is None or payload == b"":
        shown = ""
    else:
        shown = f" {payload}"
    return f"dst={msg.dst} src={msg.src} seq={msg.seq} {name}{shown}"


class TrafficPrinter:
    """An observer of the target driver (``direction, data, addr, t_ns``) printing live."""

    def __init__(self, console: Console | None = None, t0_ns: int | None = None,
                 uncaptured: Any = None) -> None:
        self.console = console or Console(stderr=True, highlight=False)
        self.t0_ns = t0_ns if t0_ns is not None else time.time_ns()
        self._lock = threading.Lock()
        self._print_lock = threading.Lock()
        # pytest's capture manager swallows what a test prints; live lines go around it
        self._uncaptured = uncaptured or contextlib.nullcontext
        self._pending: list[tuple[int, int, str, str | None]] = []  # (t_ns, n, line, style): a heap
        self._n = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def __call__(self, direction: str, data: bytes, addr: Any, t_ns: int | None = None,
                 run_delay: int | None = None) -> None:
        t_ns = t_ns if t_ns is not None else time.time_ns()
        arrow = "→" if direction == "tx" else "←"
        peer = f"{addr[0]}:{addr[1]}" if isinstance(addr, tuple) and len(addr) >= 2 else str(addr)
        line = f"{(t_ns - self.t0_ns) / 1e9:9.3f} s  {direction} {arrow} {peer:<21} {_describe(data)}"
        with self._lock:
            heapq.heappush(self._pending, (t_ns, self._n, line, "dim" if direction == "tx" else None))
            self._n += 1
            if self._thread is None and not self._stop.is_set():
                self._thread = threading.Thread(target=self._run, name="mcp-conform-traffic", daemon=True)
                self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(HOLD_S / 4):
            self.flush(time.time_ns() - int(HOLD_S * 1e9))

    def flush(self, upto_ns: int | None = None) -> None:
        """Print the held lines (those up to ``upto_ns``; all by default), in time order."""
        with self._print_lock:
            with self._lock:
                ready = []
                while self._pending and (upto_ns is None or self._pending[0][0] <= upto_ns):
                    ready.append(heapq.heappop(self._pending))
            if not ready:
                return
            with self._uncaptured(), contextlib.suppress(OSError, ValueError):
                for _t, _n, line, style in ready:
                    self.console.print(escape(line), soft_wrap=True, style=style)

    def close(self) -> None:
        """Print what is held and stop (the end of the run)."""
        self._stop.set()
        self.flush()


def listen_text(addr: Any) -> str:
    """The runner's socket as a user reads it: ``0.0.0.0:7889`` when bound to all addresses."""
    if isinstance(addr, tuple) and len(addr) >= 2:
        return f"{addr[0] or '0.0.0.0'}:{addr[1]}"
    return "its listen address"


class FirstDatagram:
    """Notes the runner's socket (``local``, set by the session) and the first datagram it
    receives: the startup wait of ``--startup-timeout`` ends there."""

    def __init__(self, awaited: str = "its Mission_Ready, or an ACK of a probe") -> None:
        self._awaited = awaited  # what the node's first datagram is (the session's ``first_awaited``)
        self.local: Any = None
        self.seen = threading.Event()

    def __call__(self, direction: str, data: bytes, addr: Any, t_ns: int | None = None,
                 run_delay: int | None = None) -> None:
        if direction == "rx":
            self.seen.set()

    def awaited(self) -> str:
        return self._awaited

    def waiting_text(self) -> str:
        return f"waiting for the node's first datagram ({self.awaited()}) on {listen_text(self.local)}"


class Tee:
    """A recorder for the session that feeds the MCAP recorder (if any), the printer and the
    first-datagram watch."""

    def __init__(self, recorder: Any, printer: TrafficPrinter | None,
                 watch: FirstDatagram | None = None) -> None:
        self._recorder = recorder
        self._printer = printer
        self._watch = watch

    def datagram(self, direction: str, data: bytes, addr: Any, t_ns: int | None = None,
                 run_delay: int | None = None, local: Any = None) -> None:
        """``local``: the runner's socket, when not the recorder's (a manager instance of
        its own, ``harness.manager_side``)."""
        if self._recorder is not None:  # (the node's run delay only when known: MCP-RTX-3)
            kw: dict[str, Any] = {}
            if run_delay is not None:
                kw["run_delay"] = run_delay
            if local is not None:
                kw["local"] = local
            self._recorder.datagram(direction, data, addr, t_ns, **kw)
        if self._printer is not None:
            self._printer(direction, data, addr, t_ns)
        if self._watch is not None:
            self._watch(direction, data, addr, t_ns)

    @property
    def local(self) -> Any:
        """The recorder's ``local`` address (set by the session to its socket's)."""
        return self._recorder.local if self._recorder is not None else None

    @local.setter
    def local(self, addr: Any) -> None:
        if self._recorder is not None:
            self._recorder.local = addr
        if self._watch is not None:
            self._watch.local = addr

    def __getattr__(self, name: str) -> Any:
        if self._recorder is not None:
            return getattr(self._recorder, name)
        return lambda *a, **kw: None  # nothing records: every other recording call is a no-op


class WaitStatus:
    """A spinner with what the runner waits for, shown once a wait passes 2 s."""

    def __init__(self, console: Console) -> None:
        self.console = console
        self.enabled = console.is_terminal
        self.plain_allowed = True  # off a terminal, a wait begun with plain=True prints lines
        self._text: str | None = None
        self._render: Any = None  # a callable giving the text, when it changes as the wait goes
        self._until: threading.Event | None = None
        self._then: str | None = None
        self._total: float | None = None
        self._plain = False
        self._printed = 0.0
        self._since = 0.0
        self._status: Any = None
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    @property
    def current(self) -> str | None:
        return self._text

    def begin(self, text: Any, total: float | None = None, plain: bool = False,
              until: threading.Event | None = None, then: str | None = None) -> None:
        """Show ``text`` (a string, or a callable giving it) once the wait passes 2 s, with
        the seconds waited (``of total``). ``plain``: off a terminal, print it as a line at
        once and every ``PLAIN_EVERY_S`` until ``end``. Once ``until`` is set, what was
        waited for came: show ``then`` instead, with no total and no more plain lines."""
        plain = plain and not self.console.is_terminal and self.plain_allowed
        if not self.enabled and not plain:
            return
        render = text if callable(text) else None
        with self._lock:
            self._until, self._then = until, then
            self._text, self._render, self._since = (render() if render else text), render, time.monotonic()
            # the first plain line at the first tick: by then the session has bound its socket
            self._total, self._plain, self._printed = total, plain, self._since - PLAIN_EVERY_S
        if self._thread is None:
            self._thread = threading.Thread(target=self._tick, name="mcp-conform-status", daemon=True)
            self._thread.start()

    def end(self) -> None:
        """Stop showing (call before printing a result line)."""
        with self._lock:
            self._text, self._render, self._plain = None, None, False
            status, self._status = self._status, None
        if status is not None:
            status.stop()

    def close(self) -> None:
        self.end()
        self._stop.set()

    def _waited(self, waited: float) -> str:
        return f"{waited:.0f} s" + (f" of {self._total:g} s" if self._total else "")

    def _line(self, waited: float) -> None:
        """A plain progress line (off a terminal)."""
        with contextlib.suppress(OSError, ValueError):
            text = self._text or ""
            self.console.print(escape(f"{text}" + (f" ({self._waited(waited)})" if waited else
                                                   (f" (up to {self._total:g} s)" if self._total else ""))),
                               soft_wrap=True, highlight=False)

    def _tick(self) -> None:
        while not self._stop.wait(0.25):
            with self._lock:
                if self._until is not None and self._until.is_set() and self._text is not None:
                    self._text, self._render, self._total, self._plain = self._then, None, None, False
                    self._until = None
                elif self._render is not None and self._text is not None:
                    self._text = self._render()
                text, since = self._text, self._since
                if text is None:
                    continue
                now = time.monotonic()
                waited = now - since
                if self._plain:
                    if now - self._printed >= PLAIN_EVERY_S:
                        self._line(waited if self._printed > since else 0.0)
                        self._printed = now
                    continue
                if waited < SHOW_AFTER_S:
                    continue
                label = f"{escape(text)} [dim]({self._waited(waited)})[/dim]"
                if self._status is None:
                    self._status = self.console.status(label)
                    self._status.start()
                else:
                    self._status.update(label)

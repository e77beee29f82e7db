"""Proof of life for the node under test, watched continuously (one place for it).

Silence proves nothing unless the node is shown alive afterwards. This module keeps the
one notion of "the node is live" the runner uses:

- **heard**: the last time a datagram attributable to the node arrived (``attributable``:
  from the node's address or carrying its MCP ID as src). Any such datagram is proof of
  life.
- **owed**: the runner sent the node a well-formed unicast command (dst = the node's ID,
  src = the manager) that a live node ACKs (MCP-ACK-1), and nothing has been heard since.
- A background watcher (every ``WATCH_INTERVAL`` s): in spawn mode it polls the process
  (an exit is noticed within 100 ms); in every mode, when an answer has been owed for
  ``--rto`` it sends its own liveness probe (WP_Off, retransmitted every ``--rto`` as a
  manager would) **from an MCP ID of its own** (``probe_src``, with its own numbering):
  duplicate detection is per source (MCP-DUP-1/3), so a probe slipped between a case's
  message and its copy cannot turn the copy into a new message for the node. When that
  probe has gone unanswered for ``--rto`` while nothing has
  been heard for ``loss_after`` (``LOSS_RTOS`` x ``--rto``, at least ``LOSS_MIN_S``), the
  node is declared **lost**. A node that ignores one kind of command but answers the probe
  is live: its missing ACK is a verdict, not a loss.
- **the mission's end**: once the runner has sent the node End_Mission ("No further
  commands", MCP-BLK-7), a process that exits with code 0 ended normally: a node may end
  after its mission (the reference node does, after ACKing copies for a linger period), and
  its ACKs of End_Mission may all have been lost before it did (a bad link, a loaded host
  late with its retransmission). That is not a loss: the wait sees the node gone and the
  exchange comes back unanswered (the End_Mission case says the ACK could not be observed:
  an error, repeated under ``--impair``). An exit before End_Mission was sent, a non-zero
  exit or a signal stays a loss.
- The case thread finds out at its next wait (``TargetDriver.wait_for`` / ``pause`` call
  ``check``), which raises ``NodeLost`` with the evidence of the last exchange. A process
  exit is declared by whichever looks first, the watcher or ``check``: a dead node is named
  dead, with its exit status, never reported as a silent one.

From a death, the loss is declared within ``loss_after`` plus the longest wait the cases
make without a command in flight (an ACK window, a vehicle settle): within 3 x rto + 2 s
for the description's timings and the embedded default's.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import Any

from mcp_conform.harness.driver import Datagram, Sent, TargetDriver
from mcp_conform.harness.errors import NodeLost
from mcp_conform.spec.codec import HEADER_SIZE, Action

LOSS_RTOS = 3.0  # declared lost after this many --rto without an answer to a probe...
LOSS_MIN_S = 2.0  # ...and never sooner than this (a loaded host, a node deaf while busy)
PROBE_SRC = 0x4C56  # the watcher's own MCP ID ("LV"): never the manager's, the node's, the cases'
WATCH_INTERVAL = 0.025  # process poll and probe clock: an exit is noticed within 100 ms
NOT_LIVE = "node not live after the window: silence proves nothing"
_ACK = int(Action.ACK)
_END = int(Action.END_MISSION)


def loss_after(rto: float) -> float:
    """How long a node may leave the runner's probes unanswered before it is declared lost."""
    return max(LOSS_RTOS * rto, LOSS_MIN_S)


def describe_exit(returncode: int | None) -> str:
    """'exited with code 3' / 'killed by signal SIGKILL' for a process's return code."""
    import signal

    if returncode is None:
        return "still running"
    if returncode < 0:
        try:
            name = signal.Signals(-returncode).name
        except ValueError:
            name = str(-returncode)
        return f"killed by signal {name}"
    return f"exited with code {returncode}"


def _sent_text(s: Sent) -> str:
    try:
        name = Action(s.action).name
    except ValueError:
        name = f"action {s.action}"
    return f"{name} dst={s.dst} seq={s.seq}"


class Liveness:
    """The watcher (see the module docstring). ``process`` is the spawned node (anything
    with ``alive()``, ``returncode`` and ``evidence()``), or None in attach mode."""

    def __init__(self, driver: TargetDriver, rto: float, target_id: Callable[[], int]) -> None:
        self.driver = driver
        self.clock = driver.clock  # the driver's (``harness.clock``): the host's, or virtual time
        self.rto = rto
        self.loss_after = loss_after(rto)
        self._target_id = target_id
        self.process: Any = None
        self.enabled = False  # probing: only between Start_Mission's ACK and End_Mission
        self.lost: NodeLost | None = None
        self.last_heard: Datagram | None = None
        self.last_heard_t = self.clock.monotonic()
        self.owed: Sent | None = None  # the oldest command sent since the node was last heard
        self.probe: Sent | None = None  # the watcher's probe in flight
        #: the runner's first well-formed End_Mission to this node: from then on an exit with
        #: code 0 is the end of its mission, not a loss (see the module docstring)
        self.end_sent: Sent | None = None
        self._probe_first = 0.0
        self._probe_last = 0.0
        self._probe_copies = 0
        self._lock = threading.RLock()
        self._stop = self.clock.event()
        self._thread: Any = None
        driver.rx_hooks.append(self._on_rx)
        driver.tx_hooks.append(self._on_tx)
        driver.check = self.check

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self._thread = self.clock.start_thread(self._run, "mcp-conform-liveness")

    def close(self) -> None:
        self._stop.set()
        if self._thread is not None and getattr(self._thread, "ident", None) != threading.get_ident():
            self._thread.join(timeout=1.0)

    def enable(self) -> None:
        """The node is receiving (its mission started): watch it from now on."""
        with self._lock:
            self.enabled = True
            self.last_heard_t = max(self.last_heard_t, self.clock.monotonic() - self.rto)

    def reset(self, process: Any = None) -> None:
        """A fresh node (spawn mode restart): forget the old one's fate."""
        with self._lock:
            self.process = process
            self.enabled = False
            self.lost = None
            self.owed = self.probe = self.end_sent = None
            self.last_heard_t = self.clock.monotonic()

    def probe_src(self) -> int:
        """The probes' src: an ID no case uses (not the manager's, the node's, the broadcast
        ID, nor the neighbours of the node's ID the cases take as "another ID")."""
        target = self._target_id()
        taken = {self.driver.our_id, target, 0xFFFF, (target + 1) & 0xFFFF, (target + 2) & 0xFFFF,
                 (target + 0x100) & 0xFFFF, 0x0ABC, 0x0ABD, 0x7777}
        src = PROBE_SRC
        while src in taken:
            src += 1
        return src

    # ------------------------------------------------------------------ attribution
    def attributable(self, d: Datagram) -> bool:
        """The datagram came from the node under test (its address, or its ID as src)."""
        if d.addr == self.driver.target:
            return True
        return d.header is not None and d.header[1] == self._target_id()

    def _on_rx(self, d: Datagram) -> None:
        if not self.attributable(d):
            return
        with self._lock:
            self.last_heard, self.last_heard_t = d, d.t
            self.owed = self.probe = None

    def _on_tx(self, s: Sent) -> None:
        if (s.action in (-1, _ACK) or s.dst != self._target_id() or s.src != self.driver.our_id
                or len(s.data) < 17):
            return
        with self._lock:
            if s.action == _END and len(s.data) == HEADER_SIZE and self.end_sent is None:
                self.end_sent = s  # End_Mission has no payload (one with a payload is malformed)
            if self.owed is None and s.t >= self.last_heard_t:
                self.owed = s

    # ------------------------------------------------------------------ the watcher
    def _run(self) -> None:
        while not self._stop.wait(WATCH_INTERVAL):
            try:
                self.tick(self.clock.monotonic())
            except OSError:
                pass  # the socket closed under us at the end of the run

    def tick(self, now: float) -> None:
        if self._tick(now):
            self._wake()

    def _tick(self, now: float) -> bool:
        """One look at the node; True when it was just declared lost."""
        send_probe = False
        resend: Sent | None = None
        with self._lock:
            if self.lost is not None:
                return False
            if self._declare_exit(now):
                return True
            if self.process is not None and not self.process.alive():
                return False  # the mission's end: the waits see the node gone
            if not self.enabled or self.owed is None:
                return False
            if self.probe is None:
                send_probe = now - self.owed.t >= self.rto
            elif now - self._probe_last >= self.rto:
                resend = self.probe
            elif now - self._probe_first >= self.rto and now - self.last_heard_t >= self.loss_after:
                self._declare(f"no answer to the runner's liveness probes for "
                              f"{now - self.last_heard_t:.1f} s (declared lost after {self.loss_after:g} s)", now)
                return True
        if send_probe:
            s = self.driver.send(Action.WP_OFF, None, self._target_id(), src=self.probe_src())
            with self._lock:
                if self.owed is not None and self.probe is None:
                    self.probe, self._probe_first, self._probe_last, self._probe_copies = s, s.t, s.t, 1
        elif resend is not None:
            s = self.driver.resend(resend)
            with self._lock:
                self._probe_last = s.t
                self._probe_copies += 1
        return False

    def _declare_exit(self, now: float) -> bool:
        """Declare the spawned node lost when its process has ended other than at its
        mission's end (under ``_lock``); True when it just was."""
        proc = self.process
        if self.lost is not None or proc is None or proc.alive() or self.ended_normally():
            return False
        self._declare(f"the node process {describe_exit(proc.returncode)}", now, exited=True)
        return True

    def ended_normally(self) -> bool:
        """The spawned node exited with code 0 after the runner sent it End_Mission: the end of
        its mission, not a loss (MCP-BLK-7: End_Mission is the last command it gets)."""
        proc = self.process
        return (proc is not None and self.end_sent is not None and not proc.alive()
                and proc.returncode == 0)

    def _declare(self, why: str, now: float, exited: bool = False) -> None:
        ev = []
        if self.last_heard is not None:
            ev.append(f"last heard from the node {now - self.last_heard_t:.2f} s before: "
                      f"{self.last_heard.describe()}")
        else:
            ev.append("nothing heard from the node since it was started")
        if self.owed is not None:
            ev.append(f"unanswered since {now - self.owed.t:.2f} s: {_sent_text(self.owed)}")
        if self.probe is not None:
            ev.append(f"liveness probe {_sent_text(self.probe)}: {self._probe_copies} copies "
                      f"{self.rto:g} s apart, unanswered")
        if self.process is not None:
            ev += self.process.evidence()
        self.lost = NodeLost(why, ev, process_exited=exited)

    def _wake(self) -> None:
        """Wake the case thread's wait (outside our lock: the receiver takes them the other way)."""
        with self.driver._cond:
            self.driver._cond.notify_all()

    # ------------------------------------------------------------------ the case thread
    def check(self) -> None:
        """Raise ``NodeLost`` when the node was declared lost while it was being watched
        (during a startup phase the session judges the process itself: a setup error).

        A process that has ended is declared here too, whichever thread looks first: the
        case thread's own waits see the process gone (``TargetDriver.alive``) as soon as the
        watcher does, and the watcher's declaration takes a moment (its evidence waits for
        the node's last output). A case that found its node dead before the watcher had said
        so went on to an unanswered liveness probe and ended "it answers no liveness probe
        either" instead of naming the exit (CI, ``test_spawn_node_killed_mid_run_at_the_
        descriptions_timings``: a SIGKILL reported as silence)."""
        if not self.enabled:
            return
        if self.lost is None and self.process is not None and not self.process.alive():
            with self._lock:  # the watcher may be declaring it: its declaration is the one
                self._declare_exit(self.clock.monotonic())
        lost = self.lost
        if lost is not None:
            raise lost

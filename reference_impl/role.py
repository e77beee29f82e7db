"""What the drone and manager roles of ``mcp-node`` share: the role's errors (``RoleError``,
with the exit code), the endpoint's events as log lines (``EventLogger``), the node's MCP
endpoint, capture and stop (``RoleNode``), and the record a role writes (``write_record``).
Neither role module imports the other; both import this one."""

from __future__ import annotations

import json
import logging
import sys
import threading
import time
from typing import Any

from mcp_conform.reference_impl.api import Mcp
from mcp_conform.reference_impl.events import (
    AckSent,
    DeliveryConfirmed,
    DeliveryFailed,
    DuplicateDiscarded,
    Event,
    Malformed,
    MessageDelivered,
    Retransmitted,
    Unexpected,
)
from mcp_conform.spec.codec import BROADCAST_ID, Action

__all__ = ["EventLogger", "RoleError", "RoleNode", "action_name", "write_record"]


class RoleError(Exception):
    """A setup problem the command line reports in one line (bad URL, port, no heartbeat)."""

    def __init__(self, message: str, exit_code: int = 2) -> None:
        super().__init__(message)
        self.exit_code = exit_code


def action_name(action: int) -> str:
    """``Action.WP_LIST`` -> ``"WP_List"``: the description's spelling, for logs and records."""
    try:
        name = Action(action).name
    except ValueError:
        return str(action)
    return "_".join(w if w in ("WP", "ACK", "ANY") else w.capitalize() for w in name.split("_"))


# ---------------------------------------------------------------------- event log
class EventLogger:
    """Logs each endpoint event as one readable line (the CLI's progress output).

    Called in the ``Mcp`` network thread, so it only formats and writes. Malformed input is
    rate-limited (``burst`` lines a second, then one summary), so a flood (MCP-ROB-7)
    does not turn the log into the bottleneck.
    """

    def __init__(self, log: logging.Logger, burst: int = 20) -> None:
        self.log = log
        self.burst = burst
        self._window = 0
        self._in_window = 0
        self._suppressed = 0

    def __call__(self, ev: Event) -> None:
        log = self.log
        if isinstance(ev, MessageDelivered):
            m = ev.msg
            cast = " (broadcast)" if m.dst == BROADCAST_ID else ""
            log.info("received %s seq %d from %d%s", action_name(m.action), m.seq, m.src, cast)
        elif isinstance(ev, AckSent):
            log.info("ACK sent for seq %d to %d", ev.acked_seq, ev.dst)
        elif isinstance(ev, DuplicateDiscarded):
            log.info("duplicate %s seq %d from %d: ACKed, not delivered again (%s)",
                     action_name(ev.msg.action), ev.msg.seq, ev.msg.src, ev.rule)
        elif isinstance(ev, Retransmitted):
            log.info("retransmitted seq %d to %d (copy %d)", ev.seq, ev.dst, ev.copy)
        elif isinstance(ev, DeliveryConfirmed):
            log.debug("seq %d ACKed by %d after %d cop%s", ev.seq, ev.dst, ev.copies,
                      "y" if ev.copies == 1 else "ies")
        elif isinstance(ev, DeliveryFailed):
            log.warning("seq %d to %d never ACKed after %d copies (%s)", ev.seq, ev.dst, ev.copies, ev.rule)
        elif isinstance(ev, Malformed):
            self._malformed(ev)
        elif isinstance(ev, Unexpected):
            what = action_name(ev.msg.action) + f" seq {ev.msg.seq} from {ev.msg.src}" if ev.msg else "input"
            # Shared-port deployments see every other drone's traffic: not-for-us is routine.
            level = logging.DEBUG if ev.rule == "MCP-ACK-5" else logging.INFO
            log.log(level, "ignored %s: %s (%s)", what, ev.reason, ev.rule)

    def _malformed(self, ev: Malformed) -> None:
        second = int(time.monotonic())
        if second != self._window:
            if self._suppressed:
                self.log.info("... %d more malformed datagrams dropped", self._suppressed)
            self._window, self._in_window, self._suppressed = second, 0, 0
        self._in_window += 1
        if self._in_window > self.burst:
            self._suppressed += 1
            return
        self.log.info("dropped malformed datagram (%d bytes) from %s: %s (%s)",
                      len(ev.data), _addr(ev.addr), ev.reason, ev.rule)


def _addr(addr: Any) -> str:
    if isinstance(addr, tuple) and len(addr) >= 2:
        return f"{addr[0]}:{addr[1]}"
    return str(addr)


class RoleNode:
    """What both roles share: the MCP endpoint, the ``listening`` event, the outcome, and a
    thread-safe ``stop()`` (also what Ctrl-C/SIGTERM do in the CLI)."""

    def __init__(self) -> None:
        self.mcp: Mcp | None = None
        self.listening = threading.Event()
        self.outcome = "running"
        self._stop = threading.Event()
        self.capture: Any = None

    def _open_capture(self, path: str | None, role: str, node_id: int, rto: float | None = None, *,
                      live: tuple[str, int] | None = None, **meta: Any) -> Any:
        """The node's MCAP capture (``--capture``), written off the hot path; None without.
        ``live`` (``--live``, issue 24): the writer process also serves the capture's channels
        over the Foxglove WebSocket protocol (a writer of no file without ``--capture``); the
        ``ws://`` URL goes to stderr.

        Its metadata says the capture is complete (the node's socket sees every datagram
        the node sends and receives) and gives the node's retransmission timeout, so
        ``mcp-capture check`` judges its absences (MCP-RTX-1) with the node's own timing."""
        if not path and live is None:
            return None
        from mcp_conform.spec import SPEC
        from mcp_conform.traceio.background import BackgroundRecorder
        from mcp_conform.traceio.recorder import RecorderError, run_metadata

        timeout = float(SPEC.params["timeout_s"]) if rto is None else float(rto)
        try:
            # the MCAP header names the writer: readers tell a node's own capture from a
            # test harness's (judge.judging: a harness's datagrams are its input, not judged)
            self.capture = BackgroundRecorder(path or None, library="mcp-node", live=live, metadata=run_metadata(
                "mcp-node", role=role, node_id=node_id, argv=" ".join(sys.argv),
                # --impair: what reached the far end is not what the node's socket saw
                complete="false" if meta.get("impair") else "true",
                parameters={"rto": timeout}, **meta))
        except RecorderError as exc:
            raise RoleError(str(exc)) from None
        if self.capture.live_url is not None:
            print(f"mcp-node: live: {self.capture.live_url} (Foxglove: Open connection, Foxglove WebSocket)",
                  file=sys.stderr, flush=True)
        return self.capture

    def _impairment(self, spec: Any) -> Any:
        """``--impair``: the schedule for this node's socket edge (None: a clean link)."""
        if spec is None:
            return None
        from mcp_conform.harness.impair import Impairment

        logging.getLogger(self.__class__.__name__.lower()).info("impaired link: %s", spec.text())
        return Impairment(spec)

    def _capture_bound(self) -> None:
        """The MCP socket is bound: it is the capture's ``local`` address."""
        if self.capture is not None and self.mcp is not None:
            self.capture.local = self.mcp.local_address

    def _close_capture(self) -> None:
        capture, self.capture = self.capture, None
        if capture is not None:
            capture.close()

    @property
    def port(self) -> int:
        assert self.mcp is not None
        return self.mcp.local_port

    def _on_stop(self) -> None:
        """Wake whatever the role waits on (before the endpoint closes)."""

    def stop(self) -> None:
        """End ``run`` early; a blocked unicast send then raises McpException."""
        self._stop.set()
        if self.outcome == "running":
            self.outcome = "stopped"
        self._on_stop()
        mcp = self.mcp
        if mcp is not None:
            mcp.close()



def write_record(path: str, record: dict[str, Any], log: logging.Logger) -> None:
    """Write ``record`` as JSON to ``path`` (atomically enough: one write); log on failure."""
    try:
        with open(path, "w", encoding="utf-8") as fh:
            json.dump(record, fh, indent=1, sort_keys=True)
            fh.write("\n")
    except OSError as exc:
        log.error("cannot write the record to %s: %s", path, exc.strerror)

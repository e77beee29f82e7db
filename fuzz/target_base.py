"""What the node under fuzz is in every role (``fuzz.drone_target`` for a drone,
``fuzz.manager_target`` for a Mission Manager): the runner's session and driver, a record of
all traffic for the oracles, the liveness probe's outcome, and the spawned process's fate.
Neither role's target imports the other's; ``fuzz.targets`` picks one.

Silence by design costs no timeout (issue 11, boofuzz#533): a valid probe goes right behind a
batch of inputs; its ACK proves the node is live and, since a node handles its datagrams in
order, that whatever it was going to say about the batch has been said.
"""

from __future__ import annotations

import signal
import threading
import time
from dataclasses import dataclass
from typing import Any

from mcp_conform.harness.driver import Datagram, Sent, TargetDriver
from mcp_conform.harness.errors import SetupError
from mcp_conform.spec import SPEC

__all__ = ["AFTER_FLAW", "DIED", "MISSION_ENDED", "PROBE_COPIES", "PROBE_MIN_WAIT", "REPLAY", "WITHHELD_START", "Probe",
           "Restarts", "TargetBase", "TargetLost", "Traffic", "TrafficRecord"]

#: The probe and its retransmissions, one --rto apart, before "not live": MCP-ROB-5/6 ("it
#: still ACKs the next valid unicast") depend on MCP-ACK-1, observed across up to 5 copies
#: ("a node may be deaf while busy, D-6"); a live node pays one round trip.
PROBE_COPIES = int(SPEC.params["max_ack_copies"])
PROBE_MIN_WAIT = 0.5  # s: a busy node on a loaded host gets at least this per copy


@dataclass(frozen=True)
class TrafficRecord:
    """One datagram the fuzzer sent (``tx``) or received (``rx``)."""

    direction: str
    t_ns: int
    data: bytes
    addr: tuple[str, int]
    run_delay: int | None = None  # the spawned node's run delay as it came (MCP-RTX-3)


class Traffic:
    """Every datagram in and out, in arrival order, for the monitor (thread-safe append)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pending: list[TrafficRecord] = []

    def __call__(self, direction: str, data: bytes, addr: tuple[str, int], t_ns: int,
                 run_delay: int | None = None) -> None:
        with self._lock:
            self._pending.append(TrafficRecord(direction, t_ns, data, addr, run_delay))

    def drain(self) -> list[TrafficRecord]:
        """What came since the last drain, in time order."""
        with self._lock:
            out, self._pending = self._pending, []
        out.sort(key=lambda r: r.t_ns)
        return out


class TargetLost(SetupError):
    """Attach mode: the node stopped answering and there is no other to fuzz or to replay on
    (issue 19 item 1: a campaign that ran on against a killed node reported its silence as
    confirmed findings). The campaign ends with what it found until then, exit 2."""


#: Why a node is restarted (counted per reason in the summary; issue 18 item 9: a campaign
#: that restarted a correct node 34-86 times in 30 s did not say why).
REPLAY = "a replay on a fresh node (triage)"
DIED = "the node died or stopped answering"
MISSION_ENDED = "its mission ended (End_Mission)"
WITHHELD_START = "a startup with Mission_Ready's ACK withheld"
NEW_TURN = "the stateful engine's turn (a node its ledger knows from its start)"
AFTER_FLAW = "the stateful engine goes on after a flaw (a node its ledger knows from its start)"


class Restarts:
    """A worker's target's restarts, counted by reason (summary.json's ``restarts_by_reason``,
    the last line; issue 18 item 9: a campaign that restarted a correct node 34-86 times in
    30 s did not say why): every protocol's (MCP's :class:`TargetBase`, MAVLink's and Nsqd's
    ``fuzz.loop.WorkerTarget``)."""

    def __init__(self) -> None:
        self.restarts = 0
        self.restart_reasons: dict[str, int] = {}

    def count_restart(self, reason: str) -> None:
        """One more restart, and why."""
        self.restarts += 1
        self.restart_reasons[reason] = self.restart_reasons.get(reason, 0) + 1


@dataclass(frozen=True)
class Probe:
    """The outcome of one liveness probe."""

    acked: bool
    sent: Sent
    copies: int
    ack: Datagram | None


class TargetBase(Restarts):
    """The node under fuzz, whatever its role: ``session`` (the runner's, of that role),
    ``run_cfg``, ``traffic``, its restarts counted by reason (:class:`Restarts`); the role's
    subclass starts it (:meth:`start`), gives a fresh node (:meth:`respawn`) and its probe
    (:meth:`probe_send`)."""

    def __init__(self, cfg: Any, run_cfg: Any, session: Any) -> None:
        super().__init__()
        self.cfg, self.run_cfg, self.session = cfg, run_cfg, session
        self.traffic = Traffic()
        #: what the oracles had to do to observe as the rules say, counted (``fuzz.oracles``:
        #: missing ACKs retransmitted, and answered on a retransmission)
        self.observations: dict[str, int] = {}
    #: the engines that fuzz this role (``--engine``; the first is its default when
    #: it cannot take ``both``)
    ENGINES: tuple[str, ...] = ("stateless", "stateful", "both")
    #: the node's retransmission period, measured at its first start (None: not measured),
    #: and the sentence saying it disagrees with --rto (None: it agrees)
    node_period: float | None = None
    timing: str | None = None

    def start(self) -> None:
        """Start (or attach to) the node; SetupError with a one-line reason otherwise."""
        raise NotImplementedError

    def impairment_spoiled(self) -> list[str]:
        """``--impair``: what the link did, since the last exchange judged, that can spoil
        an observation (a drop, a copy, a reordering, a corruption, a long delay); [] on a
        clean link. Each call starts the next window, and counts a spoiled one
        (``unjudged``)."""
        drv = self.session.driver
        link = drv.link if drv is not None else None
        if link is None:
            return []
        now = time.monotonic()
        since = getattr(self, "_judged_until", None)
        self._judged_until = now
        spoiled = [ev.describe() for ev in link.touched(now - 60.0 if since is None else since, now)]
        if spoiled:
            self.unjudged = getattr(self, "unjudged", 0) + 1
        return spoiled

    def restart(self, reason: str) -> None:
        """A fresh node (spawn mode: :meth:`respawn`), for ``reason``, counted; in attach mode
        the same node is all there is."""
        if not self.spawned:
            return
        self.respawn()
        self.count_restart(reason)

    def respawn(self) -> None:
        """The role's fresh node, started (spawn mode)."""
        raise NotImplementedError

    def probe(self, copies: int = PROBE_COPIES) -> Probe:
        """The role's valid unicast (:meth:`probe_send`), retransmitted every --rto (at least
        ``PROBE_MIN_WAIT``) until ACKed: proof of life."""
        sent = self.probe_send()
        ex = self.driver.exchange(sent, rto=max(self.rto, PROBE_MIN_WAIT), copies=copies)
        return Probe(ex.acked, sent, len(ex.copies), ex.ack)

    def probe_send(self) -> Sent:
        """The role's probe, sent once."""
        raise NotImplementedError

    def close(self) -> None:
        self.session.close()

    @property
    def spawned(self) -> bool:
        return self.session.spawned

    @property
    def driver(self) -> TargetDriver:
        assert self.session.driver is not None, "target not started"
        return self.session.driver

    @property
    def node_id(self) -> int:
        assert self.session.target_id is not None
        return self.session.target_id

    @property
    def vehicle(self):  # noqa: ANN201 - vehicle.SimVehicle or None
        return self.session.vehicle

    @property
    def rto(self) -> float:
        return self.run_cfg.rto

    @property
    def ack_window(self) -> float:
        return self.run_cfg.ack_window

    @property
    def broadcast_id(self) -> int:
        return self.run_cfg.broadcast_id

    def alive(self) -> bool:
        return self.session.alive()

    @property
    def ended(self) -> bool:
        return self.session.ended

    # ------------------------------------------------------------------ process fate
    def fate(self) -> dict[str, object]:
        """What the spawned process did: exit code, signal, its last stderr lines."""
        node = self.session.node
        if node is None:
            return {"spawned": False}
        rc = node.returncode
        out: dict[str, object] = {"spawned": True, "alive": rc is None, "exit_code": rc}
        if rc is not None and rc < 0:
            try:
                out["signal"] = signal.Signals(-rc).name
            except ValueError:
                out["signal"] = str(-rc)
        out["stderr_tail"] = node.output_tail(8)
        return out

    def check_live(self, why: str) -> None:
        """Attach mode: the liveness probe is ACKed, or ``TargetLost`` naming the node and
        ``why`` it was probed (a finding needs a live node before its input; in spawn mode
        every replay starts a fresh node, whose startup proves it live)."""
        if self.spawned:
            return
        if not self.probe().acked:
            host, port = self.driver.target
            raise TargetLost(f"the node at {host}:{port} stopped answering (no ACK of the liveness probe "
                             f"{why}); attach mode has no other node, so the campaign ends here")

    def wait_quiet(self, gap: float = 0.05, limit: float = 1.0) -> None:
        self.driver.quiet(gap=gap, limit=limit)

    def settle(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))

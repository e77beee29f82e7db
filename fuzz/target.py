"""The node under fuzz: the runner's session (spawn, restart, vehicle, embedded default) and
driver, plus what a fuzzer needs on top: a record of all traffic for the oracles, the
liveness probe, and the spawned process's fate.

Silence by design costs no timeout (issue 11, boofuzz#533): a valid probe, a WP_Off unicast
to the node, goes right behind a batch of inputs; its ACK proves the node is live and, since
a node handles its datagrams in order, that whatever it was going to say about the batch has
been said.
"""

from __future__ import annotations

import signal
import threading
import time
from dataclasses import dataclass

from fuzz.config import FuzzConfig
from fuzz.oracles import acked_seq
from harness.driver import Datagram, Sent, TargetDriver
from harness.session import Session
from spec.codec import Action

__all__ = ["FuzzTarget", "Probe", "Traffic", "TrafficRecord", "Withheld"]

PROBE_COPIES = 3  # the probe and two retransmissions, one --rto apart, before "not live"
PROBE_MIN_WAIT = 0.5  # s: a busy node on a loaded host gets at least this per copy
READY_LIMIT = 20.0  # s: a fresh node's first Mission_Ready comes within this
_READY = int(Action.MISSION_READY)


@dataclass(frozen=True)
class TrafficRecord:
    """One datagram the fuzzer sent (``tx``) or received (``rx``)."""

    direction: str
    t_ns: int
    data: bytes
    addr: tuple[str, int]


class Traffic:
    """Every datagram in and out, in arrival order, for the monitor (thread-safe append)."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._pending: list[TrafficRecord] = []

    def __call__(self, direction: str, data: bytes, addr: tuple[str, int], t_ns: int) -> None:
        with self._lock:
            self._pending.append(TrafficRecord(direction, t_ns, data, addr))

    def drain(self) -> list[TrafficRecord]:
        """What came since the last drain, in time order."""
        with self._lock:
            out, self._pending = self._pending, []
        out.sort(key=lambda r: r.t_ns)
        return out


@dataclass(frozen=True)
class Withheld:
    """A fresh node's Mission_Ready while its ACK was withheld, then given out of order."""

    copies: list[Datagram]  # the copies seen before the wrong ACK
    after_wrong_ack: Datagram | None  # a copy after the ACK of another seq (there must be one)


@dataclass(frozen=True)
class Probe:
    """The outcome of one liveness probe."""

    acked: bool
    sent: Sent
    copies: int
    ack: Datagram | None


class FuzzTarget:
    """One node under fuzz (one per ``--jobs`` worker)."""

    def __init__(self, cfg: FuzzConfig) -> None:
        self.cfg = cfg
        self.run_cfg = cfg.run_config()
        self.session = Session(self.run_cfg)
        self.traffic = Traffic()
        self.restarts = 0

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Start (or attach to) the node; SetupError with a one-line reason otherwise."""
        self.session.start(observe_startup=False)
        s = self.session
        assert s.driver is not None
        # the fuzzer judges with its own oracles, its probe behind each batch being the proof
        # of life: the runner's background watcher and whole-run monitor would judge every
        # datagram a second time and send probes of their own into the batches
        if s.monitor is not None:
            s.driver.remove_observer(s.monitor.observe)
            s.monitor = None
        if s.liveness is not None:
            s.liveness.close()
            s.liveness = None
            s.driver.check = lambda: None
        s.driver.add_observer(self.traffic)
        if self.session.target_id is None:
            self.session.target_id = 1

    def close(self) -> None:
        self.session.close()

    def restart(self) -> None:
        """A fresh node (spawn mode); in attach mode the same node is all there is."""
        if not self.spawned:
            return
        self.session.restart()
        self.restarts += 1

    def restart_withholding(self, copies: int) -> Withheld:
        """Spawn mode: a fresh node whose Mission_Ready is left unACKed for ``copies`` copies,
        then ACKed out of order (an ACK naming another seq first, then the right one); the
        mission is started again. Returns what was seen (judged by
        ``fuzz.oracles.judge_withheld``: MCP-RTX-1/2, MCP-SEQ-2)."""
        s, drv = self.session, self.driver
        if s.node is not None:
            s.node.close()
        s.restarts += 1
        self.restarts += 1
        s.ended = s.needs_restart = False
        mark = drv.mark()
        drv.auto_ack = lambda d: d.action != _READY
        try:
            s._spawn()
            limit = time.monotonic() + READY_LIMIT + (copies + 1) * max(self.rto, 0.05) * 2
            while time.monotonic() < limit and self.alive():
                got = [d for d in drv.received(mark) if d.action == _READY]
                if len(got) >= copies:
                    break
                drv.wait_for(lambda d: d.action == _READY, 0.1, drv.mark())
            got = [d for d in drv.received(mark) if d.action == _READY]
            after_wrong: Datagram | None = None
            if got and got[-1].header is not None:
                dst, src, seq, _ = got[-1].header
                wrong = drv.send_ack((seq - 1) & 0xFFFF, dst=src)  # another seq's ACK (MCP-RTX-2)
                after_wrong = drv.wait_for(lambda d: d.action == _READY and d.t > wrong.t,
                                           2.5 * max(self.rto, 0.05) + 0.2, drv.mark_before(wrong))
                last = after_wrong if after_wrong is not None and after_wrong.header else got[-1]
                drv.send_ack(last.header[2], dst=src)  # type: ignore[index]
        finally:
            drv.auto_ack = lambda d: True
        s._start_mission(False)
        return Withheld(got, after_wrong)

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

    # ------------------------------------------------------------------ probing
    def probe(self, copies: int = PROBE_COPIES) -> Probe:
        """A WP_Off unicast to the node, retransmitted every --rto, until ACKed."""
        drv = self.driver
        sent = drv.send(Action.WP_OFF, None, self.node_id)
        ex = drv.exchange(sent, rto=max(self.rto, PROBE_MIN_WAIT), copies=copies)
        if ex.ack is not None and acked_seq(ex.ack) != sent.seq:
            # the reply taken for the probe's ACK does not name the probe (judge.attribution
            # ties it by arrival: a wrong payload, or an earlier input's ACK arriving late);
            # let the node's other replies arrive too, so the judge sees every ACK it sent
            drv.quiet(gap=0.05, limit=max(self.rto, PROBE_MIN_WAIT))
        return Probe(ex.acked, sent, len(ex.copies), ex.ack)

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

    def wait_quiet(self, gap: float = 0.05, limit: float = 1.0) -> None:
        self.driver.quiet(gap=gap, limit=limit)

    def settle(self, seconds: float) -> None:
        time.sleep(max(0.0, seconds))

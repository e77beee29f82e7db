"""A drone under fuzz: the runner's drone session (spawn, restart, vehicle, embedded
default) started without its own watcher and monitor, the liveness probe (a WP_Off unicast
to the node behind each batch, ``fuzz.target_base``), and a fresh node whose Mission_Ready
is withheld (MCP-RTX-1/2, MCP-SEQ-2)."""

from __future__ import annotations

import time
from dataclasses import dataclass

from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.oracles import acked_seq
from mcp_conform.fuzz.target_base import (
    PROBE_COPIES,
    PROBE_MIN_WAIT,
    WITHHELD_START,
    Probe,
    TargetBase,
)
from mcp_conform.harness.driver import Datagram, Sent
from mcp_conform.harness.drone_session import Session
from mcp_conform.harness.session_base import timing_note
from mcp_conform.spec.codec import Action

__all__ = ["FuzzTarget", "Withheld"]

READY_LIMIT = 20.0  # s: a fresh node's first Mission_Ready comes within this
_READY = int(Action.MISSION_READY)


@dataclass(frozen=True)
class Withheld:
    """A fresh node's Mission_Ready while its ACK was withheld, then given out of order."""

    copies: list[Datagram]  # the copies seen before the wrong ACK
    after_wrong_ack: Datagram | None  # a copy after the ACK of another seq (there must be one)


class FuzzTarget(TargetBase):
    """One drone under fuzz (one per ``--jobs`` worker)."""

    def __init__(self, cfg: FuzzConfig) -> None:
        run_cfg = cfg.run_config()
        super().__init__(cfg, run_cfg, Session(run_cfg, recorder=cfg.extra.get("live_recorder")))  # --live (fuzz.live)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Start (or attach to) the node; SetupError with a one-line reason otherwise.

        A spawned node's retransmission period is measured from its first Mission_Ready
        copies; when it disagrees with --rto the campaign says so (``timing``) and judges by
        what the node does: the probes, oracles and replays take the node's period (issue 18
        item 10: at --rto 5 against a node retransmitting every 0.3 s the fuzzer ran 63
        cases/s, restarted the node 27 times and gave a false MUST finding)."""
        self.session.start(observe_startup=False, watch=False, measure=self.session.spawned)
        s = self.session
        assert s.driver is not None
        self.node_period = s.period
        self.timing = timing_note(s.period, self.run_cfg.rto, 2,
                                  f"probes and oracles take the node's {s.period or 0:.2f} s")
        if self.timing is not None and s.period is not None:
            self.run_cfg.rto = s.period
        s.driver.add_observer(self.traffic)
        if self.session.target_id is None:
            self.session.target_id = 1

    def respawn(self) -> None:
        self.session.restart()

    def restart_withholding(self, copies: int) -> Withheld:
        """Spawn mode: a fresh node whose Mission_Ready is left unACKed for ``copies`` copies,
        then ACKed out of order (an ACK naming another seq first, then the right one); the
        mission is started again. Returns what was seen (judged by
        ``fuzz.oracles.judge_withheld``: MCP-RTX-1/2, MCP-SEQ-2). Under ``--impair`` this
        one observation runs on a clean link (the link paused): a lost copy is not MCP-RTX-1."""
        s, drv = self.session, self.driver
        self.count_restart(WITHHELD_START)
        drv.auto_ack = lambda d: d.action != _READY
        link = drv.link
        if link is not None:
            link.paused = True
        try:
            s.respawn()
            # from the new node's start (``spawn_mark``, taken once the old one was stopped):
            # a late copy of the old one's Mission_Ready is not the new one's
            mark = s.spawn_mark if s.spawn_mark is not None else drv.mark()
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
            if link is not None:
                link.paused = False
        s.send_start_mission()
        return Withheld(got, after_wrong)

    # ------------------------------------------------------------------ probing
    def probe(self, copies: int = PROBE_COPIES) -> Probe:
        """A WP_Off unicast to the node, retransmitted every --rto, until ACKed
        (``TargetBase.probe``)."""
        p = super().probe(copies)
        if p.ack is not None and acked_seq(p.ack) != p.sent.seq:
            # the reply taken for the probe's ACK does not name the probe (judge.attribution
            # ties it by arrival: a wrong payload, or an earlier input's ACK arriving late);
            # let the node's other replies arrive too, so the judge sees every ACK it sent
            self.driver.quiet(gap=0.05, limit=max(self.rto, PROBE_MIN_WAIT))
        return p

    def probe_send(self) -> Sent:
        return self.driver.send(Action.WP_OFF, None, self.node_id)


"""A Mission Manager under fuzz (``mcp-fuzz --role manager``): the fuzzer plays drones.

The manager is kept in its receiving phase: every drone of the fuzz mission but one has
announced itself (Mission_Ready, ACKed), the last one never does, so the manager waits for
it and must keep receiving and ACKing whatever the drones send. The held-back drone's ID is
one the mutators never write as a source. Cases come from drone 1 (the generator's
``our_id``) to ID 0; the liveness probe is a fresh Mission_Ready from drone 1, awaited
across retransmissions. The oracles are the stateless engine's: replies per input, the
probe, the process's fate, and the trace monitor keeping the manager's (ID 0) violations.

Only the stateless engine drives a manager (the stateful engine's programs are a manager's
commands to a drone).
"""

from __future__ import annotations

from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.target_base import TargetBase
from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.driver import Sent
from mcp_conform.harness.errors import SetupError
from mcp_conform.harness.manager_session import ManagerSession, embedded_command
from mcp_conform.spec.codec import MANAGER_ID, Action

__all__ = ["FUZZ_DRONES", "ManagerFuzzTarget"]

#: Drone 1 speaks; drone 9029 is held back (no mutator writes it as a source).
FUZZ_DRONES = (1, 9029)


def run_config(cfg: FuzzConfig) -> RunConfig:
    """The runner's configuration of the manager: the drone role's, adapted."""
    rc = cfg.run_config()
    rc.role, rc.drones, rc.challenge, rc.mavlink = "manager", FUZZ_DRONES, 1, False
    if cfg.embedded:
        rc.spawn = embedded_command() + " --quiet"
    return rc


class ManagerFuzzTarget(TargetBase):
    """One manager under fuzz: a manager session, readiness instead of the drone's startup,
    and a Mission_Ready for the liveness probe."""

    #: the stateful engine's programs are a manager's commands to a drone
    ENGINES = ("stateless",)

    def __init__(self, cfg: FuzzConfig) -> None:  # noqa: D107 - no drone session
        run_cfg = run_config(cfg)
        super().__init__(cfg, run_cfg, ManagerSession(run_cfg, recorder=cfg.extra.get("live_recorder")))

    def start(self) -> None:
        self.session.open()  # type: ignore[attr-defined]
        self.driver.our_id = FUZZ_DRONES[0]  # the generator's source: a ready drone
        self.driver.add_observer(self.traffic)
        self.respawn()

    def respawn(self) -> None:
        """A fresh manager (spawn mode) that has heard drone 1 announce itself."""
        if self.spawned:
            self.session.respawn()
        limit = max(20.0, 4 * self.rto + 5.0) if self.spawned else 2.5 * self.rto + 1.0
        sent = self.driver.send(Action.MISSION_READY, None, MANAGER_ID, src=FUZZ_DRONES[0])
        ex = self.driver.exchange(sent, rto=self.rto, copies=max(3, int(limit / self.rto) + 1))
        if not ex.acked:
            ev = self.session.node_evidence()
            raise SetupError(f"the manager never ACKed Mission_Ready within {limit:.1f} s"
                             + (f"; {ev[0]}" if ev else ""))
        self.driver.quiet(gap=0.05, limit=min(1.0, self.ack_window))

    def probe_send(self) -> Sent:
        """A fresh Mission_Ready from drone 1 (``TargetBase.probe``: retransmitted every --rto, until ACKed)."""
        return self.driver.send(Action.MISSION_READY, None, MANAGER_ID, src=FUZZ_DRONES[0])

"""A busy drone in the simulator (issue 38): a node whose worker carries out its commands one
after another and waits out a take-off before the next, as the C++ drone of
``examples/mcp_cpp/drone`` does (its ``wait_altitude``: 95 % of the altitude, at most 60 s).

D-6 allows a node that is busy; MCP-BLK-7 asks it to finish its pending actions, then command
RTL. With a high take-off (:func:`busy_drone_factory`'s ``takeoff_alt``; the vehicle climbs at
``vehicle.model.VehicleConfig.climb_rate``, 20 m/s: 150 m is some 7.5 s) the Mav_Passthrough
frames the runner sends right after Start_Mission reach the autopilot only once the climb is
over, and End_Mission's RTL follows it. A correct node all the same: the runner's cases must
judge it as one (MCP-DUP-1..4, MCP-PAY-8, MCP-SEQ-3 judged, not skipped; MCP-BLK-7 passed).
"""

from __future__ import annotations

import random
from collections.abc import Callable

from mcp_conform.sim.autopilot import AutopilotClient, Flow
from mcp_conform.sim.models import DroneModel
from mcp_conform.spec import SPEC

__all__ = ["BusyAutopilot", "BusyDrone", "busy_drone_factory"]

#: how long the worker waits for the take-off's altitude (the C++ drone's ``wait_altitude`` limit)
CLIMB_LIMIT_S = 60.0


class BusyAutopilot(AutopilotClient):
    """The reference drone's autopilot client whose take-off job ends only at the altitude
    (95 % of it, as the client reads GLOBAL_POSITION_INT), bounded by :data:`CLIMB_LIMIT_S`: every
    job queued behind it (a forward, the RTL) waits for the climb."""

    def _job_takeoff(self, alt: float) -> Flow:
        yield from super()._job_takeoff(alt)
        if self.target_alt is not None:
            yield from self._until(lambda: self.target_alt is None, CLIMB_LIMIT_S)


class BusyDrone(DroneModel):
    """The reference drone model on :class:`BusyAutopilot`; ``forwards`` False: it ACKs
    Mav_Passthrough but forwards nothing (the sample node's ``--no-passthrough``, a correct node
    whose delivery is unobservable); ``rtl`` False: no RTL on End_Mission (MCP-BLK-7's fault)."""

    forwards = True
    rtl = True

    def make_autopilot(self, addr: tuple[str, int]) -> AutopilotClient:
        return BusyAutopilot(addr)

    def forward(self, frame: bytes) -> None:
        if self.forwards:
            super().forward(frame)

    def end_mission(self, now: float) -> None:
        if self.rtl or self.autopilot is None:
            super().end_mission(now)
        # else no RTL; main() still waits for the work queued before, then lingers


def busy_drone_factory(takeoff_alt: float, *, rto: float = 0.2, seed: int = 0, ready_after: float = 0.05,
                       forwards: bool = True, rtl: bool = True) -> Callable[[float], DroneModel]:
    """A fresh :class:`BusyDrone` for each spawn (``sim.runner``'s factory) taking off to
    ``takeoff_alt`` m on Start_Mission, its endpoint at ``rto``; ``forwards``, ``rtl``: see
    :class:`BusyDrone`."""
    retries = int(SPEC.params["retries"])
    spawns = random.Random(seed)

    def make(now: float) -> DroneModel:
        model = BusyDrone(1, rto, retries, random.Random(spawns.getrandbits(64)), ready_at=now + ready_after)
        model.takeoff_alt, model.forwards, model.rtl = takeoff_alt, forwards, rtl
        return model

    make.__name__ = (f"busy-drone-{takeoff_alt:g}m" + ("" if forwards else "-no-passthrough")
                     + ("" if rtl else "-no-rtl"))
    return make

"""The reference drone reaching the simulated vehicle over UDP (udp:, udpin:, udpout: URLs),
a whole session: heartbeat both ways, fix, GUIDED, arm, mission upload (WP_List) with the
mission protocol's handshake, RTL; the vehicle's request records show each request."""

from __future__ import annotations

from typing import Any

import pytest

from mcp_conform.spec.codec import Action
from mcp_conform.vehicle import start_for_node
from tests.reference_impl import test_drone as td
from tests.reference_impl.test_drone import ITEM, FakePeer, ready

manager = td.manager  # the fixtures, shared
drone_factory = td.drone_factory

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("transport", ["udp", "udpin", "udpout", "tcp"])
def test_session_over_each_transport(transport: str, manager: FakePeer, drone_factory: Any) -> None:
    vehicle, url = start_for_node(transport, fix_withheld=True)
    try:
        assert url.startswith(transport + ":")
        run = drone_factory(url)
        assert vehicle.wait_for(lambda: vehicle.connected, 10), "the drone never spoke to the vehicle"
        assert run.drone.link is not None and run.drone.link.heartbeat.wait(10)
        ready(manager, vehicle)
        manager.command(Action.START_MISSION)
        manager.command(Action.WP_LIST, (ITEM, ITEM._replace(seq=2, x=35.7712, y=-78.6745)))
        assert vehicle.wait_for(lambda: len(vehicle.mission) == 3, 10)
        manager.command(Action.END_MISSION)
        assert vehicle.wait_for(lambda: vehicle.rtl_commanded, 10)
        assert run.join() == 0
        assert vehicle.frames("HEARTBEAT"), "no HEARTBEAT from the drone"
        reqs = [e.detail for e in vehicle.events("request")]
        named = {(r["request"], r.get("mode")): r["result"] for r in reqs}
        assert named[("mode", "GUIDED")] == named[("arm", None)] == "accepted"
        assert named[("rtl", "RTL")] == "accepted"
        items = [r for r in reqs if r["request"] == "mission_item"]
        assert [r["seq"] for r in items] == [0, 1, 2]
        assert items[-1]["answer"] == "MISSION_ACK MAV_MISSION_ACCEPTED"
        assert run.drone.link.mission_result == 0
    finally:
        vehicle.close()

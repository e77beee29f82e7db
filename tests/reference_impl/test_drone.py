"""The drone role in-process, against a fake manager (a plain UDP socket using spec.codec)
and the simulated vehicle as its autopilot (MCP-BLK-4/5/7, MCP-FLOW-1, MCP-PAY-2/8)."""

from __future__ import annotations

import socket
import threading
import time
from collections.abc import Iterator
from typing import Any

import pytest

from mcp_conform.reference_impl.drone import Drone, DroneConfig, RoleError, action_name
from mcp_conform.spec.codec import (
    MANAGER_ID,
    Action,
    DecodeError,
    Message,
    MissionItem,
    decode,
    encode,
)
from mcp_conform.vehicle import SimVehicle, make_probe
from tests.capturing import free_port

RTO = 0.2
ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 2, 19, 1, 1, 3, 0, 1)


class FakePeer:
    """The other side of a node: a UDP socket on loopback speaking MCP through spec.codec."""

    def __init__(self, src: int = MANAGER_ID, seq: int = 100) -> None:
        self.src = src
        self.seq = seq
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.port = self.sock.getsockname()[1]
        self.received: list[tuple[Message, Any]] = []
        self.to: tuple[str, int] | None = None

    def close(self) -> None:
        self.sock.close()

    def recv(self, timeout: float) -> tuple[Message, Any] | None:
        """The next well-formed message within ``timeout`` s (also kept in ``received``)."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            self.sock.settimeout(left)
            try:
                data, addr = self.sock.recvfrom(65535)
            except TimeoutError:
                return None
            try:
                msg = decode(data)
            except DecodeError:
                continue
            self.received.append((msg, addr))
            return msg, addr
        return None

    def expect(self, action: Action, timeout: float = 10.0) -> tuple[Message, Any] | None:
        """The next message of type ``action`` (others are kept in ``received`` and skipped)."""
        deadline = time.monotonic() + timeout
        while (left := deadline - time.monotonic()) > 0:
            got = self.recv(left)
            if got is not None and got[0].action == action:
                return got
        return None

    def send(self, action: Action, payload: Any = None, dst: int = 1, seq: int | None = None) -> int:
        if seq is None:
            self.seq = (self.seq + 1) & 0xFFFF
            seq = self.seq
        assert self.to is not None
        self.sock.sendto(encode(Message(dst, self.src, seq, action, payload)), self.to)
        return seq

    def ack(self, msg: Message, to: Any) -> None:
        self.seq = (self.seq + 1) & 0xFFFF
        self.sock.sendto(encode(Message(msg.src, self.src, self.seq, Action.ACK, msg.seq)), to)

    def command(self, action: Action, payload: Any = None, dst: int = 1, seq: int | None = None,
                copies: int = 20) -> int:
        """Send until the matching ACK arrives (a bounded number of copies); returns the seq."""
        seq = self.send(action, payload, dst, seq)
        for _ in range(copies):
            deadline = time.monotonic() + 0.3
            while (left := deadline - time.monotonic()) > 0:
                got = self.recv(left)
                if got and got[0].action == Action.ACK and got[0].payload == seq and got[0].src == dst:
                    return seq
            self.send(action, payload, dst, seq)
        raise AssertionError(f"{action_name(action)} seq {seq} never ACKed")


@pytest.fixture
def vehicle() -> Iterator[SimVehicle]:
    v = SimVehicle(fix_withheld=True)
    v.start()
    try:
        yield v
    finally:
        v.close()


@pytest.fixture
def manager() -> Iterator[FakePeer]:
    peer = FakePeer()
    try:
        yield peer
    finally:
        peer.close()


class Running:
    """A Drone running in a thread; ``stop()`` and join in teardown."""

    def __init__(self, drone: Drone) -> None:
        self.drone = drone
        self.code: int | None = None
        self.error: BaseException | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        assert drone.listening.wait(10), "drone never bound its MCP socket"

    def _run(self) -> None:
        try:
            self.code = self.drone.run()
        except BaseException as exc:  # noqa: BLE001 - reported by the test
            self.error = exc

    def join(self, timeout: float = 15.0) -> int | None:
        self.thread.join(timeout)
        assert not self.thread.is_alive(), "drone did not finish"
        if self.error is not None:
            raise self.error
        return self.code


def start_drone(manager: FakePeer, url: str | None, **kw: Any) -> Running:
    cfg = DroneConfig(drone_id=kw.pop("drone_id", 1), bind_host="127.0.0.1", local_port=0,
                      remote_host="127.0.0.1", remote_port=manager.port, mavlink_url=url, rto=RTO, **kw)
    run = Running(Drone(cfg))
    manager.to = ("127.0.0.1", run.drone.port)
    return run


@pytest.fixture
def drone_factory(manager: FakePeer) -> Iterator[Any]:
    runs: list[Running] = []

    def make(url: str | None, **kw: Any) -> Running:
        run = start_drone(manager, url, **kw)
        runs.append(run)
        return run

    try:
        yield make
    finally:
        for run in runs:
            run.drone.stop()
            run.thread.join(10)


def ready(manager: FakePeer, vehicle: SimVehicle | None = None) -> Message:
    """Give the fix (if a vehicle is given), await Mission_Ready and ACK it."""
    if vehicle is not None:
        vehicle.give_fix()
    got = manager.expect(Action.MISSION_READY, 15)
    assert got is not None, "no Mission_Ready"
    manager.ack(got[0], got[1])
    return got[0]


def test_no_mission_ready_before_the_fix(vehicle: SimVehicle, manager: FakePeer, drone_factory: Any) -> None:
    run = drone_factory(vehicle.url)
    assert vehicle.wait_for(lambda: vehicle.connected, 10)
    assert run.drone.link is not None and run.drone.link.heartbeat.wait(10)
    assert manager.expect(Action.MISSION_READY, 1.0) is None  # 5 x --rto with no fix: silence
    msg = ready(manager, vehicle)
    assert vehicle.has_fix
    assert (msg.dst, msg.src, msg.payload) == (MANAGER_ID, 1, None)  # MCP-FLOW-1, MCP-PAY-2
    assert run.drone.ready_acked.wait(5)


def test_mission_ready_is_retransmitted_with_the_same_seq_until_acked(
        vehicle: SimVehicle, manager: FakePeer, drone_factory: Any) -> None:
    run = drone_factory(vehicle.url)
    vehicle.give_fix()
    copies = [manager.expect(Action.MISSION_READY, 10) for _ in range(3)]
    assert all(c is not None for c in copies)
    seqs = {c[0].seq for c in copies if c is not None}
    assert len(seqs) == 1  # MCP-SEQ-2
    assert not run.drone.ready_acked.is_set()
    assert copies[-1] is not None
    manager.ack(copies[-1][0], copies[-1][1])
    assert run.drone.ready_acked.wait(5)


def test_arms_only_after_start_mission(vehicle: SimVehicle, manager: FakePeer, drone_factory: Any) -> None:
    run = drone_factory(vehicle.url, takeoff_alt=7.0)
    ready(manager, vehicle)
    assert run.drone.ready_acked.wait(5)
    manager.command(Action.WP_LIST, (ITEM,))  # a command that is not Start_Mission
    time.sleep(0.5)
    assert not vehicle.armed and not vehicle.events("arm")  # MCP-BLK-4
    manager.command(Action.START_MISSION)
    assert vehicle.wait_for(lambda: vehicle.armed, 10)
    assert vehicle.mode == "GUIDED"
    assert vehicle.wait_for(lambda: any(e.detail.get("accepted") for e in vehicle.events("takeoff")), 10)
    assert [e.detail["alt"] for e in vehicle.events("takeoff")] == [7.0]


def test_passthrough_reaches_the_vehicle_once_despite_a_duplicate(
        vehicle: SimVehicle, manager: FakePeer, drone_factory: Any) -> None:
    drone_factory(vehicle.url)
    ready(manager, vehicle)
    seq = manager.command(Action.MAV_PASSTHROUGH, make_probe("dupA"))
    manager.command(Action.MAV_PASSTHROUGH, make_probe("dupA"), seq=seq)  # same seq: a duplicate, ACKed
    manager.command(Action.MAV_PASSTHROUGH, make_probe("dupB"))
    # frames are forwarded in delivery order, so once B is there a second A would be too
    assert vehicle.wait_for(lambda: vehicle.probe_count("dupB") == 1, 10)
    assert vehicle.probe_count("dupA") == 1  # MCP-PAY-8, MCP-DUP-1


def test_end_mission_commands_rtl_and_exits_zero(vehicle: SimVehicle, manager: FakePeer,
                                                 drone_factory: Any) -> None:
    run = drone_factory(vehicle.url)
    ready(manager, vehicle)
    manager.command(Action.START_MISSION)
    manager.command(Action.WP_ON, ITEM)
    manager.command(Action.WP_OFF)
    manager.command(Action.OBSTACLES_LIST, (ITEM, ITEM._replace(seq=3)))
    seq = manager.command(Action.END_MISSION)
    assert vehicle.wait_for(lambda: vehicle.rtl_commanded, 10)  # MCP-BLK-7
    manager.command(Action.END_MISSION, seq=seq)  # a lost ACK: the copy is ACKed while lingering
    assert run.join() == 0
    arm_t = vehicle.first_time("arm")
    rtl_t = vehicle.first_time("rtl")
    assert arm_t is not None and rtl_t is not None and arm_t < rtl_t
    rec = run.drone.record()
    assert rec["outcome"] == "end_mission"
    assert rec["received"] == {"Start_Mission": 1, "WP_On": 1, "WP_Off": 1, "Obstacles_List": 1,
                               "End_Mission": 1}
    assert (rec["obstacles"], rec["active_waypoints"], rec["rtl"], rec["armed"]) == (2, 0, True, True)


def test_builtin_vehicle_and_record_file(manager: FakePeer, drone_factory: Any, tmp_path: Any) -> None:
    path = tmp_path / "rec.json"
    run = drone_factory(None, gps_fix_delay=0.3, record_path=str(path), drone_id=3)
    msg = ready(manager)
    assert msg.src == 3
    manager.command(Action.WP_LIST, (ITEM, ITEM), dst=3)
    manager.command(Action.END_MISSION, dst=3)
    assert run.join() == 0
    assert run.drone.vehicle is not None and run.drone.vehicle.rtl_commanded
    import json

    rec = json.loads(path.read_text())
    assert rec["received"] == {"WP_List": 1, "End_Mission": 1} and rec["waypoints"] == 2


def test_survives_losing_the_autopilot(manager: FakePeer, drone_factory: Any) -> None:
    v = SimVehicle()
    v.start()
    try:
        run = drone_factory(v.url)
        ready(manager)
    finally:
        v.close()
    assert run.drone.link is not None
    deadline = time.monotonic() + 10
    while not run.drone.link.lost and time.monotonic() < deadline:
        time.sleep(0.05)
    assert run.drone.link.lost
    manager.command(Action.MAV_PASSTHROUGH, make_probe("lost"))  # still ACKed (MCP-ROB-5)
    manager.command(Action.END_MISSION)
    assert run.join() == 0
    assert run.drone.record()["forwarded"] == 0


def test_stop_while_waiting_for_the_fix(vehicle: SimVehicle, manager: FakePeer, drone_factory: Any) -> None:
    run = drone_factory(vehicle.url)
    assert vehicle.wait_for(lambda: vehicle.connected, 10)
    run.drone.stop()
    assert run.join() == 0
    assert run.drone.outcome == "stopped"
    assert manager.expect(Action.MISSION_READY, 0.3) is None


def test_unreachable_autopilot_is_a_role_error(manager: FakePeer) -> None:
    port = free_port(socket.SOCK_STREAM)  # nothing listens there now
    cfg = DroneConfig(drone_id=1, bind_host="127.0.0.1", local_port=0, remote_host="127.0.0.1",
                      remote_port=manager.port, mavlink_url=f"tcp:127.0.0.1:{port}", rto=RTO)
    with pytest.raises(RoleError, match="cannot connect to the autopilot"):
        Drone(cfg).run()


@pytest.mark.parametrize("bad", [0, 0xFFFF, -1, 70000])
def test_bad_drone_id(bad: int) -> None:
    with pytest.raises(RoleError):
        DroneConfig(drone_id=bad)


def test_end_mission_right_after_start_mission_arms_then_rtls_and_the_record_says_so(
        vehicle: SimVehicle, manager: FakePeer, drone_factory: Any) -> None:
    """End_Mission at once after Start_Mission, faster than the autopilot answers: the drone
    finishes the pending arm and takeoff, then commands RTL (MCP-BLK-7: "finishes pending
    actions, then commands RTL"). The vehicle then lands and disarms while the drone lingers
    (long here: a loaded host's slow exit), and the record still says the drone armed: it
    records what the drone did, not the autopilot's state when it exits (issue 19 item 9:
    test_e2e's ``armed`` was false under load)."""
    run = drone_factory(vehicle.url, linger=3.0)
    ready(manager, vehicle)
    manager.send(Action.START_MISSION)
    manager.command(Action.END_MISSION)
    assert run.join(30) == 0
    arm_t, rtl_t = vehicle.first_time("arm"), vehicle.first_time("rtl")
    assert arm_t is not None and rtl_t is not None and arm_t < rtl_t
    assert vehicle.events("landed") and not vehicle.armed  # landed and disarmed before the drone exited
    rec = run.drone.record()
    assert rec["outcome"] == "end_mission" and rec["received"] == {"Start_Mission": 1, "End_Mission": 1}
    assert rec["armed"] and rec["rtl"]


def test_the_delivery_log_is_bounded_and_counts_the_rest(monkeypatch):
    """bench/bench_soak.py: the drone's RSS grew 61 -> 134 MiB over 10^6 impaired commands, every
    delivery kept for the record; past MAX_DELIVERIES they are counted (memory flat), and
    mcp-soak says a log with omissions cannot prove exactly-once."""
    import logging

    from mcp_conform.reference_impl import drone as drone_mod

    monkeypatch.setattr(drone_mod, "MAX_DELIVERIES", 5)
    app = drone_mod.DroneApp(None, logging.getLogger("t"), 10.0)
    for seq in range(8):
        app.handle_wp_off_message(None, Message(1, 0, seq, Action.WP_OFF, None))
    assert [d[2] for d in app.deliveries] == [0, 1, 2, 3, 4] and app.deliveries_omitted == 3
    assert app.counts["WP_Off"] == 8

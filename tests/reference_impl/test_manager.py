"""The manager role in-process against fake drones (one UDP socket speaking spec.codec for
every drone ID): MCP-BLK-2/3/6, MCP-FLOW-2..6."""

from __future__ import annotations

import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from mcp_conform.reference_impl.drone import RoleError
from mcp_conform.reference_impl.manager import Manager, ManagerConfig
from mcp_conform.spec.codec import ITEM, MANAGER_ID, Action, Message, MissionItem
from mcp_conform.spec.mission import load_waypoints
from tests.reference_impl.test_drone import FakePeer

DATA = Path(__file__).parent / "data"
WAYPOINTS = load_waypoints(DATA / "challenge.waypoints")
OBSTACLES = load_waypoints(DATA / "obstacles.waypoints")
RTO = 0.2


def wire(items: tuple[Any, ...]) -> tuple[Any, ...]:
    """The items as they arrive: floats through float32 (MCP-PAY-4)."""
    return tuple(MissionItem._make(ITEM.unpack(ITEM.pack(*it))) for it in items)


class RunningManager:
    def __init__(self, mgr: Manager) -> None:
        self.mgr = mgr
        self.code: int | None = None
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()
        assert mgr.listening.wait(10)

    def _run(self) -> None:
        self.code = self.mgr.run()

    def join(self, timeout: float = 20.0) -> int | None:
        self.thread.join(timeout)
        assert not self.thread.is_alive(), "manager did not finish"
        return self.code


@pytest.fixture
def drones() -> Iterator[FakePeer]:
    peer = FakePeer(src=1)
    try:
        yield peer
    finally:
        peer.close()


@pytest.fixture
def start(drones: FakePeer) -> Iterator[Any]:
    runs: list[RunningManager] = []

    def make(**kw: Any) -> RunningManager:
        kw.setdefault("drones", (1, 2))
        kw.setdefault("waypoints", WAYPOINTS)
        cfg = ManagerConfig(bind_host="127.0.0.1", local_port=0, remote_host="127.0.0.1",
                            remote_port=drones.port, rto=RTO, **kw)
        run = RunningManager(Manager(cfg))
        drones.to = ("127.0.0.1", run.mgr.port)
        runs.append(run)
        return run

    try:
        yield make
    finally:
        for run in runs:
            run.mgr.stop()
            run.thread.join(10)


def mission_ready(drones: FakePeer, src: int) -> None:
    """Send Mission_Ready from ``src`` until the manager ACKs it (MCP-FLOW-2)."""
    drones.src = src
    drones.command(Action.MISSION_READY, None, dst=MANAGER_ID)


def play(drones: FakePeer, ids: tuple[int, ...], *, deaf: tuple[int, ...] = (), limit: float = 20.0,
         ) -> list[Message]:
    """ACK every command to ``ids`` (except to ``deaf``) until each got End_Mission (or ``limit``).

    Returns the commands in arrival order, each new (dst, seq) once.
    """
    seen: set[tuple[int, int]] = set()
    out: list[Message] = []
    ended: set[int] = set()
    deadline = time.monotonic() + limit
    while set(ids) - set(deaf) - ended and time.monotonic() < deadline:
        got = drones.recv(0.5)
        if got is None or got[0].action == Action.ACK or got[0].dst not in ids:
            continue
        msg, addr = got
        if msg.dst not in deaf:
            drones.src = msg.dst
            drones.ack(msg, addr)
        if (msg.dst, msg.seq) not in seen:
            seen.add((msg.dst, msg.seq))
            out.append(msg)
            if msg.action == Action.END_MISSION:
                ended.add(msg.dst)
    return out


def kinds(msgs: list[Message]) -> list[tuple[str, int]]:
    return [(Action(m.action).name, m.dst) for m in msgs]


def test_nothing_is_sent_before_every_drone_is_ready(drones: FakePeer, start: Any) -> None:
    run = start(challenge=1)
    mission_ready(drones, 1)
    mission_ready(drones, 7)  # not in this mission: ACKed, but it does not count
    assert drones.expect(Action.START_MISSION, 1.0) is None  # MCP-BLK-2
    assert not [m for m, _ in drones.received if m.action != Action.ACK]
    mission_ready(drones, 2)
    msgs = play(drones, (1, 2))
    assert kinds(msgs)[:2] == [("START_MISSION", 1), ("START_MISSION", 2)]
    assert run.join() == 0
    assert run.mgr.record()["ready"] == [1, 2]


def test_challenge_1_sends_one_wp_list_then_end_mission(drones: FakePeer, start: Any) -> None:
    run = start(challenge=1)
    mission_ready(drones, 2)
    mission_ready(drones, 1)
    msgs = play(drones, (1, 2))
    assert kinds(msgs) == [("START_MISSION", 1), ("START_MISSION", 2), ("WP_LIST", 1), ("WP_LIST", 2),
                           ("END_MISSION", 1), ("END_MISSION", 2)]  # MCP-FLOW-4, MCP-FLOW-3
    assert msgs[2].payload == wire(WAYPOINTS) and msgs[3].payload == wire(WAYPOINTS)
    assert all(m.src == MANAGER_ID for m in msgs)
    assert run.join() == 0


def test_challenge_2_turns_each_waypoint_on_then_off(drones: FakePeer, start: Any) -> None:
    run = start(challenge=2, drones=(1,))
    mission_ready(drones, 1)
    msgs = play(drones, (1,))
    expected = [("START_MISSION", 1)]
    for _ in WAYPOINTS:
        expected += [("WP_ON", 1), ("WP_OFF", 1)]  # MCP-FLOW-5
    assert kinds(msgs) == expected + [("END_MISSION", 1)]
    assert tuple(m.payload for m in msgs if m.action == Action.WP_ON) == wire(WAYPOINTS)
    assert run.join() == 0


def test_challenge_3_sends_the_obstacles(drones: FakePeer, start: Any) -> None:
    run = start(challenge=3, drones=(1,), obstacles=OBSTACLES)
    mission_ready(drones, 1)
    msgs = play(drones, (1,))
    assert kinds(msgs) == [("START_MISSION", 1), ("OBSTACLES_LIST", 1), ("END_MISSION", 1)]  # MCP-FLOW-6
    assert msgs[1].payload == wire(OBSTACLES)
    assert run.join() == 0


def test_no_command_before_start_mission_is_acked(drones: FakePeer, start: Any) -> None:
    run = start(challenge=1, drones=(1,))
    mission_ready(drones, 1)
    copies = [drones.expect(Action.START_MISSION, 5) for _ in range(3)]  # not ACKed: retransmitted
    assert all(c is not None for c in copies)
    assert len({c[0].seq for c in copies if c is not None}) == 1
    assert [m.action for m, _ in drones.received if m.action != Action.ACK] == [Action.START_MISSION] * 3  # MCP-BLK-3
    msgs = play(drones, (1,))
    assert kinds(msgs) == [("START_MISSION", 1), ("WP_LIST", 1), ("END_MISSION", 1)]
    assert run.join() == 0


def test_a_drone_that_never_acks_is_dropped(drones: FakePeer, start: Any) -> None:
    run = start(challenge=1, drones=(1, 2), retries=2)
    mission_ready(drones, 1)
    mission_ready(drones, 2)
    msgs = play(drones, (1, 2), deaf=(1,))
    assert [k for k in kinds(msgs) if k[1] == 1] == [("START_MISSION", 1)]  # nothing after the failure
    assert [k for k in kinds(msgs) if k[1] == 2] == [("START_MISSION", 2), ("WP_LIST", 2), ("END_MISSION", 2)]
    assert run.join() == 1
    assert run.mgr.record()["failed"] == [1]


def test_ready_timeout(drones: FakePeer, start: Any) -> None:
    run = start(challenge=1, drones=(1, 2), ready_timeout=0.5)
    mission_ready(drones, 1)
    assert run.join() == 1
    assert run.mgr.outcome == "not_ready"


def test_stop_while_waiting(start: Any) -> None:
    run = start(challenge=1)
    run.mgr.stop()
    assert run.join() == 0
    assert run.mgr.outcome == "stopped"


@pytest.mark.parametrize("kw, match", [
    ({"challenge": 4}, "challenge"),
    ({"challenge": 1, "drones": ()}, "no drones"),
    ({"challenge": 1, "drones": (1, 1)}, "repeat"),
    ({"challenge": 1, "drones": (0,)}, "drone ID"),
    ({"challenge": 1, "waypoints": ()}, "waypoints"),
    ({"challenge": 3}, "obstacles"),
])
def test_bad_config(kw: dict[str, Any], match: str) -> None:
    kw.setdefault("drones", (1,))
    kw.setdefault("waypoints", WAYPOINTS)
    with pytest.raises(RoleError, match=match):
        ManagerConfig(**kw)


def test_data_files_load() -> None:
    assert len(WAYPOINTS) == 5 and WAYPOINTS[0].x == pytest.approx(35.771332)
    assert len(OBSTACLES) >= 1

"""harness.drone_players: the runner's drones answer each copy of the manager's datagrams once,
whichever of its threads gets to it, and the mission records the earliest ACK of each seq
(MCP-ACK-1; MCP-BLK-1 ends a wait at "its ACK", the first the manager got).

The two threads are the case thread (``DronePlayers.answer``: the withheld Start_Mission's
right ACK) and the driver's receiver thread (``DronePlayers.on_datagram``). The tests
interleave them as a loaded host does (issue 38; the simulator's seeds in
tests/sim/test_manager_blk_sim.py): a real driver over an in-memory transport whose send of an
ACK lets the other thread's step run before the sender goes on (taken off the CPU after its
ACK left, before it recorded it), and a receiver thread that reaches a copy only after the case
thread, woken by it, answered it.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from typing import Any

from mcp_conform.harness.driver import TargetDriver
from mcp_conform.harness.drone_players import MANAGER_ID, DronePlayers, Mission
from mcp_conform.harness.transport import Transport
from mcp_conform.spec.codec import HEADER_SIZE, Action, Message, encode, peek_header

_ACK = int(Action.ACK)
_U16 = struct.Struct("!H")
MANAGER = ("127.0.0.1", 7889)


class PausingTransport(Transport):
    """In memory: what leaves is kept; once an ACK has left, ``after_ack`` (if set) runs first
    -- the sender off the CPU while another thread runs."""

    poll = 0.01

    def __init__(self) -> None:
        self.sent: list[bytes] = []
        self.after_ack: Callable[[], None] | None = None

    def bind(self, listen: Any) -> Any:
        return ("127.0.0.1", 1)

    def sendto(self, data: bytes, addr: Any) -> int:
        self.sent.append(data)
        head = peek_header(data)
        if head is not None and head[3] == _ACK and self.after_ack is not None:
            step, self.after_ack = self.after_ack, None
            step()
        return len(data)

    def recv(self) -> tuple[bytes, Any, int | None]:
        raise TimeoutError

    def getsockname(self) -> Any:
        return ("127.0.0.1", 1)

    def close(self) -> None:
        pass


def _setup() -> tuple[TargetDriver, PausingTransport, DronePlayers, Mission]:
    tr = PausingTransport()
    drv = TargetDriver(MANAGER, ("127.0.0.1", 0), transport=tr)
    drv.auto_ack = lambda d: False
    drv.open()
    players = DronePlayers(drv, (1, 2), 1000)
    drv.on_datagram = players.on_datagram
    m = Mission("main", (1, 2), 1, None, None)
    players.reset(m)
    players.withhold_first_start = True
    return drv, tr, players, m


def _acks_naming(tr: PausingTransport, drone: int, seq: int) -> int:
    return sum(1 for data in tr.sent if (h := peek_header(data)) is not None and h[3] == _ACK
               and h[1] == drone and _U16.unpack_from(data, HEADER_SIZE)[0] == seq)


def _start(seq: int, drone: int = 1) -> bytes:
    return encode(Message(drone, MANAGER_ID, seq, Action.START_MISSION, None))


def test_a_copy_the_case_thread_answered_is_not_answered_again_by_the_receiver():
    """The copy wakes the case thread, which releases the drone and ACKs it; the receiver
    thread, preempted between waking it and letting the players answer, reaches it after the
    release: it does not ACK it again (it did: issue 38's seeds 9 and 13)."""
    drv, tr, players, m = _setup()
    try:
        drv._arrive(_start(100), MANAGER)  # withheld
        assert _acks_naming(tr, 1, 100) == 0
        on_datagram, drv.on_datagram = drv.on_datagram, None
        drv._arrive(_start(100), MANAGER)  # recorded, the case thread woken; the players not yet
        copy = drv.received(0)[-1]
        right = players.answer(copy, release=True)
        assert right is not None
        on_datagram(copy)  # the receiver thread gets the CPU back
        assert _acks_naming(tr, 1, 100) == 1 and m.declined == 1
        assert m.acks[(1, 100)] is right
        # and the other way round: a copy the players answered is not the case thread's to answer
        drv.on_datagram = on_datagram
        drv._arrive(_start(100), MANAGER)
        assert _acks_naming(tr, 1, 100) == 2  # a later copy: its own ACK (MCP-ACK-1)
        assert players.answer(drv.received(0)[-1]) is None
        assert _acks_naming(tr, 1, 100) == 2 and m.acks[(1, 100)] is right  # still the earliest
    finally:
        drv.close()


def test_the_earliest_ack_is_recorded_whatever_order_the_threads_record_in():
    """The case thread's ACK leaves, and before it records it the receiver thread answers a later
    copy of the same seq and records its ACK: the mission keeps the case thread's, the first
    the manager got (the later one was kept before: the wait looked longer than it was)."""
    drv, tr, players, m = _setup()
    try:
        drv._arrive(_start(200), MANAGER)  # withheld
        copy = drv.received(0)[-1]
        tr.after_ack = lambda: drv._arrive(_start(200), MANAGER)  # the next copy, answered meanwhile
        right = players.answer(copy, release=True)
        assert right is not None and _acks_naming(tr, 1, 200) == 2  # one ACK of each copy
        later = [s for s in drv.sent() if s.action == _ACK and s is not right]
        assert len(later) == 1 and later[0].t >= right.t
        assert m.acks[(1, 200)] is right
        assert players.acked_actions[1] == {int(Action.START_MISSION)}
    finally:
        drv.close()


def test_another_drones_commands_are_answered_once_each_while_one_is_withheld():
    drv, tr, players, m = _setup()
    try:
        drv._arrive(_start(300, drone=1), MANAGER)  # withheld
        drv._arrive(_start(400, drone=2), MANAGER)
        drv._arrive(_start(400, drone=2), MANAGER)  # a copy: ACKed again (MCP-ACK-1)
        assert _acks_naming(tr, 1, 300) == 0 and _acks_naming(tr, 2, 400) == 2
        first = min((s for s in drv.sent() if s.action == _ACK), key=lambda s: s.t)
        assert m.acks[(2, 400)] is first and (1, 300) not in m.acks
    finally:
        drv.close()

"""Faulty conversations for the trace monitor: each breaks exactly one rule, once.

``FAULTY[name]`` is a :class:`Fault`: the rule the conversation must raise (and no other),
whether the monitor judges it as a complete trace, and ``build()`` returning the
:class:`~tests.judge.monitor_scripts.Script`. Every conversation is a whole mission
(or the part of one the fault allows) of the manager and two drones, built from the
script's clean phases with one step changed.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

from mcp_conform.judge.monitor import TESTER
from mcp_conform.spec.codec import PREAMBLE, Action, Message, MissionItem, build_datagram, encode
from mcp_conform.spec.mavframe import heartbeat_frame
from tests.judge.monitor_scripts import Script

__all__ = ["FAULTY", "Fault"]


class Fault(NamedTuple):
    rule: str
    build: Callable[[], Script]
    complete: bool = True


def _started(challenge: int = 1, **kw: object) -> Script:
    s = Script((1, 2), challenge=challenge, **kw)
    for d in s.drones:
        s.ready(d)
    for d in s.drones:
        s.start(d)
    return s


def _finish(s: Script, *, steps: bool = True) -> Script:
    if steps:
        s.challenge_steps()
    for d in s.drones:
        s.end(d)
    return s


# ---------------------------------------------------------------- HDR
def hdr1() -> Script:
    s = _started()
    s.tick(0.05)
    s.raw(1, PREAMBLE[:-1] + b"\x02" + bytes(10))  # drone 1's address, a wrong last preamble byte
    return _finish(s)


def hdr2() -> Script:
    s = _started()
    s.raw(2, PREAMBLE + b"\x00\x00")  # 11 bytes, the preamble and half a header
    return _finish(s)


def hdr3() -> Script:
    s = _started()
    s.raw(1, build_datagram(0, 1, s.next_seq(1), 9))  # "Any" on the wire
    return _finish(s)


def hdr4() -> Script:
    s = _started()
    seq = s.exchange(0, 2, Action.WP_OFF)
    s.ack(2, 0, seq, hdr_src=9)  # a second ACK, with a src that is not drone 2's ID
    return _finish(s)


def hdr5() -> Script:
    s = _started()
    s.exchange(1, 0, Action.WP_LIST, ())  # a drone sends a manager's command (ACKed)
    return _finish(s)


# ---------------------------------------------------------------- ACK
def ack1() -> Script:
    s = _started()
    s.exchange(0, 1, Action.WP_OFF, deaf=6)  # unanswered through 6 copies
    return _finish(s)


def ack2() -> Script:
    s = _started()

    def little(k: int, seq: int, data: bytes) -> bool:
        s.ack(1, 0, seq, little=k == 0)
        return k > 0
    s.exchange(0, 1, Action.WP_OFF, ack_hook=little)
    return _finish(s)


def ack3() -> Script:
    s = _started()

    def wrong_dst(k: int, seq: int, data: bytes) -> bool:
        s.ack(1, 0, seq, hdr_dst=0x0FFF if k == 0 else None)
        return k > 0
    s.exchange(0, 1, Action.WP_OFF, ack_hook=wrong_dst)
    return _finish(s)


def ack4() -> Script:
    s = _started(challenge=2)
    seq, _ = s.send(0, 0xFFFF, Action.WP_ON, s.items[0])
    s.tick(0.004)
    s.ack(1, 0, seq)  # drone 1 ACKs a broadcast
    s.tick(0.1)
    s.send(0, 0xFFFF, Action.WP_OFF)
    s.tick(0.1)
    return _finish(s)


def _copy_then_broadcast() -> tuple[Script, int, int]:
    """The harness's WP_Off to drone 1, ACKed; a copy of it (the ACK was late for the runner,
    a loaded host), then at once the harness's next message, a broadcast with the next seq."""
    s = _started()
    seq, data = s.send(0, 1, Action.WP_OFF, seq=40000, origin=TESTER)  # numbers of its own
    s.tick(0.004)
    s.ack(1, 0, seq)
    s.tick(0.25)
    s.raw(0, data, to=1, origin=TESTER)  # the copy
    s.tick(0.001)
    bseq, _ = s.send(0, 0xFFFF, Action.WP_OFF, seq=seq + 1, origin=TESTER)
    s.tick(0.004)
    return s, seq, bseq


def ack2_copy_acked_with_the_next_seq() -> Script:
    """Drone 1 ACKs the copy naming seq + 1 (``sample_node --fault ack-copies-wrong-seq``),
    which is the broadcast's seq: the ACK a waiting copy explains is that copy's wrong ACK
    (MCP-ACK-2), not an ACK of the broadcast (MCP-ACK-4) beside a copy never ACKed (MCP-ACK-1)."""
    s, seq, bseq = _copy_then_broadcast()
    assert bseq == (seq + 1) & 0xFFFF
    s.ack(1, 0, bseq)
    s.tick(0.5)
    return _finish(s)


def ack2_interleaved_copies_acked_with_the_next_seq() -> Script:
    """``sample_node --fault ack-copies-wrong-seq`` under a scheduled run (cases side by side):
    the copies of two ACKed WP_Offs (A, then B = A + 1) interleave. B's copy is answered
    "B + 1", the seq of the harness's message to ID 2 that reached drone 1; A's next copy
    is answered "A + 1" = B, which also reads as B's copy's ACK. Which ACK answered B's copy is
    not proven, so neither is an ACK of the message to ID 2 (MCP-ACK-5, the CI run's false
    alarm): A's copies answered with another seq are MCP-ACK-2's."""
    from mcp_conform.spec.codec import build_datagram

    s = Script((1,), challenge=1)
    s.ready(1)
    s.start(1)
    a, da = s.send(0, 1, Action.WP_OFF, seq=40000, origin=TESTER)
    s.tick(0.004)
    s.ack(1, 0, a)
    b, db = s.send(0, 1, Action.WP_OFF, seq=a + 1, origin=TESTER)
    s.tick(0.004)
    s.ack(1, 0, b)
    s.raw(0, build_datagram(2, 0, b + 1, int(Action.WP_OFF), b""), to=1, origin=TESTER)  # to ID 2
    s.tick(0.15)
    s.raw(0, da, to=1, origin=TESTER)  # A's copy, answered "B"
    s.tick(0.005)
    s.ack(1, 0, b)
    s.tick(0.04)
    s.raw(0, db, to=1, origin=TESTER)  # B's copy, answered "B + 1"
    s.tick(0.008)
    s.ack(1, 0, b + 1)
    for _ in range(2):
        s.tick(0.15)
        s.raw(0, da, to=1, origin=TESTER)  # A's copies, each answered "B"
        s.tick(0.0003)
        s.ack(1, 0, b)
    s.tick(1.5)
    return _finish(s)


def ack4_beside_a_waiting_copy() -> Script:
    """Drone 1 ACKs the broadcast while a copy waits, and then the copy with its own seq: the
    broadcast's ACK is MCP-ACK-4 all the same."""
    s, seq, bseq = _copy_then_broadcast()
    s.ack(1, 0, bseq)
    s.tick(0.003)
    s.ack(1, 0, seq)
    s.tick(0.5)
    return _finish(s)


def ack5() -> Script:
    s = _started()
    seq = s.exchange(0, 2, Action.WP_OFF)
    s.ack(1, 0, seq)  # drone 1 ACKs what was addressed to drone 2
    return _finish(s)


def ack6() -> Script:
    s = Script((1, 2))
    ready = {d: s.ready(d) for d in s.drones}
    for d in s.drones:
        s.start(d)
    s.tick(0.05)
    # a late copy of drone 1's Mission_Ready, which the manager rightly ACKs again (its ACK's
    # own number is ``own``; an ACK naming a number nobody sent would be MCP-ACK-2's)
    s.raw(1, encode(Message(0, 1, ready[1], Action.MISSION_READY, None)))
    s.tick(0.004)
    own = s.seq[0]
    s.ack(0, 1, ready[1])
    s.tick(0.004)
    s.ack(1, 0, own)  # drone 1 ACKs that ACK
    return _finish(s)


def ack7() -> Script:
    s = Script((1, 2), rto=1.0, ack_window=0.5)
    for d in s.drones:
        s.ready(d)
    for d in s.drones:
        s.start(d, ack_delay=0.3 if d == 1 else None)
    s.challenge_steps()
    for d in s.drones:
        s.end(d, ack_delay=0.3 if d == 1 else None)
    return s


# ---------------------------------------------------------------- SEQ
def seq1() -> Script:
    s = _started()
    s.seq[0] = (s.seq[0] + 5) & 0xFFFF  # the manager skips five numbers
    return _finish(s)


def seq2() -> Script:
    s = _started()
    seq = s.next_seq(0)
    # the first copy differs only in fields a waypoint file does not hold (target_system):
    # the same mission (no FLOW-4), other bytes (MCP-SEQ-2)
    first = encode(Message(1, 0, seq, Action.WP_LIST,
                           tuple(i._replace(target_system=(i.target_system + 7) % 256) for i in s.items)))
    s.raw(0, first, to=1)
    s.tick(s.rto)  # unACKed: a retransmission with other bytes
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items), seq=seq)
    s.tick(0.01)
    s.exchange(0, 2, Action.WP_LIST, tuple(s.items))
    return _finish(s, steps=False)


# ---------------------------------------------------------------- RTX
def rtx1() -> Script:
    s = _started()
    s.raw(0, encode(Message(1, 0, s.next_seq(0), Action.WP_OFF)), to=1)  # sent once, unACKed
    s.tick(s.rto)  # ... and given up at once
    return _finish(s)


def rtx2() -> Script:
    """The harness plays the manager: a wrong-seq ACK after drone 1's second copy, after which
    it stops. (After ``min_copies`` copies or more, a retry limit -- the rule's configurable
    one -- explains the stop as well: the monitor proves nothing there, and the runner's case
    tells the two apart on a restarted node, harness.drone_rtx2.)"""
    s = Script((1,), vehicle=False)
    seq, data = s.send(1, 0, Action.MISSION_READY)
    for _ in range(1):
        s.tick(s.rto)
        s.raw(1, data)
    s.tick(0.01)
    s.ack(0, 1, (seq + 0x8000) & 0xFFFF, origin=TESTER)
    s.tick(2.0)  # no copy for 2 s
    s.ack(0, 1, seq, origin=TESTER)
    return s


def _runner_drones(s: Script) -> dict[str, object]:
    """The harness plays every drone (``mcp-conform --role manager``): its datagrams are input."""
    for d in s.drones:
        s.exchange(d, 0, Action.MISSION_READY, origin=TESTER)
        s.tick(0.02)
    return {"acker_origin": TESTER}


def _manager_finishes(s: Script, kw: dict[str, object]) -> Script:
    for d in s.drones:
        s.exchange(0, d, Action.WP_LIST, tuple(s.items), **kw)
        s.tick(0.01)
    for d in s.drones:
        s.exchange(0, d, Action.END_MISSION, **kw)
    return s


def withheld_start_and_wrong_acks(wrong_seq: bool) -> tuple[Script, dict[str, object], int, bytes]:
    """Drones 1 and 2 ready; drone 1's Start_Mission sent three times unACKed, then the
    runner's wrong ACKs: the wrong seq from drone 1 (``wrong_seq``) and its seq from drone 2."""
    s = Script((1, 2), vehicle=False)
    kw = _runner_drones(s)
    seq, data = s.send(0, 1, Action.START_MISSION)
    for _ in range(2):
        s.tick(s.rto)
        s.raw(0, data, to=1)
    s.tick(0.01)
    if wrong_seq:
        s.ack(1, 0, (seq + 0x8000) & 0xFFFF, origin=TESTER)  # the wrong seq from drone 1
    s.ack(2, 0, seq, origin=TESTER)  # its seq, from drone 2
    return s, kw, seq, data


def rtx2_moves_on() -> Script:
    """A manager that takes a wrong-seq ACK for its Start_Mission's: at once, with no copy
    after it, it sends the next drone its Start_Mission; the right ACK comes 155 ms later
    (before the next copy would have been due). What it did after the wrong ACK proves it
    took it: MCP-RTX-2, not a new unicast while one awaits its ACK (MCP-BLK-1)."""
    s, kw, seq, data = withheld_start_and_wrong_acks(wrong_seq=True)
    s.tick(0.0005)
    t_moved = s.t
    s.send(0, 2, Action.START_MISSION)  # taken: the next drone's Start_Mission at once
    s.tick(0.004)
    s.ack(2, 0, s.seq[0] - 1, origin=TESTER)
    s.t = t_moved + 0.155
    s.ack(1, 0, seq, origin=TESTER)  # the right ACK
    s.tick(0.05)
    return _manager_finishes(s, kw)


def rtx2_moves_on_then_broadcasts() -> Script:
    """:func:`rtx2_moves_on`'s manager broadcasting the WP_List once drone 2's Start_Mission is
    ACKed, before drone 1's right ACK comes: drone 1's Start_Mission was answered by the wrong ACK
    it took, so the broadcast is drone 1's list too (D-11): MCP-RTX-2 alone, not MCP-FLOW-4."""
    s, kw, seq, data = withheld_start_and_wrong_acks(wrong_seq=True)
    s.tick(0.0005)
    t_moved = s.t
    seq2, _ = s.send(0, 2, Action.START_MISSION)  # taken: the next drone's Start_Mission at once
    s.tick(0.004)
    s.ack(2, 0, seq2, origin=TESTER)
    s.broadcast(Action.WP_LIST, tuple(s.items))
    s.t = t_moved + 0.155
    s.ack(1, 0, seq, origin=TESTER)  # the right ACK
    s.tick(0.05)
    for d in s.drones:
        s.exchange(0, d, Action.END_MISSION, **kw)
    return s


def rtx2_takes_a_stale_ack() -> Script:
    """A manager that takes any ACK from the destination: the runner's wrong-source ACK
    from drone 2 (sent while drone 1's Start_Mission awaited its ACK: not from drone 1, so
    drone 1's Start_Mission goes on) is still unanswered when drone 2's Start_Mission goes
    out, and the manager sends the next command at once, before drone 2's own ACK: MCP-RTX-2
    (as the cases judge it), not MCP-BLK-1. (Had it retransmitted after a wrong seq from the
    destination, it would not be taken for one that takes a stale ACK:
    ``test_a_manager_seen_ignoring_wrong_acks_that_never_waits_is_blk_3s``.)"""
    s, kw, seq, data = withheld_start_and_wrong_acks(wrong_seq=False)
    s.tick(s.rto - 0.01)
    s.raw(0, data, to=1)  # a correct retransmission: the wrong-source ACK did not end it
    s.tick(0.004)
    s.ack(1, 0, seq, origin=TESTER)
    s.tick(0.01)
    seq2, _ = s.send(0, 2, Action.START_MISSION)  # taken at once by drone 2's earlier ACK:
    s.tick(0.0005)
    s.send(0, 1, Action.WP_LIST, tuple(s.items))  # the next command, before drone 2's own ACK
    s.tick(0.002)
    s.ack(2, 0, seq2, origin=TESTER)
    s.tick(0.002)
    s.ack(1, 0, s.seq[0] - 1, origin=TESTER)
    s.tick(0.05)
    s.exchange(0, 2, Action.WP_LIST, tuple(s.items), **kw)
    s.tick(0.01)
    for d in s.drones:
        s.exchange(0, d, Action.END_MISSION, **kw)
    return s


def rtx1_gives_up_then_acked() -> Script:
    """A manager that sends Start_Mission twice, then moves on to the next drone when the
    third copy was due; the ACK of the first comes (late) after that: it gave up all the same
    (MCP-RTX-1, as the case judges it: two copies while the ACK was withheld)."""
    s = Script((1, 2), vehicle=False)
    kw = _runner_drones(s)
    seq, data = s.send(0, 1, Action.START_MISSION)
    s.tick(s.rto)
    s.raw(0, data, to=1)
    s.tick(s.rto)
    s.exchange(0, 2, Action.START_MISSION, **kw)  # the next drone, when the next copy was due
    s.tick(0.2)
    s.ack(1, 0, seq, origin=TESTER)  # drone 1's ACK, late
    s.tick(0.05)
    return _manager_finishes(s, kw)


def rtx1_gives_up_then_drops_the_drone() -> Script:
    """A manager that sends drone 1's WP_List twice, then gives up and moves on to drone 2;
    the ACK comes (late) after that, and the manager, having dropped drone 1, never sends it
    End_Mission (``sample_manager --fault give-up-after-two`` on a loaded host). The missing
    End_Mission is that give-up's consequence: MCP-RTX-1 only, not MCP-FLOW-3 beside it."""
    s = Script((1, 2), vehicle=False)
    kw = _runner_drones(s)
    for d in s.drones:
        s.exchange(0, d, Action.START_MISSION, **kw)
        s.tick(0.01)
    seq, data = s.send(0, 1, Action.WP_LIST, tuple(s.items))
    s.tick(s.rto)
    s.raw(0, data, to=1)
    s.tick(s.rto)
    s.exchange(0, 2, Action.WP_LIST, tuple(s.items), **kw)  # drone 2, when the next copy was due
    s.tick(0.2)
    s.ack(1, 0, seq, origin=TESTER)  # drone 1's ACK, late
    s.tick(0.05)
    s.exchange(0, 2, Action.END_MISSION, **kw)  # drone 1 dropped: no End_Mission
    s.tick(3.0)
    return s


def pay3_then_drops_the_drone() -> Script:
    """A manager whose WP_List count is little-endian (``sample_manager --fault le-count``):
    drone 1 rightly does not ACK it (MCP-ROB-4), the manager sends it 13 times, gives up and
    ends drone 2's mission only. MCP-PAY-3 alone: drone 1's missing End_Mission follows from
    the malformed list it did not ACK, not a second violation (MCP-FLOW-3 fired on a loaded
    host, where the trace ran on 2 s past drone 2's End_Mission)."""
    from mcp_conform.spec.codec import ITEM

    s = Script((1, 2), vehicle=False)
    kw = _runner_drones(s)
    for d in s.drones:
        s.exchange(0, d, Action.START_MISSION, **kw)
        s.tick(0.01)
    bad = (len(s.items) << 8).to_bytes(2, "big") + b"".join(ITEM.pack(*i) for i in s.items)
    data = build_datagram(1, 0, s.next_seq(0), int(Action.WP_LIST), bad)
    for _ in range(13):
        s.raw(0, data, to=1)
        s.tick(s.rto)
    s.exchange(0, 2, Action.WP_LIST, tuple(s.items), **kw)
    s.tick(0.01)
    s.exchange(0, 2, Action.END_MISSION, **kw)  # drone 1 dropped: no End_Mission
    s.tick(3.0)
    return s


def rtx3() -> Script:
    s = _started()
    s.exchange(0, 1, Action.WP_OFF, deaf=3, gaps=[0.2, 0.2, 0.5])  # one gap 2.5x the others
    return _finish(s)


def rtx3_storm() -> Script:
    s = _started()
    s.exchange(0, 1, Action.WP_OFF, deaf=2, gaps=[0.01, 0.01])  # 10 ms apart
    return _finish(s)


def rtx4() -> Script:
    s = _started(challenge=2)
    seq, data = s.send(0, 0xFFFF, Action.WP_ON, s.items[0])
    s.tick(0.2)
    s.raw(0, data, to=0xFFFF)  # a broadcast sent twice
    s.tick(0.1)
    s.send(0, 0xFFFF, Action.WP_OFF)
    s.tick(0.1)
    return _finish(s)


# ---------------------------------------------------------------- BLK
def blk1() -> Script:
    s = _started()
    seq, data = s.send(0, 1, Action.WP_LIST, tuple(s.items))
    s.tick(0.05)  # drone 1 has not ACKed yet: a new unicast to drone 2
    s.exchange(0, 2, Action.WP_LIST, tuple(s.items))
    s.tick(s.rto - 0.05)
    s.raw(0, data, to=1)
    s.tick(0.004)
    s.ack(1, 0, seq)
    return _finish(s, steps=False)


def blk2() -> Script:
    s = Script((1, 2))
    s.ready(1)
    s.start(1)  # before drone 2 said Mission_Ready
    s.ready(2)
    s.start(2)
    return _finish(s)


def blk2_start_before_that_drones_ready() -> Script:
    """A manager that sends drone 2 its Start_Mission before drone 2's Mission_Ready came
    (``sample_manager --fault start-early`` when the drone is the slower to start): MCP-BLK-2.
    The Mission_Ready that follows is drone 2's first, not a restart of its mission: the
    WP_List after it is not "a command before Start_Mission" (MCP-FLOW-2 beside BLK-2 on a
    fast host, before)."""
    s = Script((1, 2))
    s.ready(1)
    s.start(1)
    s.start(2)  # before drone 2 said Mission_Ready
    s.ready(2)
    return _finish(s)


def blk2_start_early_ack_numbered_after_it_read_first() -> Script:
    """``sample_manager --fault start-early`` with three drones (CI, side by side and --serial
    alike): it starts drone 1 before drone 3's Mission_Ready (MCP-BLK-2); while its main
    thread has taken seq N for drone 2's Start_Mission, its receive thread takes N+1 for the
    ACK of drone 3's Mission_Ready and sends it first; drone 3's Start_Mission takes N+2.
    The ACK read before the message numbered below it explains the gap N..N+2 (MCP-SEQ-1
    beside BLK-2 before)."""
    s = Script((1, 2, 3))
    s.ready(1)
    s.ready(2)
    s.start(1)  # before drone 3 said Mission_Ready
    n = s.next_seq(0)  # drone 2's Start_Mission's number
    s.vehicle(3, "link")
    s.vehicle(3, "fix")
    s.tick(0.01)
    mr, _ = s.send(3, 0, Action.MISSION_READY)
    s.tick(0.0001)
    s.ack(0, 3, mr)  # N+1, read 20 us before N
    s.tick(0.00002)
    s.start(2, seq=n)
    s.start(3)  # N+2
    return _finish(s)


def blk3() -> Script:
    s = Script((1, 2))
    for d in s.drones:
        s.ready(d)
    seq, data = s.send(0, 1, Action.START_MISSION)
    s.tick(0.05)  # not ACKed yet
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items))
    s.tick(s.rto - 0.05)
    s.raw(0, data, to=1)
    s.tick(0.004)
    s.ack(1, 0, seq)
    s.vehicle(1, "arm", ok=True)
    s.start(2)
    s.exchange(0, 2, Action.WP_LIST, tuple(s.items))
    return _finish(s, steps=False)


def blk4() -> Script:
    s = Script((1, 2))
    for d in s.drones:
        s.ready(d)
    s.vehicle(1, "arm", ok=True)  # before Start_Mission
    for d in s.drones:
        s.exchange(0, d, Action.START_MISSION)
    s.vehicle(2, "arm", ok=True)
    return _finish(s)


def blk5() -> Script:
    s = Script((1, 2))
    s.vehicle(1, "link")  # no fix yet
    s.exchange(1, 0, Action.MISSION_READY)
    s.vehicle(1, "fix")
    s.ready(2)
    for d in s.drones:
        s.start(d)
    return _finish(s)


def blk6() -> Script:
    s = _started()
    s.challenge_steps()
    s.end(1)
    s.exchange(0, 1, Action.WP_OFF)  # after drone 1's End_Mission
    s.end(2)
    return s


def blk7() -> Script:
    s = _started()
    s.challenge_steps()
    s.exchange(0, 1, Action.END_MISSION)  # drone 1 never commands RTL
    s.end(2)
    return s


# ---------------------------------------------------------------- PAY
def _bad_command(s: Script, action: Action, payload: bytes, *, origin: object = None) -> None:
    s.raw(0, build_datagram(1, 0, s.next_seq(0), int(action), payload), to=1, origin=origin)
    s.tick(s.rto)  # not ACKed (D-4); the manager moves on


def pay1() -> Script:
    s = _started()
    _bad_command(s, Action.WP_OFF, b"\x00\x01")
    return _finish(s)


def pay2() -> Script:
    s = Script((1, 2))
    bad = build_datagram(0, 1, s.next_seq(1), int(Action.MISSION_READY), b"\x00\x01\x00\x00")
    s.vehicle(1, "link")
    s.vehicle(1, "fix")
    s.raw(1, bad)  # not ACKed (D-4)
    s.tick(s.rto)
    s.raw(1, bad)
    s.tick(0.1)
    s.exchange(1, 0, Action.MISSION_READY)
    s.ready(2)
    for d in s.drones:
        s.start(d)
    return _finish(s)


def pay3() -> Script:
    s = _started()
    from mcp_conform.spec.codec import ITEM
    _bad_command(s, Action.WP_LIST, (2).to_bytes(2, "big") + ITEM.pack(*s.items[0]))
    return _finish(s)


def pay5() -> Script:
    s = _started(challenge=2)
    from mcp_conform.spec.codec import ITEM
    _bad_command(s, Action.WP_ON, ITEM.pack(*s.items[0])[:-1])
    return _finish(s)


def pay6() -> Script:
    s = _started()
    frame = bytearray(heartbeat_frame())
    frame[-1] ^= 0xFF  # a bad CRC
    _bad_command(s, Action.MAV_PASSTHROUGH, bytes(frame))
    return _finish(s)


def pay7() -> Script:
    insane = MissionItem(0.0, 0.0, 0.0, 0.0, 135.0, -78.6, 3.0, 9, 16, 1, 1, 0, 0, 1)  # latitude 135
    s = Script((1, 2), challenge=1, waypoints=(insane,))
    for d in s.drones:
        s.ready(d)
    for d in s.drones:
        s.start(d)
    return _finish(s)


def pay8() -> Script:
    s = _started()
    s.challenge_steps()
    s.passthrough(1)
    s.vehicle(1, "frame", frame=heartbeat_frame())  # written a second time
    s.passthrough(2)
    for d in s.drones:
        s.end(d)
    return s


def _pay8_altered(alter: Callable[[bytes], bytes]) -> Script:
    """MCP-PAY-8: drone 1 writes its passthrough frame to the autopilot altered (``alter``);
    what arrives does not parse, so no intact frame is ever delivered."""
    s = _started()
    s.challenge_steps()
    frame = heartbeat_frame()
    s.exchange(0, 1, Action.MAV_PASSTHROUGH, frame,
               on_delivery=lambda: s.vehicle(1, "unparsed", frame=alter(frame), detail="bad CRC"))
    s.passthrough(2)
    s.tick(0.05)
    return _finish(s, steps=False)


def pay8_truncated() -> Script:
    return _pay8_altered(lambda f: f[:-3])


def pay8_corrupted() -> Script:
    return _pay8_altered(lambda f: f[:12] + bytes([f[12] ^ 0x04]) + f[13:])


# ---------------------------------------------------------------- ROB
def rob2() -> Script:
    s = _started()
    seq = s.next_seq(0)
    bad = PREAMBLE[:-1] + b"\x02" + build_datagram(1, 0, seq, int(Action.WP_OFF))[9:]
    s.raw(0, bad, to=1, origin=TESTER)
    s.tick(0.004)
    s.ack(1, 0, seq)  # drone 1 ACKs a datagram with a bad preamble
    return _finish(s)


def rob3() -> Script:
    s = _started()
    seq = s.next_seq(0)
    s.raw(0, build_datagram(1, 0, seq, 12), to=1, origin=TESTER)
    s.tick(0.004)
    s.ack(1, 0, seq)
    return _finish(s)


def rob4() -> Script:
    s = _started()
    seq = s.next_seq(0)
    s.raw(0, build_datagram(1, 0, seq, int(Action.WP_OFF), b"\x01"), to=1, origin=TESTER)
    s.tick(0.004)
    s.ack(1, 0, seq)
    return _finish(s)


# ---------------------------------------------------------------- FLOW
def flow1() -> Script:
    s = Script((1, 2), vehicle=False)
    s.ready(2)
    seq, data = s.send(1, 5, Action.MISSION_READY)  # to ID 5, not the manager
    for _ in range(4):
        s.tick(s.rto)
        s.raw(1, data)
    s.start(2)
    s.challenge_steps(drones=(2,))
    s.end(2)
    return s


def ack1_manager() -> Script:
    s = Script((1, 2))
    s.ready(2)  # the manager is up: it ACKs drone 2's Mission_Ready
    s.ready(1, deaf=8)  # ... then ignores drone 1's for 8 copies (before a node's first
    # datagram, copies may go unheard: a node started late, not one that ignores them)
    for d in s.drones:
        s.start(d)
    return _finish(s)


def flow2() -> Script:
    s = Script((1, 2))
    for d in s.drones:
        s.ready(d)
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items))  # before any Start_Mission to drone 1
    for d in s.drones:
        s.start(d)
    s.challenge_steps(drones=(2,))
    return _finish(s, steps=False)


def flow3() -> Script:
    s = _started()
    s.challenge_steps()
    s.end(1)  # and never drone 2
    return s


def flow4() -> Script:
    s = _started()
    s.challenge_steps()
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items))  # a second WP_List
    return _finish(s, steps=False)


def flow5() -> Script:
    s = _started(challenge=2)
    s.exchange(0, 1, Action.WP_OFF)  # no WP_On before it
    return _finish(s)


def flow6() -> Script:
    s = _started(challenge=3)
    for d in s.drones:
        s.exchange(0, d, Action.OBSTACLES_LIST, tuple(s.items[:1]))  # not the mission's obstacles
    return _finish(s, steps=False)


# D-11: a list broadcast is a command to each drone whose mission is on (its Start_Mission
# ACKed, no End_Mission yet); going to every drone, one to a drone whose Start_Mission awaits its
# ACK (MCP-BLK-3, and that drone's list) or after its End_Mission (MCP-BLK-6, not its list)
def flow4_broadcast_before_start() -> Script:
    """The WP_List broadcast once drone 1's Start_Mission is ACKed, before drone 2's is sent:
    drone 2's mission got no list."""
    s = Script((1, 2))
    for d in s.drones:
        s.ready(d)
    s.start(1)
    s.broadcast(Action.WP_LIST, tuple(s.items))
    s.start(2)
    return _finish(s, steps=False)


def blk3_broadcast_before_start_acked() -> Script:
    """The WP_List broadcast while drone 2's Start_Mission awaits its ACK (its first copy
    unanswered, the next ACKed): a further command to drone 2 before that ACK (a broadcast goes
    to every drone, D-11), MCP-BLK-3's; it is drone 2's list (one fault, one rule: no FLOW-4)."""
    s = Script((1, 2))
    for d in s.drones:
        s.ready(d)
    s.start(1)

    def answer(k: int, seq: int, data: bytes) -> bool:
        if k == 0:
            s.broadcast(Action.WP_LIST, tuple(s.items))
            s.tick(-0.01)
            return False
        s.ack(2, 0, seq)
        return True
    s.exchange(0, 2, Action.START_MISSION, ack_hook=answer)
    return _finish(s, steps=False)


def flow4_broadcast_twice() -> Script:
    s = _started()
    s.broadcast(Action.WP_LIST, tuple(s.items))
    s.broadcast(Action.WP_LIST, tuple(s.items))  # a second list to every drone, a new seq
    return _finish(s, steps=False)


def flow4_broadcast_and_unicast() -> Script:
    s = _started()
    s.broadcast(Action.WP_LIST, tuple(s.items))
    s.exchange(0, 1, Action.WP_LIST, tuple(s.items))  # drone 1's second list
    return _finish(s, steps=False)


def flow6_broadcast_after_end() -> Script:
    """Drone 1's mission ended before the Obstacles_List broadcast: it never got one (MCP-FLOW-6),
    and the broadcast went to it after its End_Mission (MCP-BLK-6): two faults, two rules
    (tests/judge/test_broadcast_lists.py; not in ``FAULTY``, whose scripts break one rule)."""
    s = _started(challenge=3)
    s.end(1)
    s.broadcast(Action.OBSTACLES_LIST, tuple(s.items))
    s.end(2)
    return s


def flow6_broadcast_before_start() -> Script:
    """The Obstacles_List broadcast once drone 1's Start_Mission is ACKed, before drone 2's is
    sent: drone 2's mission got no list (D-11)."""
    s = Script((1, 2), challenge=3)
    for d in s.drones:
        s.ready(d)
    s.start(1)
    s.broadcast(Action.OBSTACLES_LIST, tuple(s.items))
    s.start(2)
    return _finish(s, steps=False)


def blk6_broadcast_after_end() -> Script:
    """Drone 1's mission (its Obstacles_List unicast) ended; then the Obstacles_List broadcast for
    drone 2: drone 2's list, and a command to drone 1 after its End_Mission (a broadcast goes to
    every drone: "it will send no further commands in the current mission")."""
    s = _started(challenge=3)
    s.exchange(0, 1, Action.OBSTACLES_LIST, tuple(s.items))
    s.tick(0.01)
    s.end(1)
    s.broadcast(Action.OBSTACLES_LIST, tuple(s.items))
    s.end(2)
    return s


def _skipping_steps(s: Script, *, broadcast: bool = False) -> Script:
    """Challenge 2 with the third waypoint's WP_On carrying the second again: one waypoint
    repeated, one skipped, in the middle of the mission (every WP_On a mission waypoint, each
    WP_Off after a WP_On)."""
    sent = list(s.items)
    sent[2] = sent[1]
    for wp in sent:
        if broadcast:
            s.broadcast(Action.WP_ON, wp)
            s.broadcast(Action.WP_OFF)
            continue
        for d in s.drones:
            s.exchange(0, d, Action.WP_ON, wp)
            s.tick(0.01)
        for d in s.drones:
            s.exchange(0, d, Action.WP_OFF)
            s.tick(0.01)
    return _finish(s, steps=False)


def flow5_skips_a_waypoint() -> Script:
    return _skipping_steps(_started(challenge=2))


def flow5_broadcast_skips_a_waypoint() -> Script:
    return _skipping_steps(_started(challenge=2), broadcast=True)


def flow5_broadcast_wp_off_before_its_wp_on() -> Script:
    """A WP_On broadcast while only drone 1's mission is on, then drone 2 started, then the
    WP_Off broadcast: drone 2 gets a WP_Off with no WP_On before it."""
    s = Script((1, 2), challenge=2)
    for d in s.drones:
        s.ready(d)
    s.start(1)
    s.broadcast(Action.WP_ON, s.items[0])
    s.start(2)
    s.broadcast(Action.WP_OFF)
    for wp in s.items[1:]:
        s.broadcast(Action.WP_ON, wp)
        s.broadcast(Action.WP_OFF)
    return _finish(s, steps=False)


# ---------------------------------------------------------------- DUP, SEQ-3 (autopilot link)
def dup1() -> Script:
    s = _started()
    s.passthrough(2)
    frame = heartbeat_frame()

    def again(k: int, seq: int, data: bytes) -> bool:
        s.ack(1, 0, seq)
        s.tick(0.01)
        s.vehicle(1, "frame", frame=frame)  # each copy written to the autopilot
        s.tick(-0.01)
        return k > 0
    s.exchange(0, 1, Action.MAV_PASSTHROUGH, frame, ack_hook=again)
    return _finish(s)


def dup2() -> Script:
    s = _started()
    s.passthrough(1)
    s.passthrough(2)
    s.exchange(0, 1, Action.MAV_PASSTHROUGH, heartbeat_frame())  # the same bytes: not delivered
    s.tick(0.05)
    return _finish(s)


def dup3() -> Script:
    s = _started()
    s.passthrough(2)
    frame = heartbeat_frame()
    seq = s.passthrough(1)
    other = heartbeat_frame(seq=7)
    s.tick(0.05)
    s.exchange(5, 1, Action.MAV_PASSTHROUGH, other, seq=seq, origin=TESTER)  # not delivered
    del frame
    return _finish(s)


def seq3() -> Script:
    s = _started(seqs={0: 65530})
    s.passthrough(2)
    while s.seq[0] != 65535:
        s.passthrough(1, heartbeat_frame(seq=s.seq[0] & 0xFF))
    s.passthrough(1, heartbeat_frame(seq=200))  # seq 65535
    s.exchange(0, 1, Action.MAV_PASSTHROUGH, heartbeat_frame(seq=201))  # seq 0: not delivered
    s.tick(0.05)
    return _finish(s)


def trn2() -> Script:
    s = _started()
    first = len(s.records)
    seq, data = s.send(0, 1, Action.WP_OFF)  # from another source port: never ACKed
    for _ in range(5):
        s.tick(s.rto)
        s.raw(0, data, to=1)
    s.records[first:] = [r._replace(src_addr=("127.0.0.1", 40000)) for r in s.records[first:]]
    s.tick(s.rto)
    s.exchange(0, 1, Action.WP_OFF)  # from its usual address: ACKed
    return _finish(s)


FAULTY: dict[str, Fault] = {
    "hdr1-bad-preamble": Fault("MCP-HDR-1", hdr1),
    "hdr2-short": Fault("MCP-HDR-2", hdr2),
    "hdr3-action-9": Fault("MCP-HDR-3", hdr3),
    "hdr4-wrong-src": Fault("MCP-HDR-4", hdr4),
    "hdr5-drone-sends-wp-list": Fault("MCP-HDR-5", hdr5),
    "ack1-unanswered": Fault("MCP-ACK-1", ack1),
    "ack2-little-endian": Fault("MCP-ACK-2", ack2, complete=False),
    "ack3-wrong-dst": Fault("MCP-ACK-3", ack3),
    "ack4-acks-broadcast": Fault("MCP-ACK-4", ack4, complete=False),
    "ack5-acks-other-id": Fault("MCP-ACK-5", ack5, complete=False),
    "ack6-acks-ack": Fault("MCP-ACK-6", ack6),
    "ack7-slow": Fault("MCP-ACK-7", ack7),
    "seq1-skips": Fault("MCP-SEQ-1", seq1),
    "seq2-copy-differs": Fault("MCP-SEQ-2", seq2, complete=False),
    "rtx1-gives-up": Fault("MCP-RTX-1", rtx1),
    "ack2-copy-acked-with-the-next-seq": Fault("MCP-ACK-2", ack2_copy_acked_with_the_next_seq),
    "ack4-beside-a-waiting-copy": Fault("MCP-ACK-4", ack4_beside_a_waiting_copy),
    "ack2-interleaved-copies-acked-with-the-next-seq": Fault("MCP-ACK-2", ack2_interleaved_copies_acked_with_the_next_seq),
    "rtx1-manager-gives-up-then-acked": Fault("MCP-RTX-1", rtx1_gives_up_then_acked),
    "rtx1-manager-gives-up-and-drops-the-drone": Fault("MCP-RTX-1", rtx1_gives_up_then_drops_the_drone),
    "rtx2-stops-on-wrong-ack": Fault("MCP-RTX-2", rtx2),
    "rtx2-manager-moves-on-after-a-wrong-ack": Fault("MCP-RTX-2", rtx2_moves_on),
    "rtx2-manager-takes-a-stale-ack": Fault("MCP-RTX-2", rtx2_takes_a_stale_ack),
    "rtx3-uneven": Fault("MCP-RTX-3", rtx3),
    "rtx3-storm": Fault("MCP-RTX-3", rtx3_storm, complete=False),
    "rtx4-broadcast-twice": Fault("MCP-RTX-4", rtx4, complete=False),
    "blk1-no-stop-and-wait": Fault("MCP-BLK-1", blk1, complete=False),
    "blk2-start-before-all-ready": Fault("MCP-BLK-2", blk2),
    "blk2-start-before-that-drones-ready": Fault("MCP-BLK-2", blk2_start_before_that_drones_ready),
    "blk2-start-early-ack-numbered-after-it-read-first": Fault("MCP-BLK-2",
                                                               blk2_start_early_ack_numbered_after_it_read_first),
    "blk3-command-before-start-acked": Fault("MCP-BLK-3", blk3),
    "blk4-arms-early": Fault("MCP-BLK-4", blk4),
    "blk5-ready-without-fix": Fault("MCP-BLK-5", blk5),
    "blk6-command-after-end": Fault("MCP-BLK-6", blk6, complete=False),
    "blk7-no-rtl": Fault("MCP-BLK-7", blk7),
    "pay1-payload-on-wp-off": Fault("MCP-PAY-1", pay1),
    "pay2-ready-payload": Fault("MCP-PAY-2", pay2),
    "pay3-count-mismatch": Fault("MCP-PAY-3", pay3),
    "pay3-manager-drops-the-drone-that-did-not-ack-it": Fault("MCP-PAY-3", pay3_then_drops_the_drone),
    "pay5-short-item": Fault("MCP-PAY-5", pay5),
    "pay6-bad-crc": Fault("MCP-PAY-6", pay6),
    "pay7-insane-item": Fault("MCP-PAY-7", pay7),
    "pay8-forwarded-twice": Fault("MCP-PAY-8", pay8),
    "pay8-forwarded-truncated": Fault("MCP-PAY-8", pay8_truncated),
    "pay8-forwarded-corrupted": Fault("MCP-PAY-8", pay8_corrupted),
    "rob2-acks-bad-preamble": Fault("MCP-ROB-2", rob2, complete=False),
    "rob3-acks-unknown-action": Fault("MCP-ROB-3", rob3, complete=False),
    "rob4-acks-bad-length": Fault("MCP-ROB-4", rob4, complete=False),
    "flow1-ready-to-wrong-id": Fault("MCP-FLOW-1", flow1),
    "ack1-manager-ready-not-acked": Fault("MCP-ACK-1", ack1_manager),
    "flow2-list-before-start": Fault("MCP-FLOW-2", flow2),
    "flow3-no-end-mission": Fault("MCP-FLOW-3", flow3),
    "flow4-two-wp-lists": Fault("MCP-FLOW-4", flow4, complete=False),
    "flow5-wp-off-without-wp-on": Fault("MCP-FLOW-5", flow5),
    "flow6-wrong-obstacles": Fault("MCP-FLOW-6", flow6, complete=False),
    "rtx2-moves-on-then-broadcasts": Fault("MCP-RTX-2", rtx2_moves_on_then_broadcasts),
    "flow4-broadcast-before-start": Fault("MCP-FLOW-4", flow4_broadcast_before_start),
    "blk3-broadcast-before-start-acked": Fault("MCP-BLK-3", blk3_broadcast_before_start_acked),
    "flow4-broadcast-twice": Fault("MCP-FLOW-4", flow4_broadcast_twice, complete=False),
    "flow4-broadcast-and-unicast": Fault("MCP-FLOW-4", flow4_broadcast_and_unicast, complete=False),
    "flow5-broadcast-wp-off-before-its-wp-on": Fault("MCP-FLOW-5", flow5_broadcast_wp_off_before_its_wp_on),
    "flow6-broadcast-before-start": Fault("MCP-FLOW-6", flow6_broadcast_before_start),
    "blk6-broadcast-after-end": Fault("MCP-BLK-6", blk6_broadcast_after_end),
    "flow5-skips-a-waypoint": Fault("MCP-FLOW-5", flow5_skips_a_waypoint),
    "flow5-broadcast-skips-a-waypoint": Fault("MCP-FLOW-5", flow5_broadcast_skips_a_waypoint),
    "dup1-duplicate-delivered": Fault("MCP-DUP-1", dup1),
    "dup2-same-bytes-dropped": Fault("MCP-DUP-2", dup2),
    "dup3-other-src-dropped": Fault("MCP-DUP-3", dup3),
    "seq3-no-wrap": Fault("MCP-SEQ-3", seq3),
    "trn2-source-port-filter": Fault("MCP-TRN-2", trn2),
}

"""``fuzz.target_core``, the fuzz target's process and link whatever its protocol (issue 39):
a spawned target's start, failure and end as reported; the synchronous link's frames (cut by
the protocol's framing, bad bytes dropped), its traffic from the target's side, its beat and
the gap after it, its end, and a write to a target that reads nothing bounded."""

from __future__ import annotations

import socket
import struct
import sys
import threading
import time

import pytest

from mcp_conform.fuzz.target_core import ProcessTarget, SyncLink, TargetSpec, connect_when_listening
from mcp_conform.harness.errors import SetupError, SpawnFailure
from mcp_conform.harness.mavlink_session import DIALECT, MavlinkFraming
from mcp_conform.harness.session_base import free_port


def _frame(msg: object, seq: int = 0) -> bytes:
    enc = DIALECT.MAVLink(None, srcSystem=1, srcComponent=1)
    enc.seq = seq
    return bytes(msg.pack(enc))  # type: ignore[attr-defined]


def _heartbeat(seq: int = 0) -> bytes:
    return _frame(DIALECT.MAVLink_heartbeat_message(1, 3, 0, 0, 4, 3), seq)


def _pair() -> tuple[socket.socket, socket.socket]:
    server = socket.create_server(("127.0.0.1", 0))
    client = socket.create_connection(server.getsockname())
    peer, _ = server.accept()
    server.close()
    return client, peer


def test_a_spawned_target_is_reached_and_its_end_reported():
    """Spawned from a template with its placeholders filled in (the protocol's own too), reached
    by the first connection; killed, its end says how, with its command as evidence."""
    script = ("import socket,sys,time; s=socket.create_server((sys.argv[1], int(sys.argv[2]))); "
              "c,_=s.accept(); c.sendall(sys.argv[3].encode()); time.sleep(30)")
    t = ProcessTarget()
    sock = t.open(TargetSpec(f"{sys.executable} -c '{script}' {{target_host}} {{target_port}} {{greeting}}"),
                  lambda host, port: {"greeting": f"hello-{port}"})
    try:
        sock.settimeout(5.0)
        assert sock.recv(100) == f"hello-{t.address[1]}".encode()
        assert t.process_alive() and t.death() is None and t.ending() == (None, tuple(t.node.evidence()))
        assert (t.fds() or 0) >= 3
        t.process.proc.kill()
        how, evidence = t.ending(5.0)
        assert how == "the node process killed by signal SIGKILL", how
        assert any(line.startswith("node command: ") for line in evidence), evidence
        assert not t.process_alive() and t.death().signal_name == "SIGKILL"
    finally:
        sock.close()
        t.stop()


def test_a_target_that_dies_before_it_listens_or_is_not_there_fails_in_one_line():
    t = ProcessTarget()
    with pytest.raises(SpawnFailure, match=r"the spawned node exited with code 3 before it listened on"):
        t.open(TargetSpec(f"{sys.executable} -c 'raise SystemExit(3)'"))
    port = free_port("127.0.0.1", socket.SOCK_STREAM)
    t0 = time.monotonic()
    with pytest.raises(SetupError, match=rf"tcp:127.0.0.1:{port}: cannot reach the node"):
        connect_when_listening(("127.0.0.1", port), None, "the node", within=0.3)
    assert time.monotonic() - t0 < 3.0
    assert ProcessTarget().ending() == (None, ()) and ProcessTarget().process_alive()  # attached: nothing to tell


def test_the_link_cuts_frames_keeps_its_traffic_and_times_the_beat():
    client, peer = _pair()
    traffic: list[tuple[str, int, bytes]] = []
    link = SyncLink(client, MavlinkFraming(), traffic=traffic, beat=lambda r: r.name == "HEARTBEAT")
    try:
        ping = _frame(DIALECT.MAVLink_param_request_read_message(1, 1, b"X", -1))
        link.send(ping)
        peer.settimeout(2.0)
        assert peer.recv(100) == ping
        t0 = time.monotonic()
        param = _frame(DIALECT.MAVLink_param_value_message(b"X", 1.0, 9, 1, 0), 1)
        peer.sendall(b"garbage!" + param + _heartbeat(2))
        got = link.until(lambda r: r.name == "HEARTBEAT", 2.0)
        assert got is not None and [r.name for r in link.frames] == ["PARAM_VALUE", "HEARTBEAT"]
        assert link.until(lambda r: r.name == "PARAM_VALUE", 0.0, start=1) is None  # from ``start`` on
        assert link.last_beat == got.t >= t0
        assert [(d, raw) for d, _, raw in traffic] == [("rx", ping), ("tx", param), ("tx", _heartbeat(2))]
        assert link.wait_beat(t0 - 1.0, 1.0)  # a beat after the moment asked
        t1 = time.monotonic()
        assert not link.wait_beat(t1, 0.3) and time.monotonic() - t1 < 0.5  # none within the gap
        threading.Timer(0.1, lambda: peer.sendall(_heartbeat(3))).start()
        assert link.wait_beat(link.last_beat, 2.0) and len(link.frames) == 3
        peer.close()
        link.drain()
        assert link.closed and link.until(lambda r: True, 1.0, start=3) is None
    finally:
        link.close()
        peer.close()


def test_a_write_to_a_target_that_reads_nothing_is_bounded():
    """A target that stopped reading: the write ends within its bound and the link is closed,
    the fuzzer never hangs on it."""
    client, peer = _pair()
    link = SyncLink(client, MavlinkFraming())
    try:
        t0 = time.monotonic()
        for _ in range(64):
            link.send(b"\0" * (1 << 20))
            if link.closed:
                break
        assert link.closed and time.monotonic() - t0 < 10.0
    finally:
        link.close()
        peer.close()


def test_a_target_that_resets_the_connection_at_once_ends_the_link():
    """Accepted, then reset before the fuzzer's first read: the link opens, and is closed at
    its first read (the vehicle's start then fails in one line: no HEARTBEAT), no error."""
    client, peer = _pair()
    peer.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
    peer.close()
    time.sleep(0.1)
    link = SyncLink(client, MavlinkFraming())
    try:
        assert link.until(lambda r: True, 2.0) is None and link.closed
    finally:
        link.close()


def test_the_case_runner_drops_what_was_held_writes_the_case_and_its_probe_and_reads_to_its_answer():
    """``SyncLink.exchange``: what the link held before is dropped; the case and its probe go
    out in one write; the answer's index counts only the frames after that write (the case's
    answers before it, what came after it not yet read); no answer: None, within the bound."""
    client, peer = _pair()
    link = SyncLink(client, MavlinkFraming())
    try:
        peer.sendall(_heartbeat(0))
        assert link.until(lambda r: True, 2.0) is not None and len(link.frames) == 1
        answered = lambda r: r.name == "PARAM_VALUE"  # noqa: E731
        case_and_probe = b"case" + _frame(DIALECT.MAVLink_param_request_read_message(1, 1, b"X", -1))

        def serve() -> None:
            peer.settimeout(2.0)
            got = b""
            while len(got) < len(case_and_probe):
                got += peer.recv(1000)
            assert got == case_and_probe
            peer.sendall(_heartbeat(1) + _heartbeat(2)
                         + _frame(DIALECT.MAVLink_param_value_message(b"X", 1.0, 9, 1, 0), 3) + _heartbeat(4))

        threading.Thread(target=serve).start()
        i = link.exchange(case_and_probe, answered, 2.0)
        assert i == 2 and [r.name for r in link.frames[:3]] == ["HEARTBEAT", "HEARTBEAT", "PARAM_VALUE"]
        t0 = time.monotonic()
        assert link.exchange(b"again", answered, 0.3) is None and 0.25 <= time.monotonic() - t0 < 1.0
        assert all(r.name == "HEARTBEAT" for r in link.frames)  # the answer of before was dropped
    finally:
        link.close()
        peer.close()


class _Fake:
    """A target as ``SpareTarget`` makes one: started, closed, its traffic kept."""

    made: list[_Fake] = []

    def __init__(self, log: list | None = None) -> None:
        self.log, self.closed, self.late = log, False, None
        _Fake.made.append(self)

    def close(self) -> None:
        self.closed = True


def test_a_worker_target_restarts_on_its_spare_counts_why_and_keeps_none_when_attached():
    from mcp_conform.fuzz.target_core import SpareTarget

    class Own(SpareTarget):
        def adopt(self, t):
            t.late = 0.1  # the campaign's own, told apart from a replay's
            return t

    _Fake.made = []
    t = Own(_Fake(), _Fake, _Fake.close, attached=False)
    first = t.current
    log: list = []
    replay = t.fresh(log)  # no spare yet: one made now, with the log, and a spare started
    assert replay.log is log and replay.late is None and len(t.spares.queue) == 1
    again = t.restart("after a hit")
    assert first.closed and again is t.current and again.late == 0.1 and again.log is None
    assert again is not replay and t.restarts == 1 and t.restart_reasons == {"after a hit": 1}
    t.close()
    assert again.closed and t.spares.queue == []
    attached = Own(_Fake(), _Fake, _Fake.close, attached=True)
    attached.fresh()
    assert attached.spares.queue == []  # a target reached at an address has no spare
    attached.close()


def test_a_linked_target_sends_its_keepalive_once_a_period_and_tells_a_closed_link_dead():
    from mcp_conform.fuzz.target_core import LinkedTarget

    client, peer = _pair()
    t = LinkedTarget()
    t.link = SyncLink(client, MavlinkFraming())
    try:
        sent: list[int] = []
        for _ in range(3):
            t.keepalive(0.2, lambda: (sent.append(1), _heartbeat(0))[1])
        assert len(sent) == 1 and t.alive()
        time.sleep(0.25)
        t.keepalive(0.2, lambda: (sent.append(1), _heartbeat(1))[1])
        peer.settimeout(2.0)
        got = b""
        while len(got) < 2 * len(_heartbeat(0)):
            got += peer.recv(1000)
        assert len(sent) == 2 and got == _heartbeat(0) + _heartbeat(1)
        peer.close()
        t.link.drain()
        assert t.closed and not t.alive()
    finally:
        t.close()



class _Toy:
    """A protocol declared to the shared case runner (``LinkedTarget``): a HEARTBEAT its beat,
    a PARAM_REQUEST_READ its probe, a PARAM_VALUE its answer; what the runner asked recorded."""

    @staticmethod
    def target(client: socket.socket, gap: float) -> object:
        from mcp_conform.fuzz.target_core import LinkedTarget

        asked: list[tuple] = []

        class Oracles:
            @staticmethod
            def lost(t, case, answered=False):  # noqa: ANN001, ANN205
                asked.append(("lost", case, answered))
                return "lost"

        class Toy(LinkedTarget):
            BEAT_GAP_S, REPLY_S, oracles = gap, 0.5, Oracles  # noqa: RUF012

            def is_beat(self, r):  # noqa: ANN001, ANN202
                return r.name == "HEARTBEAT"

            def probe_frame(self) -> bytes:
                return _frame(DIALECT.MAVLink_param_request_read_message(1, 1, b"PROBE", -1))

            def is_probe_answer(self, r) -> bool:  # noqa: ANN001
                return r.name == "PARAM_VALUE"

            def judge(self, case, upto):  # noqa: ANN001, ANN202
                asked.append(("judge", case, [r.name for r in self.frames[:upto]]))
                return None

        t = Toy()
        t.link = SyncLink(client, MavlinkFraming(), beat=t.is_beat)
        t.asked = asked  # type: ignore[attr-defined]
        return t


class _Case:
    def __init__(self, data: bytes) -> None:
        self.data = data

    def wire(self) -> bytes:
        return self.data


def test_the_shared_case_runner_judges_what_came_before_the_probes_answer():
    """``LinkedTarget.run``: the case written with the protocol's probe behind it; the frames
    before the probe's answer judged by the protocol, the answer and those before it dropped;
    no answer within ``REPLY_S``, or a beat missing longer than ``BEAT_GAP_S``: its ``lost``."""
    client, peer = _pair()
    t = _Toy.target(client, gap=5.0)
    try:
        case = _Case(_heartbeat(7))
        peer.sendall(_heartbeat(0) + _frame(DIALECT.MAVLink_param_value_message(b"PROBE", 1.0, 9, 1, 0))
                     + _heartbeat(1))
        assert t.run(case) is None
        assert t.asked == [("judge", case, ["HEARTBEAT"])]  # type: ignore[attr-defined]
        peer.settimeout(2.0)
        got = peer.recv(1000)
        assert got.startswith(_heartbeat(7)) and got.endswith(t.probe_frame())  # the case, then the probe
        assert len(t.frames) <= 1 and all(r.name == "HEARTBEAT" for r in t.frames)  # the answer's and before: dropped
        assert t.last_beat > 0
        t.asked.clear()  # type: ignore[attr-defined]
        assert t.run(case) == "lost" and t.asked == [("lost", case, False)]  # no answer  # type: ignore[attr-defined]
    finally:
        peer.close()
        t.close()
    client, peer = _pair()
    t = _Toy.target(client, gap=0.01)  # the beat's bound passed while the probe was answered
    try:
        peer.sendall(_frame(DIALECT.MAVLink_param_value_message(b"PROBE", 1.0, 9, 1, 0)))
        assert t.run(_Case(b"")) == "lost" and t.asked[-1][0] == "lost" and t.asked[-1][2] is True  # type: ignore[attr-defined]
    finally:
        peer.close()
        t.close()

"""``--impair`` at a socket's own edge (issue 22 item 3): the link knows every decision,
and a conformance case the impairment spoiled is repeated, never failed."""

from __future__ import annotations

import socket
import time
from types import SimpleNamespace

import pytest

from mcp_conform.conformance._impaired import ATTEMPTS, run_impaired
from mcp_conform.harness.errors import CaseFailure, Inconclusive
from mcp_conform.harness.impair import Impairment, parse_impairment
from mcp_conform.harness.impair_link import ImpairedLink
from mcp_conform.harness.session_base import DatagramSessionBase
from mcp_conform.spec.codec import Action, Message, encode

WP_OFF = encode(Message(1, 0, 1000, Action.WP_OFF, None))


class Recorder:
    def __init__(self) -> None:
        self.records: list[tuple[str, bytes]] = []

    def impairment(self, decision, data, t_ns=None) -> None:
        self.records.append((decision.direction, data))


@pytest.fixture
def pair():
    a = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    b = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    a.bind(("127.0.0.1", 0))
    b.bind(("127.0.0.1", 0))
    b.settimeout(0.3)
    yield a, b
    a.close()
    b.close()


def got(sock: socket.socket) -> bytes | None:
    try:
        return sock.recvfrom(65535)[0]
    except TimeoutError:
        return None


def seed_where(spec: str, first_dropped: bool, second_dropped: bool, direction: str = "tx") -> int:
    """A seed whose schedule drops (or not) the first two datagrams of ``direction``, found by
    asking the schedule itself (it is deterministic: same seed, same decisions)."""
    for seed in range(1000):
        imp = Impairment(parse_impairment(f"{spec},seed={seed}"))
        d0, d1 = imp.decide(direction, WP_OFF), imp.decide(direction, WP_OFF)
        if (d0.dropped is not None, d1.dropped is not None) == (first_dropped, second_dropped):
            return seed
    raise AssertionError("no such seed")


def test_a_drop_is_known_recorded_and_nothing_leaves(pair):
    a, b = pair
    rec = Recorder()
    link = ImpairedLink(Impairment(parse_impairment("loss=1,seed=1")), recorder=rec)
    link.send(a, WP_OFF, b.getsockname())
    assert got(b) is None
    touched = link.touched(time.monotonic() - 1)
    assert [ev.describe() for ev in touched] == ["WP_OFF seq 1000 0->1 (sent) drop:loss"]
    assert rec.records == [("tx", WP_OFF)]  # the capture's /impair record, with the datagram


def test_duplicates_and_delays_are_delivered_and_kept(pair):
    a, b = pair
    link = ImpairedLink(Impairment(parse_impairment("dup=1,delay=20-30ms,seed=3")))
    seen: list[bytes] = []
    link.send(a, WP_OFF, b.getsockname(), seen.append)
    assert got(b) == WP_OFF and got(b) == WP_OFF  # two copies, late
    deadline = time.monotonic() + 2.0
    while len(seen) < 2 and time.monotonic() < deadline:  # told right after it left
        time.sleep(0.01)
    assert seen == [WP_OFF, WP_OFF]  # the observers see each copy as it leaves
    assert link.touched(time.monotonic() - 1)[0].spoils  # a copy can spoil an observation
    link.close()


def test_a_short_delay_alone_does_not_spoil():
    link = ImpairedLink(Impairment(parse_impairment("delay=1-2ms,seed=3")), spoil_delay_s=0.05)
    link.receive(WP_OFF, ("127.0.0.1", 1), lambda d, a: None)
    assert link.events and not link.touched(time.monotonic() - 1)
    link.close()


def test_a_corrupted_received_copy_is_discarded_as_the_udp_checksum_would():
    link = ImpairedLink(Impairment(parse_impairment("corrupt=1,seed=5")))
    delivered: list[bytes] = []
    link.receive(WP_OFF, ("127.0.0.1", 1), lambda d, a: delivered.append(d))
    assert delivered == [] and len(link.touched(time.monotonic() - 1)) == 1


def test_paused_is_a_clean_link(pair):
    a, b = pair
    link = ImpairedLink(Impairment(parse_impairment("loss=1,seed=1")))
    link.paused = True
    link.send(a, WP_OFF, b.getsockname())
    assert got(b) == WP_OFF and link.events == []


# ---------------------------------------------------------------------- a spoiled case
class FakeSession(DatagramSessionBase):
    def __init__(self, link: ImpairedLink) -> None:
        self.cfg = SimpleNamespace(rto=0.05, impair=link.spec)
        self.driver = SimpleNamespace(link=link, sent=lambda: [])
        self.ended: list[str] = []
        self.startup_window = (0.0, None)

    def begin_case(self, case_id, rules):
        return SimpleNamespace(start_t=time.monotonic(), notes=[])

    def end_case(self, ctx, outcome):
        self.ended.append(outcome)


class FakeState:
    def __init__(self, session, item, phase="main") -> None:
        self.session = session
        self.meta = {item.nodeid: ("ACK/case", ("MCP-ACK-1",), "MUST", phase)}
        self.ctx = {item.nodeid: item.funcargs["node"]}
        self.case_deadline = None

    def record(self, item):
        return SimpleNamespace(id="ACK/case", rules=("MCP-ACK-1",))

    def current_limit(self):
        return 10.0

    def arm(self):
        pass

    def disarm(self):
        pass


class Item:
    """A case that sends one WP_Off through the link and fails when it did not arrive."""

    nodeid = "cases/test_ack.py::test_case"

    def __init__(self, link, pair, always_fail=False) -> None:
        self.link, (self.a, self.b), self.always_fail = link, pair, always_fail
        self.funcargs = {"node": SimpleNamespace(start_t=time.monotonic(), notes=[])}
        self.runs = 0

    def runtest(self) -> None:
        self.runs += 1
        self.link.send(self.a, WP_OFF, self.b.getsockname())
        if got(self.b) is None or self.always_fail:
            raise CaseFailure("MCP-ACK-1", "the WP_Off arrives", "nothing arrived")


def first_attempt(item: Item) -> BaseException:
    try:
        item.runtest()
    except CaseFailure as exc:
        return exc
    raise AssertionError("the first attempt passed")


def test_a_case_whose_probe_was_dropped_is_repeated_and_passes(pair):
    seed = seed_where("loss=0.5", first_dropped=True, second_dropped=False)
    link = ImpairedLink(Impairment(parse_impairment(f"loss=0.5,seed={seed}")))
    item = Item(link, pair)
    session = FakeSession(link)
    state = FakeState(session, item)
    run_impaired(state, item, first_attempt(item))  # returns: the repeat passed
    assert item.runs == 2 and session.ended == ["spoiled"]
    notes = state.ctx[item.nodeid].notes
    assert notes == ["attempt 1 spoiled by the impairment (MCP-ACK-1 failed): "
                     "WP_OFF seq 1000 0->1 (sent) drop:loss"]


def test_an_untouched_failure_stands_at_once(pair):
    seed = seed_where("loss=0.5", first_dropped=False, second_dropped=False)
    link = ImpairedLink(Impairment(parse_impairment(f"loss=0.5,seed={seed}")))
    item = Item(link, pair, always_fail=True)
    exc = first_attempt(item)
    with pytest.raises(CaseFailure):
        run_impaired(FakeState(FakeSession(link), item), item, exc)
    assert item.runs == 1  # not repeated: no decision can have caused it


def test_a_real_fault_fails_on_the_last_clean_attempt(pair):
    link = ImpairedLink(Impairment(parse_impairment("loss=1,seed=1")))
    item = Item(link, pair, always_fail=True)
    state = FakeState(FakeSession(link), item)
    with pytest.raises(CaseFailure):
        run_impaired(state, item, first_attempt(item))
    assert item.runs == ATTEMPTS
    notes = state.ctx[item.nodeid].notes
    assert notes[-1] == f"attempt {ATTEMPTS} ran with the impairment paused (a clean link)"
    assert not link.paused


def test_a_touched_startup_phase_is_skipped_with_the_reason(pair):
    link = ImpairedLink(Impairment(parse_impairment("loss=1,seed=1")))
    start = time.monotonic()
    item = Item(link, pair)
    session = FakeSession(link)
    exc = first_attempt(item)
    session.startup_window = (start, time.monotonic())
    with pytest.raises(Inconclusive, match=r"MCP-ACK-1: spoiled by the impairment: the startup "
                                           r"phase it judges was touched \(WP_OFF seq 1000"):
        run_impaired(FakeState(session, item, phase="startup"), item, exc)
    assert item.runs == 1

"""The liveness watcher and the mission's end (``harness.liveness``, MCP-BLK-7, MCP-ACK-1).

A node may end its process (code 0) after End_Mission: the reference node ACKs copies for a
linger period and returns 0. Through a bad link every ACK of End_Mission can be lost before
it does (CI: ``test_the_reference_node_through_a_bad_link_has_no_failure[3]`` reported
"node lost during this case: the node process exited with code 0"). That is the end of its
mission, not a loss; a node that exits otherwise (before End_Mission, non-zero, a signal)
is still lost. The order of events is scripted here: the watcher is ticked by hand.
"""

from __future__ import annotations

import socket
import time
from types import SimpleNamespace

import pytest

from mcp_conform.conformance._impaired import SPOILABLE
from mcp_conform.harness.driver import TargetDriver
from mcp_conform.harness.errors import NodeLost, SilenceUnproven
from mcp_conform.harness.impair import Impairment, parse_impairment
from mcp_conform.harness.impair_link import ImpairedLink
from mcp_conform.harness.liveness import Liveness
from mcp_conform.spec.codec import Action, Message, encode, peek_header

NODE_ID = 1
RTO = 0.05


class FakeProcess:
    """The spawned node: alive until ``exit``."""

    def __init__(self) -> None:
        self.returncode: int | None = None

    def alive(self) -> bool:
        return self.returncode is None

    def exit(self, code: int) -> None:
        self.returncode = code

    def evidence(self) -> list[str]:
        return [f"exit: {self.returncode}"]


class Rig:
    """The runner's driver and watcher, and the node's socket whose own link loses every
    datagram it sends (its ACKs never reach the runner)."""

    def __init__(self) -> None:
        self.node = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.node.bind(("127.0.0.1", 0))
        self.node.settimeout(2.0)
        self.node_link = ImpairedLink(Impairment(parse_impairment("loss=1,seed=1")))
        self.driver = TargetDriver(self.node.getsockname(), ("127.0.0.1", 0), our_id=0)
        self.driver.open()
        self.proc = FakeProcess()
        self.driver.alive = self.proc.alive
        self.watch = Liveness(self.driver, RTO, lambda: NODE_ID)
        self.watch.reset(self.proc)
        self.watch.enable()

    def node_acks_one(self) -> int:
        """The node receives a datagram and ACKs it; its link drops the ACK. Its action."""
        data, _ = self.node.recvfrom(65535)
        hdr = peek_header(data)
        assert hdr is not None
        _, src, seq, action = hdr
        ack = encode(Message(src, NODE_ID, 7, Action.ACK, seq))
        self.node_link.send(self.node, ack, self.driver.listen)
        return action

    def close(self) -> None:
        self.watch.close()
        self.driver.close()
        self.node.close()


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def test_an_exit_0_after_end_mission_is_the_missions_end_not_a_loss(rig):
    """The CI order: End_Mission delivered, its ACK lost, the node ends (0), the watcher looks,
    then the exchange waits for an ACK. Before the fix the wait raised NodeLost."""
    sent = rig.driver.send(Action.END_MISSION, None, NODE_ID)
    assert rig.node_acks_one() == Action.END_MISSION
    rig.proc.exit(0)
    rig.watch.tick(time.monotonic())
    ex = rig.driver.exchange(sent, rto=RTO, copies=3)  # returns: the node is gone, not lost
    assert not ex.acked
    assert rig.watch.lost is None and rig.watch.ended_normally()
    rig.driver.check()  # nothing to raise


def _end_mission(rig):
    return rig.driver.send(Action.END_MISSION, None, NODE_ID)


def _restarted(rig):
    """End_Mission went to the node before a restart; the fresh node exits."""
    _end_mission(rig)
    rig.node_acks_one()
    rig.proc = FakeProcess()
    rig.driver.alive = rig.proc.alive
    rig.watch.reset(rig.proc)
    rig.watch.enable()
    return rig.driver.send(Action.WP_OFF, None, NODE_ID)


@pytest.mark.parametrize("how,code", [
    ("no End_Mission: a command", 0),
    ("End_Mission, then exit 3", 3),
    ("End_Mission, then SIGKILL", -9),
    ("End_Mission with a payload (malformed)", 0),
    ("End_Mission from another src", 0),
    ("End_Mission to the node before its restart", 0),
])
def test_any_other_exit_is_still_a_loss(rig, how, code):
    send = {
        "no End_Mission: a command": lambda: rig.driver.send(Action.WP_OFF, None, NODE_ID),
        "End_Mission, then exit 3": lambda: _end_mission(rig),
        "End_Mission, then SIGKILL": lambda: _end_mission(rig),
        "End_Mission with a payload (malformed)":
            lambda: rig.driver.send_datagram(NODE_ID, 5, int(Action.END_MISSION), b"\x00\x01"),
        "End_Mission from another src": lambda: rig.driver.send(Action.END_MISSION, None, NODE_ID, src=0x20),
        "End_Mission to the node before its restart": lambda: _restarted(rig),
    }[how]
    sent = send()
    rig.node_acks_one()
    rig.proc.exit(code)
    rig.watch.tick(time.monotonic())
    assert rig.watch.lost is not None
    with pytest.raises(NodeLost) as info:
        rig.driver.exchange(sent, rto=RTO, copies=3)
    assert "the node process" in info.value.reason and info.value.process_exited


def test_the_end_mission_case_is_repeated_under_impair_not_an_error_at_once(rig):
    """``BLK/test_end_mission_then_rtl`` with the CI order of events: it ends in an exception
    ``--impair`` repeats (SPOILABLE: a clean last attempt judges it), naming the node's normal
    end; before the fix it ended in NodeLost ("the node process exited with code 0"), an
    error at once. (Imported here, as ``test_manager_case`` does: a case module loads the runner.)"""
    from mcp_conform.conformance.cases.test_blk import test_end_mission_then_rtl as case

    def command(action):
        sent = rig.driver.send(action, None, NODE_ID)
        rig.node_acks_one()
        rig.proc.exit(0)
        rig.watch.tick(time.monotonic())
        return rig.driver.exchange(sent, rto=RTO, copies=3)

    session = SimpleNamespace(liveness=rig.watch, end_mission=None, ended=False,
                              node_evidence=lambda: rig.proc.evidence())
    node = SimpleNamespace(command=command, session=session, rto=RTO,
                           expect_acked=lambda *a, **k: pytest.fail("judged a missing ACK of a node that ended"))
    with pytest.raises(SilenceUnproven) as info:
        case(node)
    assert isinstance(info.value, SPOILABLE)
    assert "ended its mission" in info.value.reason and "exit: 0" in info.value.evidence
    assert session.ended

"""The soak's medium holds delayed copies in ``mcp-impair``'s bounded queue (issue 38 item
6): a copy past the cap is dropped and recorded in its link's view as a queue drop."""

from __future__ import annotations

import socket
import time

from mcp_conform.harness.impair import DelayQueue, Impairment, parse_impairment
from mcp_conform.soak.medium import Medium
from mcp_conform.spec.codec import Action, Message, encode


class _Recorder:
    def __init__(self) -> None:
        self.decisions: list = []

    def datagram(self, *args, **kwargs) -> None:
        pass

    def impairment(self, decision, data) -> None:
        self.decisions.append(decision)


def test_a_copy_past_the_cap_is_dropped_and_recorded() -> None:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as manager, \
            socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as drone:
        manager.bind(("127.0.0.1", 0))
        drone.bind(("127.0.0.1", 0))
        rec = _Recorder()
        medium = Medium([1], Impairment(parse_impairment("dup=1,delay=30s,seed=1")), manager.getsockname(),
                        {1: drone.getsockname()}, {"drone1": rec}, "127.0.0.1")
        medium.queue = DelayQueue(max_count=1)
        try:
            manager.sendto(encode(Message(1, 0, 3, Action.START_MISSION, None)), medium.front_addr)
            deadline = time.monotonic() + 5.0
            while not rec.decisions and time.monotonic() < deadline:
                medium._read(medium.front, None, time.monotonic())
                time.sleep(0.01)
        finally:
            medium.stop()
    (d,) = rec.decisions
    assert d.dropped == "queue" and len(d.deliveries) == 1 and len(medium.queue) == 1
    assert medium.impairment.counts["drop:queue"] == 1

"""MCP-ROB-7's flood in the simulator goes through ``SimSideSocket.sendto_many`` (one call for
the 10,000 datagrams ``harness.driver.flood`` sends at one virtual instant) instead of a
``sendto`` each (issue 38: the per-datagram path made cheaper). The run must be the same: what
the model read and answered, what reached the runner's sockets and when, what the link did."""

from __future__ import annotations

import random
from typing import Any

import pytest

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.impair import parse_impairment
from mcp_conform.sim.models import DroneModel
from mcp_conform.sim.mutants import mutant_factory
from mcp_conform.sim.transport import SimTransport
from mcp_conform.spec.generators import malformed_corpus


def _flood(make_model: Any, batch: bool, link: str | None, count: int = 6000) -> dict[str, Any]:
    clock = VirtualClock()
    spec = parse_impairment(link) if link else None
    t = SimTransport(clock, spec, spec, link_seed=3)
    t.bind(("127.0.0.1", 0))
    corpus = [d for _, d in malformed_corpus(5, 8, dst=1, src=0, first_seq=10,
                                              kinds=["bad_preamble", "unknown_action", "count_mismatch"])]
    got: dict[str, Any] = {}

    def body() -> None:
        t.attach(make_model(clock.now))
        clock.sleep(0.3)
        sock = t.side_socket("127.0.0.1")
        target = t.model.addr
        if batch:
            got["sent"] = sock.sendto_many(corpus, count, target)
        else:
            for i in range(count):
                sock.sendto(corpus[i % len(corpus)], target)
            got["sent"] = count
        clock.sleep(2.0)  # every copy read, the answers back, timers fired
        side = []
        while True:
            try:
                side.append(sock.recvfrom(65535))
            except BlockingIOError:
                break
        got["side"] = side
        sock.close()

    clock.run(body)
    m = t.model
    got.update(runner=list(t._inbox.queue), delivered=list(m.delivered), outcome=m.outcome, now=clock.now,
               switches=clock.switches, malformed=getattr(m, "_malformed", None),
               down=[(r.index, r.copy, r.t_sent, r.t_arrive, r.kinds) for r in t.down.records],
               up=[(r.index, r.copy, r.t_sent, r.t_arrive, r.kinds) for r in t.up.records])
    return got


MODELS = {
    "reference": lambda: (lambda now: DroneModel(1, 0.2, 3, random.Random(1), ready_at=now + 0.05)),
    "ack-bad-preamble": lambda: mutant_factory("ack-bad-preamble", rto=0.2, seed=2),  # answers the flood
    "flood-hang": lambda: mutant_factory("flood-hang", rto=0.2, seed=3),  # deaf after 5,000
}


@pytest.mark.parametrize("link", [None, "loss=0.1,dup=0.05,reorder=0.1,delay=0-2ms"])
@pytest.mark.parametrize("model", sorted(MODELS))
def test_the_batch_flood_is_the_per_datagram_flood(model: str, link: str | None) -> None:
    one, many = _flood(MODELS[model](), False, link), _flood(MODELS[model](), True, link)
    assert many == one
    assert len(one["down"]) >= 6000 and one["runner"]  # the flood went down; the drone spoke
    if model == "ack-bad-preamble":
        assert len(one["runner"]) > 100  # its ACKs of the flood came back (to the runner's --target)

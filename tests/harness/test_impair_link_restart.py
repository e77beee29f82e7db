"""harness.impair_link on the virtual clock (harness.clock): what the link holds is dropped as the
session replaces the node, so a delayed copy never reaches the next process."""

from __future__ import annotations

from mcp_conform.harness.clock import VirtualClock
from mcp_conform.harness.impair import Impairment, parse_impairment
from mcp_conform.harness.impair_link import ImpairedLink


class _Sock:
    def __init__(self, clock: VirtualClock) -> None:
        self.clock, self.sent = clock, []

    def sendto(self, data: bytes, addr: tuple[str, int]) -> int:
        self.sent.append((self.clock.now, data))
        return len(data)


def _run(drop: bool) -> list[tuple[float, bytes]]:
    clock = VirtualClock(start=0.0)
    sock = _Sock(clock)
    link = ImpairedLink(Impairment(parse_impairment("delay=100-100ms,seed=1")), clock=clock)

    def main() -> None:
        link.send(sock, b"x" * 20, ("127.0.0.1", 9))
        clock.sleep(0.05)
        if drop:
            assert link.drop_held() == 1
        clock.sleep(1.0)
        link.close()

    clock.run(main)
    return sock.sent


def test_a_held_copy_is_delivered_on_the_virtual_clock_unless_dropped():
    assert _run(drop=False) == [(0.1, b"x" * 20)]
    assert _run(drop=True) == []

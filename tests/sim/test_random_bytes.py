"""The random datagrams of MCP-ROB-6 (``conformance/cases/test_rob.py``, the manager's script in
``harness/mission_script.py``) are drawn as ``getrandbits(32 * n)``'s top byte of each 32-bit
word, not one ``getrandbits(8)`` a byte (issue 38: ~40 ms of each simulated suite run): the same
bytes for a seed and the generator left in the same state, so the runner, the simulator and any
stored capture keep sending what they sent."""

from __future__ import annotations

import random

import pytest

from mcp_conform.conformance.cases.test_rob import _random_bytes
from mcp_conform.spec.codec import MAX_DATAGRAM


@pytest.mark.parametrize("seed", [0, 1, 7, 2**31 - 1, 12345678901234567890])
@pytest.mark.parametrize("n", [0, 1, 3, 4, 5, 31, 1000, MAX_DATAGRAM - 17, MAX_DATAGRAM])
def test_the_same_bytes_and_state_as_one_draw_a_byte(seed: int, n: int) -> None:
    per_byte, fast = random.Random(seed), random.Random(seed)
    per_byte.random(), fast.random()  # a generator already drawn from, as in a case
    want = bytes(per_byte.getrandbits(8) for _ in range(n))
    assert _random_bytes(fast, n) == want
    assert fast.getstate() == per_byte.getstate()
    assert fast.getrandbits(8) == per_byte.getrandbits(8)


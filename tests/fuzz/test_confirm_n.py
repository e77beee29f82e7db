"""The one N-of-N rule of both protocols' triage (``fuzz.confirm``): what it counts, when it
stops, and what an environment-dependent hit's note says."""

from __future__ import annotations

import pytest

from mcp_conform.fuzz.budget import Late
from mcp_conform.fuzz.confirm import confirm_n
from mcp_conform.fuzz.environment import EnvironmentLog


def _replays(shown: list[bool]):  # noqa: ANN202
    calls = []

    def once() -> int | None:
        calls.append(1)
        k = len(calls) - 1
        return k if shown[k] else None
    return once, calls


def test_every_replay_shows_it_n_of_n():
    once, calls = _replays([True, True, True])
    conf = confirm_n(once, 3)
    assert conf.confirmed and conf.hits == [0, 1, 2] and conf.replays == "3 of 3" and len(calls) == 3


def test_the_first_miss_ends_it_unless_every_replay_is_wanted():
    once, calls = _replays([True, False, True])
    conf = confirm_n(once, 3)
    assert not conf.confirmed and len(calls) == 2 and conf.replays == "1 of 3"
    once, calls = _replays([True, False, True])
    conf = confirm_n(once, 3, until_miss=False)
    assert not conf.confirmed and len(calls) == 3 and conf.hits == [0, 2] and conf.replays == "2 of 3"


def test_the_note_counts_triage_s_own_replay_with_the_confirming_ones():
    log = EnvironmentLog()
    once, _ = _replays([False, False, False])
    confirm_n(once, 3, until_miss=False).note(log, "NSQD-ROB-1", "crash", "died", "timing or load")
    once, _ = _replays([True, False, True])
    confirm_n(once, 3).note(log, "MCP-ACK-1", "valid WP_OFF", "no ACK", "timing or load")
    got = {e["rule"]: e["why"] for e in log.values()}
    assert got["NSQD-ROB-1"].startswith("reproduced 1 of 4 replays"), got
    assert got["MCP-ACK-1"].startswith("reproduced 2 of 3 replays"), got


def test_the_deadline_passes_through():
    def once() -> int | None:
        raise Late

    with pytest.raises(Late):
        confirm_n(once, 3)

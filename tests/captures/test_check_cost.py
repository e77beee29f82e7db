"""What makes ``mcp-capture check`` of a million violations cheaper (issue 17), checked for
what it must not change: the same records read, the same judgement, the same JSON bytes.

No timing here (bench/bench_capture_tools.py prints the seconds and the peak RSS).
"""

from __future__ import annotations

import gc
from pathlib import Path
from typing import Any

import pytest

from judge.judging import NoJudge, Params, judge
from spec.codec import Action, Message, encode
from traceio.recorder import McapRecorder


def _capture(path: Path, n: int = 20) -> Path:
    with McapRecorder(path, local=("127.0.0.1", 7889)) as rec:
        for i in range(n):
            rec.datagram("rx", encode(Message(0, 1 + i % 3, i, Action.MISSION_READY, None)),
                         ("127.0.0.1", 41001 + i % 3), 1_800_000_000_000_000_000 + i * 1_000_000)
    return path


class _Spy(NoJudge):
    """Notes whether the cyclic collector was on as each datagram was judged."""

    def __init__(self, fail_at: int | None = None) -> None:
        self.enabled: list[bool] = []
        self.fail_at = fail_at

    def datagram(self, *args: Any, **kw: Any) -> list[Any]:
        self.enabled.append(gc.isenabled())
        if len(self.enabled) == self.fail_at:
            raise RuntimeError("judge failed")
        return []


@pytest.mark.parametrize("was", [True, False])
def test_the_collector_is_off_while_judging_and_as_it_was_after(tmp_path: Path, was: bool) -> None:
    """Judging keeps every violation and its evidence (millions of tuples): the collector's
    passes over them were a fifth of checking a million violations. Off while judging,
    as it was before once judging ends, and when judging fails too."""
    cap = _capture(tmp_path / "c.mcap")
    (gc.enable if was else gc.disable)()
    try:
        spy = _Spy()
        judge(cap, Params(), monitor=spy)
        assert spy.enabled == [False] * 20
        assert gc.isenabled() is was
        with pytest.raises(RuntimeError, match="judge failed"):
            judge(cap, Params(), monitor=_Spy(fail_at=3))
        assert gc.isenabled() is was
    finally:
        gc.enable()

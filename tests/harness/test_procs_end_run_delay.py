"""A process that ends by itself keeps its run delay (``harness.procs``, D-7): its
``/proc/<pid>`` goes when it is reaped, and a manager that closes once its mission is done is
reaped by the first liveness check that finds it gone -- before the runner stops it and reads
its run delay a last time (``SpawnedNode.before_stop``). Every ``poll`` and ``wait`` reads it
first, between the exit and the reaping (``waitid(..., WNOWAIT)``), and keeps it."""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import pytest

from mcp_conform.harness.procs import ManagedProcess
from mcp_conform.harness.run_delay import run_delay_ns

pytestmark = [
    pytest.mark.skipif(not Path("/proc/self/schedstat").exists(),
                       reason="no /proc/<pid>/schedstat: a run delay cannot be read on this system"),
    pytest.mark.skipif(not hasattr(os, "waitid") or not hasattr(os, "WNOWAIT"),
                       reason="no waitid(WNOWAIT): an ended process cannot be looked at unreaped"),
]

#: the node's last act: its own run delay, summed over its threads as harness.run_delay sums them
SAYS_ITS_RUN_DELAY = """
import os, time
t = time.monotonic()
while time.monotonic() - t < 0.05:
    pass
total = 0
for tid in os.listdir("/proc/self/task"):
    with open(f"/proc/self/task/{tid}/schedstat") as f:
        total += int(f.read().split()[1])
print(total, flush=True)
"""


def _ended(how: str) -> ManagedProcess:
    """The process started, ended by itself, and reaped by the way ``how`` names."""
    p = ManagedProcess([sys.executable, "-c", SAYS_ITS_RUN_DELAY])
    if how == "poll":  # the runner's liveness checks
        end = time.monotonic() + 30
        while p.alive() and time.monotonic() < end:
            time.sleep(0.01)
    elif how == "wait":
        p.proc.wait(timeout=30)
    else:
        p.proc.wait()
    assert p.returncode == 0
    return p


@pytest.mark.parametrize("how", ["poll", "wait", "wait-no-timeout"])
def test_a_process_that_ended_by_itself_keeps_its_run_delay_once_reaped(how: str) -> None:
    p = _ended(how)
    out, err = p.output(5)
    assert out and not err, (out, err)
    said = int(out[-1])  # what it read of itself as its last act
    assert p.proc.returncode is not None  # reaped: /proc/<pid> is gone, or another process's
    got = p.run_delay()
    assert got is not None and got >= said


def test_a_running_process_is_read_now_and_a_stopped_one_as_it_ended() -> None:
    p = ManagedProcess([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        now = p.run_delay()
        assert now is not None and now == pytest.approx(run_delay_ns(p.pid), abs=10**9)
    finally:
        p.stop(0.5)
    assert not p.alive()
    ended = p.run_delay()
    assert ended is not None and ended >= now

"""``harness.procs``' parent-death signal, set with no Python in the child (issue 40 item 4:
``preexec_fn`` is documented unsafe while threads run, and the runner's do): the node under
test is started through ``setpriv --pdeathsig KILL`` and a ``sh`` guard, and the kernel
SIGKILLs it when the runner dies, however it dies (prctl(2) PR_SET_PDEATHSIG). The node's
pid and command line are its own. Linux only; skipped where setpriv(1) is not there (the
reaper alone covers that case: tests/conformance/test_faults.py's kill -9 test)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from mcp_conform.harness import procs

ROOT = Path(__file__).resolve().parents[2]
GONE_WITHIN = 10.0  # s: the kernel sends the signal as the runner exits; generous under load

pytestmark = pytest.mark.skipif(procs._wrapper() is None,
                                reason="no setpriv(1) with --pdeathsig here: only the reaper kills orphans")

#: the node: reads its own parent-death signal (prctl(2) PR_GET_PDEATHSIG = 2), its pid and
#: its command line, then waits to be killed
NODE = textwrap.dedent("""
    import ctypes, os, signal, sys, time
    libc = ctypes.CDLL(None, use_errno=True)
    sig = ctypes.c_int(0)
    libc.prctl(2, ctypes.byref(sig), 0, 0, 0)
    argv = open("/proc/self/cmdline", "rb").read().split(b"\\0")[:-1]
    print("deathsig", sig.value, "pid", os.getpid(), "argv0", argv[0].decode(), flush=True)
    time.sleep(float(sys.argv[1]))
""")

#: the runner: spawns the node through harness.procs from a thread while another thread
#: busies itself (the case preexec_fn was unsafe for), with the reaper switched off so only
#: the death signal can kill the node; prints the node's pid once the node has written its
#: line (a node still starting would die of the closed pipe instead), then waits to be killed
RUNNER = textwrap.dedent("""
    import sys, threading, time
    from mcp_conform.harness import procs
    procs.Reaper._start = lambda self: None  # the reaper off: the death signal alone
    stop = threading.Event()
    threading.Thread(target=lambda: [time.sleep(0.001) for _ in iter(stop.is_set, True)], daemon=True).start()
    box = []
    spawner = threading.Thread(target=lambda: box.append(procs.ManagedProcess(sys.argv[1:])))
    spawner.start()
    spawner.join()
    deadline = time.monotonic() + 60
    while not box[0].output()[0] and time.monotonic() < deadline:  # the node has started and written
        time.sleep(0.01)
    print(box[0].pid, flush=True)
    time.sleep(120)
""")


def _alive(pid: int) -> bool:
    """Whether ``pid`` is a live process (a zombie is dead, waiting to be reaped)."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            return f.read().rsplit(b")", 1)[1].split()[0] != b"Z"
    except OSError:
        return False


def test_the_node_carries_sigkill_as_its_parent_death_signal_its_pid_and_argv_its_own():
    p = procs.ManagedProcess([sys.executable, "-c", NODE, "0"])
    try:
        assert p.proc.wait(timeout=60) == 0, p.output()
        out, err = p.output()
        assert out == [f"deathsig {int(signal.SIGKILL)} pid {p.pid} argv0 {sys.executable}"], (out, err)
    finally:
        p.stop()


def test_sigkill_of_the_runner_kills_the_node_it_spawned_from_a_thread():
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    runner = subprocess.Popen([sys.executable, "-c", RUNNER, sys.executable, "-c", NODE, "120"], cwd=ROOT,
                              env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    node = None
    try:
        assert runner.stdout is not None
        line = runner.stdout.readline()
        assert line.strip().isdigit(), (line, runner.stderr.read() if runner.poll() is not None else "")
        node = int(line)
        assert _alive(node)
        runner.kill()
        runner.wait(timeout=30)
        deadline = time.monotonic() + GONE_WITHIN
        while _alive(node) and time.monotonic() < deadline:
            time.sleep(0.02)
        assert not _alive(node), f"node {node} still alive {GONE_WITHIN:g} s after its runner's SIGKILL"
    finally:
        runner.kill()
        runner.wait(timeout=30)
        if node is not None and _alive(node):
            os.kill(node, signal.SIGKILL)


def test_a_runner_dead_before_the_signal_was_set_means_no_node():
    """The guard after setpriv: the parent is no longer the runner (here: pid 1 named as
    the runner, as an orphan's parent would be), so the command never runs (exit 137)."""
    wrapper = procs._wrapper()
    assert wrapper is not None
    run = subprocess.run([*wrapper, "1", sys.executable, "-c", "print('ran')"], capture_output=True,
                         text=True, timeout=60)
    assert run.returncode == 137 and run.stdout == "", (run.returncode, run.stdout, run.stderr)


@pytest.mark.parametrize("command,error", [("/nonexistent/node", FileNotFoundError),
                                           ("no-such-command-anywhere", FileNotFoundError),
                                           ("/", PermissionError)])
def test_a_command_that_cannot_run_raises_as_popen_would(command, error):
    """The wrapper itself starts, so the command's own error is checked before: an OSError,
    not a process exiting 127 (``harness.session_base.SpawnedNode`` turns it into a setup error)."""
    with pytest.raises(error):
        procs.ManagedProcess([command])

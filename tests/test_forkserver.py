"""The tests' fork server (tests/forkserver.py) runs ``python -m mcp_conform.conformance`` (and
``captures``, ``fuzz``) as a fresh interpreter does: same exit status, same output, the caller's working directory and
environment, its own process, killed at the timeout."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests import forkserver

ROOT = Path(__file__).resolve().parents[1]
ENV = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1")


def _both(args: list[str], cwd: Path = ROOT, env: dict[str, str] = ENV) -> tuple[subprocess.CompletedProcess[str], ...]:
    fresh = subprocess.run([sys.executable, "-m", "mcp_conform.conformance", *args], cwd=cwd, env=env, capture_output=True,
                           text=True, timeout=60)
    forked = forkserver._CLIENT.run(args, cwd=cwd, env=env, timeout=60)
    return fresh, forked


@pytest.mark.parametrize("args", [["--version"], ["--list", "--select", "MCP-SEQ"], ["--rto", "zero"],
                                  ["--role", "manager", "--list"], ["--protocol", "nsqd", "--list"]],
                         ids=["version", "list", "bad-option", "manager-list", "nsqd-list"])
def test_a_forked_run_matches_a_fresh_interpreter(args: list[str]) -> None:
    fresh, forked = _both(args)
    assert (forked.returncode, forked.stdout, forked.stderr) == (fresh.returncode, fresh.stdout, fresh.stderr)
    assert fresh.stdout or fresh.stderr  # the comparison compared something


GOLDEN = ROOT / "captures" / "golden" / "challenge1.mcap"
SUITE = ROOT / "captures" / "golden" / "drone-suite.mcap"


@pytest.mark.parametrize(("module", "args"), [("captures", ["check", str(GOLDEN)]),
                                              ("captures", ["show", "/nonexistent/x.mcap"]),
                                              ("fuzz", ["--max-cases", "many"])],
                         ids=["capture-check", "capture-missing-file", "fuzz-bad-option"])
def test_a_forked_capture_or_fuzz_run_matches_a_fresh_interpreter(module: str, args: list[str]) -> None:
    """The other served modules (``SERVED``): what their ``__main__`` exits with, as it prints it."""
    fresh = subprocess.run([sys.executable, "-m", f"mcp_conform.{module}", *args], cwd=ROOT, env=ENV,
                           capture_output=True, text=True, timeout=60)
    forked = forkserver._CLIENT.run(args, cwd=ROOT, env=ENV, timeout=60, module=module)
    assert (forked.returncode, forked.stdout, forked.stderr) == (fresh.returncode, fresh.stdout, fresh.stderr)
    assert fresh.stdout or fresh.stderr


def _out_of_memory(text: str) -> bool:
    """An allocation refused, as Python (MemoryError) or a C library (lz4's decompressor) says it."""
    return any(w in text for w in ("MemoryError", "allocation_failed", "Cannot allocate memory", "out of memory"))


def test_an_address_space_limit_is_the_childs_as_prlimit_sets_it() -> None:
    """``limit_as``: under 64 MiB a check of the drone suite's capture runs out of memory (a
    MemoryError), as under prlimit(1) in a fresh interpreter; the next run, unlimited, does
    not: the server and its later children are not limited. (A forked child starts with the
    server's modules loaded and may check a small capture from the heap it already has: the
    capture read here is larger, 245 KB, than a fresh allocation the limit leaves room for.)"""
    small = 64 * 2**20
    args = ["check", str(SUITE)]
    forked = forkserver._CLIENT.run(args, cwd=ROOT, env=ENV, timeout=60, module="captures", limit_as=small)
    # where it runs out depends on what the child must still allocate: the capture's chunks, or
    # (from a fresh clone, no bytecode cached) compiling a subcommand's module first; either way
    # one line, exit 2, never "corrupt" (that would judge a capture read in part as a cut one)
    assert forked.returncode == 2 and "out of memory" in forked.stderr, forked.stderr[-2000:]
    assert "Traceback" not in forked.stderr and "corrupt" not in forked.stderr, forked.stderr[-2000:]
    assert len(forked.stderr.strip().splitlines()) == 1, forked.stderr[-2000:]
    again = forkserver._CLIENT.run(args, cwd=ROOT, env=ENV, timeout=60, module="captures")
    assert again.returncode in (0, 1) and not _out_of_memory(again.stderr + again.stdout), again.stderr
    if shutil.which("prlimit") is not None:
        with pytest.MonkeyPatch.context() as mp:
            mp.setenv("MCP_TEST_FORKSERVER", "0")
            fresh = forkserver.run_module("captures", args, cwd=ROOT, env=ENV, timeout=60, limit_as=small)
        assert fresh.returncode != 0 and _out_of_memory(fresh.stderr), fresh.stderr[-2000:]


def test_the_callers_directory_and_environment_are_the_childs(tmp_path: Path) -> None:
    """A relative --json lands in the caller's directory; an MCP_CONFORM_ variable set after
    the server started reaches the run (its seed in the report)."""
    env = dict(ENV, MCP_CONFORM_SEED="4242")
    forked = forkserver._CLIENT.run(["--list", "--json", "r.json"], cwd=tmp_path, env=env, timeout=60)
    assert forked.returncode == 0, forked.stderr
    report = (tmp_path / "r.json").read_text()
    assert '"seed": 4242' in report


def test_a_run_past_its_timeout_is_killed(tmp_path: Path) -> None:
    """As ``subprocess.run(timeout=...)``: TimeoutExpired raised and the child killed (the
    server has no child left, where the run itself would wait 30 s for its target)."""
    # a port of its own: the default (7889) may be another run's on a shared host, and a run
    # that cannot bind it ends at once instead of waiting
    hang = ["--target", "127.0.0.1:9", "--listen", "127.0.0.1:0", "--startup-timeout", "30", "--timeout", "60"]
    with pytest.raises(subprocess.TimeoutExpired):
        forkserver._CLIENT.run(hang, cwd=tmp_path, env=ENV, timeout=1.0)
    server = forkserver._CLIENT._servers[forkserver._key(ENV)].proc.pid
    children = Path(f"/proc/{server}/task/{server}/children")
    if not children.exists():
        pytest.skip("this kernel does not list a process's children in /proc")
    for _ in range(100):  # the server reaps the killed child within its 20-ms select loop
        if not children.read_text().split():
            break
        time.sleep(0.1)
    assert not children.read_text().split(), "the timed-out run is still running"


def test_an_environment_read_at_import_gets_a_server_imported_with_it() -> None:
    """pymavlink picks its dialect module when mavutil is imported and mavwp asks the
    environment when it loads a waypoint file: a caller whose environment gained MAVLINK20
    after its first run (mavutil sets it on the first MAVLink 2 frame it reads) is served by
    a server imported with it. One server for both gave the second run a MAVLink 1 message
    class handed MAVLink 2's arguments: every manager-role case an error."""
    args = ["--role", "manager", "--waypoints", "examples/mission.waypoints", "--select", "MCP-ACK-1"]
    without = {k: v for k, v in ENV.items() if k != "MAVLINK20"}
    for env in (without, dict(without, MAVLINK20="1"), without):  # a fresh interpreter passes each
        forked = forkserver._CLIENT.run(args, cwd=ROOT, env=env, timeout=60)
        assert forked.returncode == 0 and "1 passed" in forked.stdout, (env.get("MAVLINK20"), forked.stdout)

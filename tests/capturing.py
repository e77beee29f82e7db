"""Test helpers shared by the test packages: packet captures by tcpdump or dumpcap on this
host (started and waited for, bounded; stopped with SIGINT so they close their files; the
kernel's drop count read from their own words) and free ports."""

from __future__ import annotations

import argparse
import contextlib
import io
import re
import signal
import socket
import subprocess
import time
from pathlib import Path

import pytest

__all__ = ["dropped_by_kernel", "free_port", "start_capture", "stop_capture", "wait_for_port"]


def free_port(kind: int = socket.SOCK_DGRAM, host: str = "127.0.0.1") -> int:
    """A port nothing is bound to now, UDP by default, ``socket.SOCK_STREAM`` for TCP: chosen
    as the runner chooses its nodes' ports (``vehicle.ports.free_port``, which takes the host
    first), below the ephemeral range, where no other process's bind(0) can take it first."""
    from mcp_conform.vehicle.ports import free_port as below_ephemeral

    return below_ephemeral(host, kind)


def wait_for_port(port: int, host: str = "127.0.0.1", timeout: float = 10.0) -> bool:
    """Whether a TCP listener answers on ``port`` within ``timeout`` s (polled, bounded)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        with socket.socket() as s, contextlib.suppress(OSError):
            s.settimeout(0.2)
            s.connect((host, port))
            return True
        time.sleep(0.05)
    return False


def start_capture(cmd: list[str], log: Path, ready: str) -> subprocess.Popen[bytes]:
    """Start a capture tool and wait (bounded) until it says it is capturing; SKIP when it
    cannot capture here (not installed, no permission)."""
    err = open(log, "wb")  # noqa: SIM115 - closed with the process below
    try:
        proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=subprocess.DEVNULL, stderr=err)
    except FileNotFoundError:
        err.close()
        pytest.skip(f"{cmd[0]} is not installed (.ci/apt-tools installs it)")
    err.close()
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        if ready in log.read_text(errors="replace"):
            return proc
        if proc.poll() is not None:
            pytest.skip(f"{cmd[0]} cannot capture here: {log.read_text(errors='replace').strip()[-300:]}")
        time.sleep(0.05)
    proc.kill()
    pytest.skip(f"{cmd[0]} did not start capturing within 15 s")
    raise AssertionError  # unreachable


def stop_capture(proc: subprocess.Popen[bytes]) -> None:
    """SIGINT: both tcpdump and dumpcap flush and close their file."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(5)


def dropped_by_kernel(log: Path) -> int | None:
    """The packets the kernel dropped, as the tool said on exit (None: it did not say)."""
    found = re.findall(r"(\d+) packets? dropped by kernel", log.read_text(errors="replace"))
    return sum(int(n) for n in found) if found else None


def run_subcommand(module, *argv: str) -> tuple[int, str, str]:  # noqa: ANN001 - a captures.* module
    """One ``mcp-capture`` subcommand (the module's ``register``) in process: (code, out, err)."""
    parser = argparse.ArgumentParser(prog="mcp-capture")
    module.register(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(list(argv))
    out, err = io.StringIO(), io.StringIO()
    return args.run(args, out, err), out.getvalue(), err.getvalue()

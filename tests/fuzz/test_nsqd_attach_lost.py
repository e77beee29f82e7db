"""An attached Nsqd backend killed mid-campaign (``mcp-fuzz --protocol nsqd --target``): the
campaign ends there, exit 2, one line naming the backend, ``summary.json`` with the counts so far
and ``"node_lost": true``, and no finding -- as an MCP campaign ends on a node lost in attach
mode (test_campaign_faults' item 1). Before, the dead backend's silence was triaged like a
live one's: its replays ran on the same dead backend (attach mode has no other) and "confirmed"
an NSQD-ROB-1 hang, "not accepting", 3 of 3 -- the stateless engine counted it 53,452 times
over the rest of a 40-s campaign and exited 1; a hit and a replay in attach mode now first find
the backend live (``fuzz.nsqd_backend.Backend.check_live``)."""

from __future__ import annotations

import signal
import socket
import subprocess
import sys
from pathlib import Path

import pytest

from mcp_conform.vehicle.ports import free_port
from tests.fuzz.test_campaign_faults import ROOT, STATUS, _finish, _fuzz, _wait_status, assert_lost

pytestmark = pytest.mark.slow


@pytest.mark.parametrize("engine", ["stateless", "stateful"])
def test_a_killed_attached_backend_ends_the_campaign_without_a_finding(tmp_path: Path, engine: str) -> None:
    port = free_port(kind=socket.SOCK_STREAM)
    backend = subprocess.Popen([sys.executable, "-m", "mcp_conform.reference_impl", "--protocol", "nsqd", "backend",
                                "--listen", f"127.0.0.1:{port}", "--update-period", "0.1"],
                               cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    out_dir = tmp_path / "out"
    try:
        assert backend.stdout is not None and backend.stdout.readline().startswith("listening on")
        proc = _fuzz(["--protocol", "nsqd", "--engine", engine, "--target", f"127.0.0.1:{port}", *STATUS,
                      "--duration", "120", "--out", str(out_dir)])
        _wait_status(proc)
        backend.send_signal(signal.SIGKILL)
        rc, out, err = _finish(proc)
    finally:
        backend.kill()
        backend.wait(timeout=10)
    summary = assert_lost(rc, out, err, out_dir, f"127.0.0.1:{port}", "accepts no connection")
    assert summary["cases"] > 0 and summary["elapsed_s"] < 120, summary  # ended at the loss
    assert summary["findings"] == [] and not list(out_dir.glob("finding-*")), summary["findings"]

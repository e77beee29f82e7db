"""--jobs and the shared example database: workers with their own nodes, and a failure one
worker found replayed first by another through hypothesis's Redis database (a real
redis-server on a free loopback port)."""

from __future__ import annotations

import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from mcp_conform.fuzz.campaign import run_campaign, run_worker
from mcp_conform.fuzz.config import FuzzConfig
from mcp_conform.fuzz.findings import FindingStore
from tests.capturing import free_port
from tests.fuzz.test_faulty_nodes import spawn_command


@pytest.fixture
def redis_url(tmp_path: Path) -> Iterator[str]:
    exe = shutil.which("redis-server")
    if exe is None:
        pytest.skip("redis-server is not installed (Debian package redis-server, .ci/apt-tools)")
    port = free_port(socket.SOCK_STREAM)
    proc = subprocess.Popen([exe, "--port", str(port), "--bind", "127.0.0.1", "--save", "",
                             "--appendonly", "no", "--dir", str(tmp_path)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        from redis import Redis

        r = Redis(host="127.0.0.1", port=port)
        for _ in range(100):
            try:
                if r.ping():
                    break
            except Exception:  # noqa: BLE001 - not up yet
                time.sleep(0.05)
        else:
            pytest.fail("redis-server did not answer")
        yield f"redis://127.0.0.1:{port}/0"
    finally:
        proc.terminate()
        proc.wait(timeout=5)


@pytest.mark.slow
def test_failure_found_by_one_worker_is_replayed_first_by_the_other(redis_url: str) -> None:
    from redis import Redis

    base = FuzzConfig(spawn=spawn_command("no-dup-discard", True), mavlink=True, engine="stateful",
                      seed=6, duration=90.0, max_cases=20_000, rto=0.2, ack_window=0.25, db=redis_url,
                      extra={"stop_on_rule": "MCP-DUP-1"})
    first = FindingStore(None)
    run_worker(base.for_worker(0), first)
    assert "MCP-DUP-1" in first.by_rule()
    host, port = redis_url[len("redis://"):].split("/")[0].split(":")
    assert Redis(host=host, port=int(port)).keys(b"mcp-fuzz:*"), "nothing saved in the shared database"
    # the second worker generates nothing: it only replays what the database holds
    second_cfg = base.for_worker(1)
    second_cfg.extra = {"reuse_only": True}
    second = FindingStore(None)
    res = run_worker(second_cfg, second)
    assert "MCP-DUP-1" in second.by_rule(), res.engines
    assert res.engines["stateful"]["cases"] > 0


@pytest.mark.slow
def test_jobs_run_workers_on_their_own_nodes(tmp_path: Path) -> None:
    cfg = FuzzConfig(engine="stateless", jobs=2, seed=5, max_cases=2000, out=str(tmp_path))
    summary = run_campaign(cfg, FindingStore(tmp_path))
    assert [w["worker"] for w in summary["workers"]] == [0, 1]
    assert all(w["cases"] == 2000 and w["error"] is None for w in summary["workers"])
    assert summary["cases"] == 4000 and summary["findings"] == 0
    assert (tmp_path / "summary.json").exists()

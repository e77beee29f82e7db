"""Run ``mcp-conform`` as a user would (a subprocess) and read its JSON report."""

from __future__ import annotations

import json
import os
import shlex
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from tests.capturing import free_port  # noqa: F401  (re-exported for the runner tests)
from tests.forkserver import run_module

ROOT = Path(__file__).resolve().parents[2]
SAMPLE_NODE = ROOT / "tests" / "conformance" / "nodes" / "sample_node.py"
FAST = ["--rto", "0.2", "--ack-window", "0.25"]


@dataclass
class RunResult:
    rc: int
    report: dict[str, Any]
    output: str

    @property
    def rules(self) -> dict[str, str]:
        return self.report.get("rules", {})

    def rules_with(self, *outcomes: str) -> dict[str, str]:
        return {r: o for r, o in self.rules.items() if o in outcomes}

    def cases_with(self, *outcomes: str) -> list[dict[str, Any]]:
        return [c for c in self.report.get("cases", []) if c["outcome"] in outcomes]

    def explain(self) -> str:
        bad = self.cases_with("failed", "warned", "error")
        lines = [f"exit {self.rc}; error={self.report.get('error')!r}"]
        for c in bad:
            lines.append(f"{c['outcome']}: {c['id']} {c['rules']}: {c.get('reason') or ''} "
                         f"expected={c.get('expected')!r} actual={c.get('actual')!r}")
        lines.append("--- output tail ---")
        lines.append("\n".join(self.output.splitlines()[-40:]))
        return "\n".join(lines)


def run_conform(*args: str, timeout: float = 240.0) -> RunResult:
    """``python -m mcp_conform.conformance ARGS --json FILE`` from the repository root (a child of the
    tests' fork server, ``tests/forkserver.py``, unless ``MCP_TEST_FORKSERVER=0``)."""
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "report.json"
        env = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1")
        proc = run_module("conformance", [*args, "--json", str(path)], cwd=ROOT, env=env, timeout=timeout)
        report = json.loads(path.read_text()) if path.exists() else {}
    return RunResult(proc.returncode, report, proc.stdout + proc.stderr)


def sample_node_command(*extra: str, rto: float = 0.2) -> str:
    """The independent test node, with the runner's placeholders."""
    words = [sys.executable, str(SAMPLE_NODE), "--id", "{id}", "--bind", "{target_host}:{target_port}",
             "--send-to", "{listen_host}:{listen_port}", "--mavlink", "{mavlink}", "--rto", str(rto), *extra]
    return " ".join(shlex.quote(w) if "{" not in w else w for w in words)


def reference_node_command(rto: float = 0.2) -> str:
    return (f"{shlex.quote(sys.executable)} -m mcp_conform.reference_impl drone --id {{id}} --bind "
            f"{{target_host}}:{{target_port}} --send-to {{listen_host}}:{{listen_port}} "
            f"--mavlink {{mavlink}} --rto {rto}")


SAMPLE_MANAGER = ROOT / "tests" / "conformance" / "nodes" / "sample_manager.py"


def sample_manager_command(*extra: str, rto: float = 0.2, retries: int = 12,
                           send_to: str = "{listen_host}:{listen_port}") -> str:
    """The independent test manager, with the runner's manager-role placeholders."""
    words = [sys.executable, str(SAMPLE_MANAGER), "--challenge", "{challenge}", "--drones", "{drones}",
             "--waypoints", "{waypoints}", "--obstacles", "{obstacles}", "--bind", "{target_host}:{target_port}",
             "--send-to", send_to, "--rto", str(rto), "--retries", str(retries), *extra]
    return " ".join(shlex.quote(w) if "{" not in w else w for w in words)


def verdict_differences(live: dict[str, dict[str, str]], offline: dict[Any, dict[str, str]]) -> list[tuple]:
    """(node, rule, live verdict, offline verdict) wherever a run's monitor section and a
    judgement of its capture (judge.judging) disagree."""
    off = {str(k): v for k, v in offline.items()}
    return [(n, r, live.get(n, {}).get(r), off.get(n, {}).get(r))
            for n in sorted(set(live) | set(off))
            for r in sorted(set(live.get(n, {})) | set(off.get(n, {})))
            if live.get(n, {}).get(r) != off.get(n, {}).get(r)]


def wait_first_datagram(listen_port: int, timeout: float = 30.0) -> None:
    """Until a node started in the background has sent its first datagram to
    ``listen_port`` (read here on a socket of our own, closed at once: its Mission_Ready is
    retransmitted until ACKed). Attach mode expects a running node; a loaded host can take
    seconds from a node's start to its first Mission_Ready, longer than the runner waits
    for it (2.5 x --rto + 1 s) before it probes instead."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", listen_port))
        s.settimeout(timeout)
        try:
            s.recvfrom(65535)
        except TimeoutError:
            raise AssertionError(f"no datagram from the node on port {listen_port} within {timeout} s") from None

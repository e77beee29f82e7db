"""mcp-conform end to end: the reference drone passes in every mode; setup errors exit 2.

These run the runner as a user does (``python -m mcp_conform.conformance``, a subprocess) and read the
JSON report it writes. Timing figures are printed by the runner, never asserted here.
The spawned reference node with the vehicle on TCP is one run for two tests (``tcp_vehicle``);
the suite under pytest-xdist (each worker its own node, one JSON) is test_xdist.py's run.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from mcp_conform.spec import SPEC
from tests.spawned import attached_node
from tests.xdist_once import once

from .runner_helpers import (
    FAST,
    ROOT,
    RunResult,
    free_port,
    reference_node_command,
    run_conform,
)

pytestmark = pytest.mark.slow


def _assert_clean_pass(res):
    assert res.rc == 0, res.explain()
    assert res.report["error"] is None, res.explain()
    assert not res.cases_with("failed", "warned", "error"), res.explain()
    must = {r.id for r in SPEC.rules_for("drone") if r.level == "MUST"}
    assert not {r for r in must if res.rules.get(r) == "failed"}, res.explain()


def test_embedded_default_passes_every_must_and_should():
    res = run_conform()
    _assert_clean_pass(res)
    # the suite observed, not just skipped: the vehicle and startup rules were judged
    for rule in ("MCP-ACK-1", "MCP-RTX-1", "MCP-RTX-3", "MCP-BLK-4", "MCP-BLK-5", "MCP-BLK-7",
                 "MCP-DUP-1", "MCP-DUP-3", "MCP-SEQ-3", "MCP-PAY-8", "MCP-ROB-7"):
        assert res.rules[rule] == "passed", (rule, res.explain())
    assert res.report["parameters"]["mode"] == "embedded"


@pytest.fixture(scope="module")
def tcp_vehicle(tmp_path_factory) -> RunResult:
    """The drone-role suite against the spawned reference node with the vehicle on TCP
    (``--mavlink``'s default): one run for the spawn-mode test and the UDP tests' comparison,
    once per test session (tests/xdist_once.py: its exit status, report and output are shared
    by the xdist workers; the node itself is gone by then)."""
    def run(_: Path) -> list:
        res = run_conform("--spawn", reference_node_command(), "--mavlink", "tcp", *FAST)
        return [res.rc, res.report, res.output]

    rc, report, output = once(tmp_path_factory, "tcp-vehicle", run)
    return RunResult(rc, report, output)


def test_spawn_mode_reference_node_passes(tcp_vehicle):
    _assert_clean_pass(tcp_vehicle)
    assert tcp_vehicle.rules["MCP-BLK-5"] == "passed", tcp_vehicle.explain()


@pytest.fixture(scope="module")
def tcp_vehicle_rules(tcp_vehicle):
    """The per-rule outcomes of the drone-role suite with the vehicle on TCP."""
    _assert_clean_pass(tcp_vehicle)
    return tcp_vehicle.rules


@pytest.mark.parametrize("transport", ["udp", "udpout"])
def test_spawn_mode_reference_node_passes_with_the_vehicle_over_udp(transport, tcp_vehicle_rules):
    """The drone-role suite over a UDP autopilot link judges every rule as over TCP."""
    res = run_conform("--spawn", reference_node_command(), "--mavlink", transport, *FAST)
    _assert_clean_pass(res)
    assert res.rules == tcp_vehicle_rules, res.explain()
    for rule in ("MCP-BLK-4", "MCP-BLK-5", "MCP-BLK-7", "MCP-DUP-1", "MCP-PAY-8"):
        assert res.rules[rule] == "passed", (rule, res.explain())


def test_attach_mode_reference_node_passes_and_skips_vehicle_rules():
    listen = free_port()
    # attach: the node runs (and speaks) before the runner starts
    with attached_node(lambda port: [sys.executable, "-m", "mcp_conform.reference_impl", "drone", "--id", "3", "--bind",
                                     f"127.0.0.1:{port}", "--send-to", f"127.0.0.1:{listen}", "--rto", "0.2"],
                       listen, cwd=ROOT) as (_, port):
        res = run_conform("--target", f"127.0.0.1:{port}", "--listen", f"127.0.0.1:{listen}", *FAST)
    _assert_clean_pass(res)
    assert res.report["cases"], res.explain()
    for rule in ("MCP-BLK-4", "MCP-BLK-5", "MCP-DUP-1", "MCP-PAY-8"):
        assert res.rules[rule] == "skipped", (rule, res.explain())
    assert res.rules["MCP-ACK-1"] == "passed"
    assert res.rules["MCP-RTX-1"] == "passed", res.explain()  # Mission_Ready copies still seen


def test_target_that_never_answers_is_a_setup_error():
    res = run_conform("--target", f"127.0.0.1:{free_port()}", "--listen", f"127.0.0.1:{free_port()}", *FAST,
                      timeout=60)
    assert res.rc == 2, res.explain()
    assert res.report["error"], res.explain()
    assert "never answered" in res.report["error"]


def test_spawn_command_that_fails_is_a_setup_error():
    res = run_conform("--spawn", f"{sys.executable} -c 'import sys; sys.exit(3)'", *FAST, timeout=60)
    assert res.rc == 2, res.explain()
    assert "exited" in (res.report["error"] or ""), res.explain()


def test_selection_by_rule_marker(tmp_path):
    out = tmp_path / "report.json"
    proc = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "--pyargs", "mcp_conform.conformance.cases",
         "-m", "mcp_ack_4 or mcp_ack_6", "--mcp-json", str(out)],
        cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    import json

    doc = json.loads(out.read_text())
    assert sorted(r for c in doc["cases"] for r in c["rules"]) == ["MCP-ACK-4", "MCP-ACK-6"]
    assert doc["rules"]["MCP-ACK-4"] == doc["rules"]["MCP-ACK-6"] == "passed"

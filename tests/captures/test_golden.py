"""The golden captures: re-recorded and diffed against the committed files; replayed against
the reference nodes (pass) and against a faulty node (fails, naming where)."""

from __future__ import annotations

import io
import shlex
import sys
from pathlib import Path

import pytest

from mcp_conform.captures.diff import DiffOptions, diff_captures, print_report
from mcp_conform.captures.replay import replay
from mcp_conform.captures.scenarios import GOLDEN, record_challenge
from mcp_conform.traceio.reader import Datagram, open_capture
from tests.forkserver import run_module

ROOT = Path(__file__).resolve().parents[2]
SAMPLE = ROOT / "tests" / "conformance" / "nodes" / "sample_node.py"
PY = shlex.quote(sys.executable)
DRONE = (f"{PY} -m mcp_conform.reference_impl drone --id {{id}} --bind {{target_host}}:{{target_port}} "
         "--send-to {listen_host}:{listen_port} --rto 0.5")
MANAGER = (f"{PY} -m mcp_conform.reference_impl manager --challenge {{challenge}} --drones {{drones}} "
           "--waypoints {waypoints} --obstacles {obstacles} --bind {target_host}:{target_port} --send-to {listen_host}:{listen_port} "
           "--rto 0.5")
pytestmark = pytest.mark.slow


def _report(result) -> str:
    buf = io.StringIO()
    print_report(result, buf)
    return buf.getvalue()


def _records(path: Path) -> list[Datagram]:
    return [r for r in open_capture(path) if type(r) is Datagram]


def test_golden_files_are_small_and_whole():
    files = sorted(GOLDEN.glob("*.mcap"))
    assert [f.name for f in files] == ["challenge1.mcap", "challenge2.mcap", "challenge3.mcap", "drone-suite.mcap"]
    for f in files:
        assert f.stat().st_size < 300_000, f
        cap = open_capture(f)
        assert sum(1 for r in cap if type(r) is Datagram) > 0 and cap.truncated is None
        assert f.name in (GOLDEN / "README.md").read_text()


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_challenge_rerecorded_matches_its_golden(tmp_path, challenge):
    out = tmp_path / f"challenge{challenge}.mcap"
    record_challenge(challenge, out)
    result = diff_captures(GOLDEN / f"challenge{challenge}.mcap", out)
    assert result.same, _report(result)
    assert len(result.golden.conversations) == 2  # 0 <-> 1 and 0 <-> 2


def test_drone_suite_rerecorded_matches_its_golden(tmp_path):
    out = tmp_path / "drone-suite.mcap"
    # --serial: the golden is the suite's traffic in its serial order (the schedule runs the
    # silence cases' batch in threads: the same datagrams, their order not fixed)
    proc = run_module("conformance", ["--serial", "--capture", str(out)], cwd=ROOT, timeout=300)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-2000:]
    result = diff_captures(GOLDEN / "drone-suite.mcap", out, DiffOptions())
    # a change to the suite's cases changes what the runner sends: re-record the golden then
    # (captures/golden/README.md), and say so in the commit
    assert result.same, _report(result)


@pytest.mark.parametrize("challenge", [1, 2, 3])
def test_replay_golden_challenge_against_the_reference_drone_and_manager(challenge):
    records = _records(GOLDEN / f"challenge{challenge}.mcap")
    as_drone = replay(records, role="drone", spawn=DRONE, rto=0.5, ack_window=0.3)
    assert as_drone.ok, _report(as_drone.diff)
    assert as_drone.received >= 4 and len(as_drone.diff.candidate.conversations) == 1
    as_manager = replay(records, role="manager", spawn=MANAGER, rto=0.5, ack_window=0.3)
    assert as_manager.ok, _report(as_manager.diff) + as_manager.node_output
    assert len(as_manager.diff.candidate.conversations) == 2


def test_replay_golden_drone_suite_against_the_reference_drone():
    records = _records(GOLDEN / "drone-suite.mcap")
    spawn = (f"{PY} -m mcp_conform.reference_impl drone --id {{id}} --bind {{target_host}}:{{target_port}} "
             "--send-to {listen_host}:{listen_port} --mavlink {mavlink} --rto 0.2")
    result = replay(records, role="drone", spawn=spawn, mavlink=True, rto=0.2, ack_window=0.25)
    assert result.ok, _report(result.diff) + result.node_output
    assert result.sent > 10_000  # the MCP-ROB-7 flood, expanded from its burst record


@pytest.mark.parametrize("fault, what", [
    ("ack-little-endian", "payload"),  # MCP-ACK-2: every ACK names another seq
    ("no-rtl", None),  # MCP-BLK-7 is on the autopilot link: the MCP conversation is the same
])
def test_replay_against_a_faulty_node_names_where(fault, what):
    records = _records(GOLDEN / "challenge2.mcap")
    spawn = (f"{PY} {SAMPLE} --id {{id}} --bind {{target_host}}:{{target_port}} "
             f"--send-to {{listen_host}}:{{listen_port}} --rto 0.5 --fault {fault}")
    result = replay(records, role="drone", spawn=spawn, rto=0.5, ack_window=0.3)
    if what is None:
        assert result.diff.same, _report(result.diff)
        return
    assert not result.ok and result.exit_code == 1
    first = result.diff.divergences[0]
    assert first.kind == "changed" and first.golden.action == 7  # the node's first ACK of a command
    assert any(f == what for f, _, _ in first.fields)
    assert "first divergence (changed) in conversation 0 ↔ 1" in _report(result.diff)


def test_replay_against_the_correct_sample_node_passes():
    records = _records(GOLDEN / "challenge1.mcap")
    spawn = (f"{PY} {SAMPLE} --id {{id}} --bind {{target_host}}:{{target_port}} "
             "--send-to {listen_host}:{listen_port} --rto 0.5")
    result = replay(records, role="drone", spawn=spawn, rto=0.5, ack_window=0.3)
    assert result.ok, _report(result.diff)


def test_replay_command_line(tmp_path):
    out = tmp_path / "replay.json"
    rec = tmp_path / "replay.mcap"
    # the mcp-capture command (python -m mcp_conform.captures), served by the tests' fork server
    proc = run_module("captures", ["replay", str(GOLDEN / "challenge1.mcap"), "--spawn", DRONE, "--rto", "0.5",
                                   "--ack-window", "0.3", "--json", str(out), "--capture-out", str(rec)],
                      cwd=ROOT, timeout=120)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert "same: every conversation matches" in proc.stdout and "monitor: 0 violation(s)" in proc.stdout
    import json

    body = json.loads(out.read_text())
    assert body["ok"] is True and body["diff"]["same"] is True and body["sent"] >= 4
    # the replay's own recording diffs equal to the golden conversation it played
    assert diff_captures(GOLDEN / "challenge1.mcap", rec).summary() == {"missing": 8}  # 0 <-> 2 not played


def test_replay_errors_are_one_line(tmp_path):
    from mcp_conform.captures.cli import main

    assert main(["replay", str(tmp_path / "none.mcap"), "--target", "127.0.0.1:9"]) == 2
    assert main(["replay", str(GOLDEN / "challenge1.mcap")]) == 2  # neither --target nor --spawn
    assert main(["replay", str(GOLDEN / "challenge1.mcap"), "--target", "nohost:xx"]) == 2


def test_replay_in_attach_mode():
    """A node already running (attach): replay sends to --target and listens on --listen."""
    from mcp_conform.harness.drone_session import free_port
    from tests.spawned import attached_node

    listen = free_port()
    with attached_node(lambda p: [sys.executable, "-m", "mcp_conform.reference_impl", "drone", "--id", "1", "--bind",
                                  f"127.0.0.1:{p}", "--send-to", f"127.0.0.1:{listen}", "--rto", "0.5", "-q"],
                       listen, kill=False, cwd=ROOT) as (node, target):
        result = replay(_records(GOLDEN / "challenge3.mcap"), ("127.0.0.1", target), role="drone",
                        listen=("127.0.0.1", listen), rto=0.5, ack_window=0.3)
        assert result.ok, f"{_report(result.diff)}\nthe node: {node.explain()}"
        assert result.received >= 4

"""``--live [HOST:]PORT`` on ``mcp-node``, ``mcp-fuzz`` and ``mcp-soak`` (and ``mcp-conform``'s
option checks; its run: tests/conformance/test_live_foxglove.py): a bad value or a port in
use is one line and exit 2; the node and the soak stream their channels while they run and
stop serving when they end (issue 24 item 2)."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from tests import foxglove_ws
from tests.capturing import free_port

pytest.importorskip("foxglove", reason="foxglove-sdk is not installed")

ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1")


def _node(argv: list[str]) -> int:
    from mcp_conform.reference_impl.cli import main

    try:
        return main(argv)
    except SystemExit as exc:  # argparse's usage error
        return int(exc.code or 0)


def _soak(argv: list[str]) -> int:
    from mcp_conform.soak.cli import main

    try:
        return main(argv)
    except SystemExit as exc:
        return int(exc.code or 0)


def _fuzz(argv: list[str]) -> int:
    from mcp_conform.fuzz.cli import main

    return main(argv)


def _conform(argv: list[str]) -> int:
    from mcp_conform.conformance.cli import main

    return main(argv)


TOOLS: dict[str, tuple[Callable[[list[str]], int], list[str]]] = {
    "mcp-node": (_node, ["drone", "--id", "1"]),
    "mcp-fuzz": (_fuzz, ["--max-cases", "1"]),
    "mcp-soak": (_soak, ["--missions", "1"]),
    "mcp-conform": (_conform, []),
}


@pytest.fixture
def taken_port() -> Iterator[int]:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        yield s.getsockname()[1]


@pytest.mark.parametrize("tool", sorted(TOOLS))
@pytest.mark.parametrize("value", ["x", "1:2:3", "70000", ":8765"])
def test_a_bad_live_value_is_one_line_and_exit_2(tool: str, value: str, capsys: pytest.CaptureFixture[str]) -> None:
    run, argv = TOOLS[tool]
    assert run([*argv, "--live", value]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "--live" in err and repr(value) in err, err


@pytest.mark.parametrize("tool", ["mcp-fuzz", "mcp-soak"])
def test_a_port_in_use_is_one_line_and_exit_2(tool: str, taken_port: int, tmp_path: Path,
                                              capsys: pytest.CaptureFixture[str]) -> None:
    run, argv = TOOLS[tool]
    extra = ["--out", str(tmp_path)] if tool == "mcp-soak" else []
    assert run([*argv, *extra, "--live", f"127.0.0.1:{taken_port}"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines() == [err] and f"--live 127.0.0.1:{taken_port}: cannot serve" in err, err


def test_mcp_conform_with_the_port_in_use_stops_at_once(taken_port: int, tmp_path: Path) -> None:
    report = tmp_path / "r.json"
    proc = subprocess.run([sys.executable, "-m", "mcp_conform.conformance", "--live", f"127.0.0.1:{taken_port}",
                           "--json", str(report)], cwd=ROOT, env=ENV, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert f"--live 127.0.0.1:{taken_port}: cannot serve" in proc.stdout + proc.stderr


@pytest.mark.parametrize("argv, why", [(["--jobs", "2"], "use --jobs 1"),
                                       (["--protocol", "nsqd", "--target", "127.0.0.1:4150"], "--protocol nsqd")])
def test_mcp_fuzz_serves_one_workers_mcp_run(argv: list[str], why: str, capsys: pytest.CaptureFixture[str]) -> None:
    assert _fuzz([*argv, "--live", "0"]) == 2
    assert why in capsys.readouterr().err


@pytest.mark.slow
def test_mcp_node_streams_its_capture_channels_and_stops_on_sigint() -> None:
    wanted = ("/mcp/tx", "/mavlink", "/vehicle/location", "/vehicle/attitude")
    run = foxglove_ws.watch_tool(  # everything seen: Ctrl-C, as a user ends it
        [sys.executable, "-m", "mcp_conform.reference_impl", "drone", "--id", "1", "--bind", "127.0.0.1:0",
         "--send-to", f"127.0.0.1:{free_port()}", "--rto", "0.2"], cwd=ROOT, env=ENV, until=60, wait=30,
        interrupt_when=lambda s: all(s.on(t) for t in wanted))
    seen = run.seen
    assert run.returncode == 130, run.err  # Ctrl-C: the grammar's interrupt (docs/grammar.md)
    assert f"mcp-node: live: ws://127.0.0.1:{run.port}" in run.err
    assert seen.closed and seen.server_info["name"] == "mcp-node"
    for topic in wanted:
        assert any(m.running for m in seen.on(topic)), topic
    ready = seen.on("/mcp/tx")[0].json()
    assert (ready["action_name"], ready["src"]) == ("MISSION_READY", 1)
    fix = seen.on("/vehicle/location")[0].json()
    assert fix["frame_id"] == "drone1" and fix["latitude"] != 0
    assert not foxglove_ws.listening(run.port)


@pytest.mark.slow
def test_mcp_soak_streams_each_view_and_the_missions_outcomes(tmp_path: Path) -> None:
    run = foxglove_ws.watch_tool(
        [sys.executable, "-m", "mcp_conform.soak", "--missions", "2", "--impair", "loss=0.1,seed=3",
         "--drones", "1,2", "--challenges", "1", "--out", str(tmp_path)], cwd=ROOT, env=ENV, until=120)
    seen = run.seen
    assert run.returncode == 0, run.out + run.err
    assert f"mcp-soak: live: ws://127.0.0.1:{run.port}" in run.out
    assert {"/log", "/manager/mcp/tx", "/drone1/mcp/rx", "/drone2/impair"} <= seen.topics()
    for topic in ("/manager/mcp/tx", "/manager/mcp/rx", "/drone1/mcp/rx", "/drone2/mcp/tx", "/drone1/impair"):
        assert any(m.running for m in seen.on(topic)), topic
    assert {m.json()["src"] for m in seen.on("/drone2/mcp/tx") if m.json()["decoded"]} == {2}
    lines = [m.json()["message"] for m in seen.on("/log")]
    assert "mission 1 (seed 4) complete" in lines, lines
    assert seen.closed and not foxglove_ws.listening(run.port)


def test_mcp_fuzz_logs_each_new_finding_with_its_rule_and_evidence() -> None:
    from mcp_conform.fuzz.findings import Finding
    from mcp_conform.fuzz.live import LiveStore

    lines: list[tuple[str, str, str]] = []

    class Recorder:
        def log(self, message: str, level: str = "info", name: str = "", t_ns: int | None = None) -> None:
            lines.append((message, level, name))

    store = LiveStore(None, [], Recorder())
    finding = Finding("MCP-ACK-1", "an ACK of seq 7", "no ACK within 0.25 s", ["00"], "wp_on", "stateless", 1,
                      evidence=["sent WP_On seq 7 at 0.1 s"])
    store.add(finding)
    store.add(Finding(**{**finding.__dict__, "occurrences": 1}))  # the same group: counted, not logged
    assert lines == [("finding MCP-ACK-1 (MUST) [stateless, 1 datagram(s)]: expected an ACK of seq 7; "
                      "actual no ACK within 0.25 s — sent WP_On seq 7 at 0.1 s", "error", "mcp-fuzz")]
    assert store.order[0].occurrences == 2

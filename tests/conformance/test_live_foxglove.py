"""``mcp-conform --live`` (issue 24 item 2): "A WebSocket client receives every channel of a
live ``mcp-conform`` run while it runs."

The run is the whole suite against the embedded reference drone with the simulated vehicle
(``--mavlink``), recorded too (``--capture``), so what the client got live is checked against
the capture written from the same events: the same topics, log times and bytes.
"""

from __future__ import annotations

import base64
import json
import os
import signal
import socket
import subprocess
import sys
from collections import Counter
from pathlib import Path

import jsonschema
import pytest
from mcap.reader import make_reader

from spec.codec import Action, decode
from tests import foxglove_ws
from tests.capturing import free_port
from traceio import fox
from traceio.recorder import CHANNELS

ROOT = Path(__file__).resolve().parents[2]
#: The channels the issue names, each of which must carry messages while the run goes.
WANTED = ("/mcp/tx", "/mcp/rx", "/mavlink", "/vehicle/location", "/vehicle/attitude", "/log",
          "/conformance/case")


def _captured(path: Path) -> list[tuple[int, str, int, bytes]]:
    with path.open("rb") as f:
        return [(m.sequence, ch.topic, m.log_time, bytes(m.data))
                for _s, ch, m in make_reader(f).iter_messages(log_time_order=False)]


@pytest.mark.slow
def test_a_websocket_client_receives_every_channel_of_a_live_run_while_it_runs(tmp_path: Path) -> None:
    port = free_port(socket.SOCK_STREAM)
    capture, report = tmp_path / "run.mcap", tmp_path / "report.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "conformance", "--live", f"127.0.0.1:{port}", "--mavlink",
         "--capture", str(capture), "--json", str(report)],
        cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1"),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    try:
        ws = foxglove_ws.connect(f"ws://127.0.0.1:{port}", alive=lambda: proc.poll() is None)
        # "while it runs": the runner still going and its report (written at the end) not yet there
        seen = foxglove_ws.watch(ws, running=lambda: proc.poll() is None and not report.exists())
        out, _ = proc.communicate(timeout=240)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 0, out
    assert f"live: ws://127.0.0.1:{port}" in out
    assert seen.closed, "the server did not close the connection at the end of the run"
    with socket.socket() as s:  # nothing left listening
        assert s.connect_ex(("127.0.0.1", port)) != 0

    # serverInfo, then every channel of a capture advertised, with the capture's schemas
    assert seen.subprotocol in foxglove_ws.SUBPROTOCOLS
    assert seen.server_info.get("name") == "mcp-conform"
    assert set(CHANNELS) | set(fox.FOXGLOVE_CHANNELS) <= seen.topics()
    for topic in WANTED:
        assert any(m.running for m in seen.on(topic)), f"nothing on {topic} while the run went"

    validators = {c["topic"]: jsonschema.Draft202012Validator(json.loads(c["schema"]))
                  for c in seen.channels.values()}
    for m in seen.messages:
        validators[m.topic].validate(m.json())

    # /log: foxglove.Log lines of cases started and passed, with their rule IDs
    logs = [m.json() for m in seen.on("/log")]
    started = [entry for entry in logs if ": started [MCP-" in entry["message"]]
    passed = [entry for entry in logs if ": passed [MCP-" in entry["message"]]
    assert started and passed, logs[:5]
    assert {entry["level"] for entry in started + passed} == {fox.log_level("info")}
    assert {entry["name"] for entry in started} == {"case"}

    # /mcp/rx: a datagram the node sent, its raw bytes decoding to the fields shown
    rx = next(m.json() for m in seen.on("/mcp/rx") if m.json()["decoded"])
    msg = decode(base64.b64decode(rx["raw_base64"]))
    assert (rx["dst"], rx["src"], rx["seq"], rx["action"]) == (msg.dst, msg.src, msg.seq, int(msg.action))
    assert rx["action_name"] == Action(msg.action).name

    # the same events as the capture: each live message is one of its messages, and from the
    # first one the client got, none written after it was missed
    captured = _captured(capture)
    by_key = {(topic, t, data): seq for seq, topic, t, data in captured}
    live = Counter((m.topic, m.log_time, m.data) for m in seen.messages)
    assert not live - Counter((topic, t, data) for _seq, topic, t, data in captured)
    first = min(by_key[k] for k in live)
    after = Counter((topic, t, data) for seq, topic, t, data in captured if seq >= first)
    assert after == live, f"missed live: {sorted((after - live).elements())[:5]}"


@pytest.mark.slow
def test_an_interrupted_run_stops_serving(tmp_path: Path) -> None:
    """SIGINT mid-run: the runner ends as an interrupted run does (exit 2, its report written),
    the client's connection is closed and nothing is left listening."""
    port = free_port(socket.SOCK_STREAM)
    report = tmp_path / "report.json"
    proc = subprocess.Popen(
        [sys.executable, "-m", "conformance", "--live", f"127.0.0.1:{port}", "--json", str(report)],
        cwd=ROOT, env=dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1"),
        stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)

    def then(s: foxglove_ws.Session) -> None:  # a few cases in: Ctrl-C
        if proc.poll() is None and len(s.on("/conformance/case")) >= 6:
            proc.send_signal(signal.SIGINT)

    try:
        ws = foxglove_ws.connect(f"ws://127.0.0.1:{port}", alive=lambda: proc.poll() is None)
        seen = foxglove_ws.watch(ws, running=lambda: proc.poll() is None, until=120, then=then)
        out, _ = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert proc.returncode == 2, out
    assert json.loads(report.read_text())["error"] == "interrupted by SIGINT"
    assert seen.closed and len(seen.on("/conformance/case")) >= 6
    with socket.socket() as s:
        assert s.connect_ex(("127.0.0.1", port)) != 0

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
import sys
from collections import Counter
from pathlib import Path

import jsonschema
import pytest
from mcap.reader import make_reader

from mcp_conform.spec.codec import Action, decode
from mcp_conform.traceio import fox
from mcp_conform.traceio.recorder import CHANNELS
from tests import foxglove_ws

ROOT = Path(__file__).resolve().parents[2]
ENV = dict(os.environ, PYTHONPATH=str(ROOT), NO_COLOR="1")
#: The channels the issue names, each of which must carry messages while the run goes.
WANTED = ("/mcp/tx", "/mcp/rx", "/mavlink", "/vehicle/location", "/vehicle/attitude", "/log",
          "/conformance/case")


def _captured(path: Path) -> list[tuple[int, str, int, bytes]]:
    with path.open("rb") as f:
        return [(m.sequence, ch.topic, m.log_time, bytes(m.data))
                for _s, ch, m in make_reader(f).iter_messages(log_time_order=False)]


@pytest.mark.slow
def test_a_websocket_client_receives_every_channel_of_a_live_run_while_it_runs(tmp_path: Path) -> None:
    capture, report = tmp_path / "run.mcap", tmp_path / "report.json"
    # "while it runs": the runner still going and its report (written at the end) not yet there
    run = foxglove_ws.watch_tool(
        [sys.executable, "-m", "mcp_conform.conformance", "--mavlink", "--capture", str(capture), "--json", str(report)],
        cwd=ROOT, env=ENV, stderr_to_out=True, wait=240, running=lambda: not report.exists())
    seen, out = run.seen, run.out
    assert run.returncode == 0, out
    assert f"live: ws://127.0.0.1:{run.port}" in out
    assert seen.closed, "the server did not close the connection at the end of the run"
    assert not foxglove_ws.listening(run.port)  # nothing left listening

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
    """SIGINT mid-run: the runner ends as an interrupted run does (exit 130, its report written),
    the client's connection is closed and nothing is left listening."""
    report = tmp_path / "report.json"
    run = foxglove_ws.watch_tool(  # a few cases in: Ctrl-C
        [sys.executable, "-m", "mcp_conform.conformance", "--json", str(report)], cwd=ROOT, env=ENV, stderr_to_out=True,
        until=120, interrupt_when=lambda s: len(s.on("/conformance/case")) >= 6)
    assert run.returncode == 130, run.out
    assert json.loads(report.read_text())["error"] == "interrupted by SIGINT"
    assert run.seen.closed and len(run.seen.on("/conformance/case")) >= 6
    assert not foxglove_ws.listening(run.port)

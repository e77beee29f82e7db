"""``traceio.live`` (issue 24 item 2): the live server serves what the recorder writes, the
same messages as the capture; ``--live`` values; stopping leaves nothing listening."""

from __future__ import annotations

import json
import socket
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.traceio import fox
from mcp_conform.traceio.background import BackgroundRecorder
from mcp_conform.traceio.live import LiveError, LiveServer, parse_live
from mcp_conform.traceio.recorder import CHANNELS, STREAM_CHANNELS, McapRecorder
from tests import foxglove_ws

#: every channel a live server of one view serves
ALL = {*CHANNELS, *fox.FOXGLOVE_CHANNELS, *STREAM_CHANNELS}

pytest.importorskip("foxglove", reason="foxglove-sdk is not installed")
from pymavlink.dialects.v20 import ardupilotmega as mavlink2  # noqa: E402


def _frames() -> list[bytes]:
    mav = mavlink2.MAVLink(None, 1, 1)
    return [mav.global_position_int_encode(5000, 357711030, -786746590, 103_500, 3_000, 1, -2, 0, 9000).pack(mav),
            mav.attitude_encode(5000, 0.1, -0.2, 1.5, 0.0, 0.0, 0.0).pack(mav)]


def _file_messages(path: Path) -> list[tuple[str, int, bytes]]:
    with path.open("rb") as f:
        return [(ch.topic, m.log_time, bytes(m.data)) for _s, ch, m in make_reader(f).iter_messages(log_time_order=False)]


def test_the_live_stream_is_the_capture_message_for_message(tmp_path: Path) -> None:
    server = LiveServer("127.0.0.1", 0)
    feed = server.feed()
    all_topics = len(ALL)
    watcher = foxglove_ws.Watcher(server.url)
    watcher.start()
    _wait_subscribed(server, all_topics)
    rec = McapRecorder(tmp_path / "run.mcap", live=feed, local=("127.0.0.1", 7889))
    t = 1_700_000_000_000_000_000
    rec.case_mark("TRN/test_x", "start", t, rules=["MCP-TRN-2"])
    rec.datagram("rx", encode(Message(0, 1, 7, Action.MISSION_READY, None)), ("127.0.0.1", 7890), t + 1)
    rec.datagram("tx", b"\x00garbage", ("127.0.0.1", 7890), t + 2)
    for i, frame in enumerate(_frames()):
        rec.mavlink("tx", frame, t + 3 + i, drone=1)
    rec.case_mark("TRN/test_x", "end", t + 9, outcome="failed", rules=["MCP-TRN-2"],
                  evidence="no ACK of seq 7 within 0.25 s")
    rec.close()
    server.stop()
    seen = watcher.session()
    assert seen.closed
    assert seen.topics() == ALL
    live = [(m.topic, m.log_time, m.data) for m in seen.messages]
    assert live == _file_messages(tmp_path / "run.mcap")  # same messages, same order
    assert {m.topic for m in seen.messages} >= {"/mcp/rx", "/mcp/tx", "/mavlink", "/vehicle/location",
                                                  "/vehicle/attitude", "/log", "/conformance/case"}
    failed = [m.json() for m in seen.on("/log") if "failed" in m.json()["message"]]
    assert failed == [{**failed[0], "level": fox.log_level("error"),
                       "message": "TRN/test_x: failed [MCP-TRN-2]: no ACK of seq 7 within 0.25 s"}]


def _wait_subscribed(server: LiveServer, n: int, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while server.subscribed() < n:
        assert time.monotonic() < deadline, "the client never subscribed"
        time.sleep(0.01)


def test_a_recorder_of_no_file_feeds_the_server_only(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    got: list[tuple[str, bytes, int]] = []

    class Feed:
        def publish(self, topic: str, data: bytes, t_ns: int) -> None:
            got.append((topic, data, t_ns))

    rec = McapRecorder(None, live=Feed())
    rec.log("campaign started", "info", "mcp-fuzz", 5)
    rec.datagram("tx", b"\x01\x02", ("127.0.0.1", 9), 6)
    rec.add_metadata("x", {"a": 1})
    rec.close()
    rec.log("after close", t_ns=7)  # nothing once closed
    assert [t for t, _, _ in got] == ["/log", "/mcp/tx"] and [t for *_, t in got] == [5, 6]
    assert json.loads(got[0][1])["message"] == "campaign started"
    assert list(tmp_path.iterdir()) == []


def test_segments_are_served_under_their_names() -> None:
    with LiveServer("127.0.0.1", 0, feeds={"drone1": None, None: ("/log",)}) as server:
        assert server.feed("drone1").topic("/mcp/rx") == "/drone1/mcp/rx"
        ws = foxglove_ws.connect(server.url, timeout=5)
        ws.settimeout(2)
        adverts = []
        while len(adverts) < len(ALL) + 1:
            doc = json.loads(ws.recv())
            if doc["op"] == "advertise":
                adverts += doc["channels"]
        ws.close()
    topics = {c["topic"]: c.get("metadata", {}) for c in adverts}
    assert topics.pop("/log") == {}
    assert set(topics) == {f"/drone1{t}" for t in ALL}
    assert all(meta == {"segment": "drone1"} for meta in topics.values())


@pytest.mark.parametrize("text, expected", [("8765", ("127.0.0.1", 8765)), ("0", ("127.0.0.1", 0)),
                                            ("0.0.0.0:0", ("0.0.0.0", 0)), ("localhost:9000", ("localhost", 9000))])
def test_live_values(text: str, expected: tuple[str, int]) -> None:
    assert parse_live(text) == expected


@pytest.mark.parametrize("text", ["", "x", ":80", "host:", "1:2:3", "70000", "-1", "[::1]:80"])
def test_bad_live_values_are_one_line_errors(text: str) -> None:
    with pytest.raises(LiveError) as exc:
        parse_live(text)
    assert str(exc.value).startswith("--live: ") and "\n" not in str(exc.value)


def test_a_port_in_use_is_a_one_line_error_and_stop_frees_the_port() -> None:
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        with pytest.raises(LiveError, match=rf"^--live 127\.0\.0\.1:{port}: cannot serve: .*in use"):
            LiveServer("127.0.0.1", port)
    server = LiveServer("127.0.0.1", 0)
    port = server.port
    assert port and server.url == f"ws://127.0.0.1:{port}"
    server.stop()
    server.stop()  # idempotent
    server.publish("/log", b"{}", 1)  # a no-op once stopped
    assert not foxglove_ws.listening(port)


def test_nothing_listens_once_stop_returns() -> None:
    """foxglove-sdk's stop() returns about a millisecond before its listening socket closes:
    a connection in that moment was accepted (74 of 100 servers of the SDK alone)."""
    for _ in range(30):
        server = LiveServer("127.0.0.1", 0)
        server.stop()
        with socket.socket() as s:
            assert s.connect_ex(("127.0.0.1", server.port)) != 0


def test_a_node_writer_process_serves_and_stops(tmp_path: Path) -> None:
    """mcp-node's recorder: the writer process serves, says its URL, and stops with it."""
    rec = BackgroundRecorder(None, library="mcp-node", live=("127.0.0.1", 0))
    assert rec.live_url is not None and rec.live_url.startswith("ws://127.0.0.1:")
    port = int(rec.live_url.rsplit(":", 1)[1])
    got = threading.Event()
    watcher = foxglove_ws.Watcher(rec.live_url, then=lambda s: bool(s.on("/mcp/tx")) and got.set())
    watcher.start()
    deadline = time.monotonic() + 20
    while not got.is_set() and time.monotonic() < deadline:  # until the client has seen a datagram
        rec.datagram("tx", encode(Message(0, 1, 1, Action.MISSION_READY, None)), ("127.0.0.1", 7889))
        rec.flush()
        got.wait(0.1)
    rec.close()
    seen = watcher.session()
    assert seen.closed and seen.on("/mcp/tx")
    assert seen.on("/mcp/tx")[0].json()["action_name"] == "MISSION_READY"
    assert not foxglove_ws.listening(port)
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        with pytest.raises(Exception, match=r"^--live 127\.0\.0\.1:\d+: cannot serve"):
            BackgroundRecorder(None, live=("127.0.0.1", taken.getsockname()[1]))


def test_a_client_that_stops_reading_does_not_hold_the_end_of_the_run() -> None:
    """foxglove-sdk's stop() waits for each client to take what is queued for it: with a
    subscribed client that reads nothing and 20000 messages queued, it never returned."""
    server = LiveServer("127.0.0.1", 0)
    feed = server.feed()
    ws = foxglove_ws.connect(server.url, timeout=5)
    ws.recv()  # serverInfo, then the channels
    ids = [c["id"] for c in json.loads(ws.recv())["channels"]]
    ws.send(json.dumps({"op": "subscribe", "subscriptions": [{"id": i, "channelId": i} for i in ids]}))
    _wait_subscribed(server, len(ids))
    data = b'{"x":"' + b"a" * 300 + b'"}'
    for i in range(20000):
        feed.publish("/mcp/rx", data, i)
    stopper = threading.Thread(target=server.stop, daemon=True)
    stopper.start()
    stopper.join(60)
    assert not stopper.is_alive(), "stop() hung on a client that does not read"
    assert server.abandoned  # the stuck client's connection left to a daemon thread
    assert not foxglove_ws.listening(server.port)
    ws.close()

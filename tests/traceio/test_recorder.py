"""traceio.recorder: MCAP files read back with the mcap reader, CRCs validated."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest
from mcap.reader import make_reader

from mcp_conform.spec.codec import Action, Message, MissionItem, encode
from mcp_conform.spec.mavframe import heartbeat_frame
from mcp_conform.traceio.background import BackgroundRecorder
from mcp_conform.traceio.recorder import (
    CHANNELS,
    METADATA_NAME,
    McapRecorder,
    RecorderError,
    foxglove_channels,
    mavlink_type,
    run_metadata,
    summarize_payload,
)

ROOT = Path(__file__).resolve().parents[2]
ITEM = MissionItem(0.0, 0.0, 0.0, 0.0, 35.771103, -78.674659, 3.0, 1, 16, 1, 1, 3, 0, 1)
PEER = ("127.0.0.1", 7890)


def read_all(path: Path) -> tuple[dict[str, list[tuple[int, dict]]], dict[str, str]]:
    """topic -> [(log_time, body)], and topic -> schema encoding; CRCs validated."""
    with open(path, "rb") as f:
        reader = make_reader(f, validate_crcs=True)
        out: dict[str, list[tuple[int, dict]]] = {}
        encodings: dict[str, str] = {}
        for schema, channel, message in reader.iter_messages(log_time_order=False):
            assert channel.message_encoding == "json"
            encodings[channel.topic] = schema.encoding if schema else ""
            out.setdefault(channel.topic, []).append((message.log_time, json.loads(message.data)))
    return out, encodings


def test_channels_schemas_and_counts(tmp_path):
    path = tmp_path / "run.mcap"
    wp_list = encode(Message(1, 0, 7, Action.WP_LIST, (ITEM, ITEM._replace(seq=2))))
    ack = encode(Message(0, 1, 8, Action.ACK, 7))
    with McapRecorder(path) as rec:
        rec.case_mark("ACK/test_x", "start", 1_000, rules=("MCP-ACK-1",))
        rec.datagram("tx", wp_list, PEER, 1_100)
        rec.datagram("rx", ack, ("127.0.0.1", 40000), 1_200)
        rec.datagram("rx", b"garbage", ("127.0.0.1", 40000), 1_300)
        rec.mavlink("rx", b"\xfd\x09\x00\x00\x00\x01\x01\x00\x00\x00", 1_400, msg_type="HEARTBEAT")
        rec.vehicle_event("fix", 1_450, drone=1, detail="fix_type 3")
        rec.case_mark("ACK/test_x", "end", 1_500, outcome="passed", rules=("MCP-ACK-1",))
    msgs, encodings = read_all(path)
    assert set(encodings.values()) == {"jsonschema"}
    assert set(encodings) == set(CHANNELS) - {"/mcp/burst", "/impair"} | {"/log"}
    assert {t: len(v) for t, v in msgs.items()} == {
        "/mcp/tx": 1, "/mcp/rx": 2, "/mavlink": 1, "/vehicle": 1, "/conformance/case": 2, "/log": 2}
    with open(path, "rb") as f:
        summary = make_reader(f, validate_crcs=True).get_summary()
    assert summary is not None
    assert {s.name for s in summary.schemas.values()} == {
        "mcp.Datagram", "mcp.Burst", "mcp.MavlinkFrame", "mcp.CaseMark", "mcp.Impairment",
        "mcp.VehicleEvent", "foxglove.LocationFix", "foxglove.PoseInFrame", "foxglove.Log"}
    assert {c.topic for c in summary.channels.values()} == set(CHANNELS) | set(foxglove_channels())
    for schema in summary.schemas.values():
        body = json.loads(schema.data)
        assert body["type"] == "object"
        # Foxglove shows raw bytes when the schema says they are base64
        if "raw_base64" in body["properties"]:
            assert body["properties"]["raw_base64"]["contentEncoding"] == "base64"
    burst = json.loads(next(s for s in summary.schemas.values() if s.name == "mcp.Burst").data)
    assert burst["properties"]["cycle"]["items"]["properties"]["raw_base64"]["contentEncoding"] == "base64"


def test_decoded_and_undecodable_datagrams(tmp_path):
    path = tmp_path / "run.mcap"
    wp_list = encode(Message(1, 0, 7, Action.WP_LIST, (ITEM, ITEM._replace(seq=2))))
    short = wp_list[:12]
    with McapRecorder(path) as rec:
        rec.datagram("tx", wp_list, PEER, 10)
        rec.datagram("rx", short, ("127.0.0.1", 5), 20)
        rec.datagram("rx", wp_list[:-3], ("127.0.0.1", 5), 30)
    msgs, _ = read_all(path)
    (t_tx, tx), = msgs["/mcp/tx"]
    assert t_tx == 10
    assert tx["decoded"] is True and (tx["dst"], tx["src"], tx["seq"]) == (1, 0, 7)
    assert tx["action_name"] == "WP_LIST" and tx["peer"] == "127.0.0.1:7890"
    assert tx["payload"]["count"] == 2 and tx["payload"]["items"][1]["seq"] == 2
    assert base64.b64decode(tx["raw_base64"]) == wp_list and bytes.fromhex(tx["raw_hex"]) == wp_list
    (_, bad_short), (_, bad_len) = msgs["/mcp/rx"]
    assert bad_short["decoded"] is False and bad_short["error_rule"].startswith("MCP-ROB")
    assert bad_short["error_reason"] and bad_short["length"] == 12
    # a whole header but a payload that does not fit: the header is still shown
    assert bad_len["decoded"] is False and bad_len["seq"] == 7 and bad_len["action"] == int(Action.WP_LIST)


def test_case_marks_and_mavlink_content(tmp_path):
    path = tmp_path / "run.mcap"
    frame = bytes(range(20))
    with McapRecorder(path) as rec:
        rec.case_mark("DUP/test_y", "start", 5, rules=("MCP-DUP-1", "MCP-DUP-2"))
        rec.mavlink("tx", frame, 6)
        rec.case_mark("DUP/test_y", "end", 7, outcome="failed", rules=("MCP-DUP-1", "MCP-DUP-2"))
    msgs, _ = read_all(path)
    start, end = (body for _, body in msgs["/conformance/case"])
    assert start == {"case": "DUP/test_y", "event": "start", "outcome": None, "rules": ["MCP-DUP-1", "MCP-DUP-2"]}
    assert end["event"] == "end" and end["outcome"] == "failed"
    (_, mav), = msgs["/mavlink"]
    assert mav["msg_type"] is None and mav["length"] == 20 and base64.b64decode(mav["raw_base64"]) == frame


def test_mavlink_type_from_the_frame():
    assert mavlink_type(heartbeat_frame()) == "HEARTBEAT"
    assert mavlink_type(heartbeat_frame(version=1)) == "HEARTBEAT"
    assert mavlink_type(b"\xfd\x00") is None and mavlink_type(b"") is None


def test_metadata_record_and_local_address(tmp_path):
    path = tmp_path / "run.mcap"
    meta = run_metadata("mcp-conform", target="127.0.0.1:7890", role="drone", seed=7, spawn=None)
    with McapRecorder(path, metadata=meta, local=("", 7889)) as rec:
        rec.datagram("tx", b"x" * 17, PEER, 1)
        rec.datagram("rx", b"y" * 17, PEER, 2, local=("127.0.0.1", 5))
    with open(path, "rb") as f:
        (record,) = list(make_reader(f, validate_crcs=True).iter_metadata())
    assert record.name == METADATA_NAME
    m = record.metadata
    assert m["recorder"] == "mcp-conform" and m["target"] == "127.0.0.1:7890" and m["seed"] == "7"
    assert m["spec_version"] and len(m["spec_sha256"]) == 64 and m["tool_version"]
    assert "spawn" not in m
    msgs, _ = read_all(path)
    assert msgs["/mcp/tx"][0][1]["local"] == "0.0.0.0:7889"
    assert msgs["/mcp/rx"][0][1]["local"] == "127.0.0.1:5"


def test_burst_is_one_summary_record(tmp_path):
    path = tmp_path / "run.mcap"
    cycle = [encode(Message(1, 0, s, Action.WP_OFF, None))[:-1] + b"\x00\x0b" for s in range(3)]
    with McapRecorder(path, local=("127.0.0.1", 4000)) as rec:
        rec.burst("tx", cycle, 10000, PEER, 100, 900)
    msgs, _ = read_all(path)
    ((t, body),) = msgs["/mcp/burst"]
    assert t == 100 and body["count"] == 10000 and body["last_t_ns"] == 900
    assert [base64.b64decode(d["raw_base64"]) for d in body["cycle"]] == cycle
    assert body["peer"] == "127.0.0.1:7890" and body["local"] == "127.0.0.1:4000"


def test_background_recorder_writes_the_same_file(tmp_path):
    path = tmp_path / "bg.mcap"
    wp_off = encode(Message(1, 0, 3, Action.WP_OFF, None))
    with BackgroundRecorder(path, metadata={"recorder": "test"}, local=("127.0.0.1", 9)) as rec:
        for i in range(1000):
            rec.datagram("rx", wp_off, PEER, i)
        rec.mavlink("rx", heartbeat_frame(), 5000, drone=1)
        rec.burst("tx", [b"abc"], 5, PEER, 6000, 7000)
        rec.case_mark("X/y", "start", 8000)
        with pytest.raises(ValueError, match="direction"):
            rec.datagram("up", b"", PEER)
    msgs, _ = read_all(path)
    assert len(msgs["/mcp/rx"]) == 1000 and msgs["/mcp/rx"][5][0] == 5
    assert msgs["/mcp/rx"][0][1]["local"] == "127.0.0.1:9" and msgs["/mcp/rx"][0][1]["seq"] == 3
    assert msgs["/mavlink"][0][1]["msg_type"] == "HEARTBEAT" and msgs["/mavlink"][0][1]["drone"] == 1
    assert msgs["/mcp/burst"][0][1]["count"] == 5 and len(msgs["/conformance/case"]) == 1
    with open(path, "rb") as f:
        assert next(iter(make_reader(f).iter_metadata())).metadata == {"recorder": "test"}
    with pytest.raises(RecorderError, match="cannot write"):
        BackgroundRecorder(tmp_path / "no-dir" / "x.mcap")


@pytest.mark.slow
def test_background_writer_finishes_the_file_when_its_owner_is_killed(tmp_path):
    """SIGKILL of the recording process: the writer sees the pipe close and writes the footer."""
    path = tmp_path / "killed.mcap"
    script = textwrap.dedent(f"""
        import os, signal, time
        from mcp_conform.traceio.background import BackgroundRecorder
        rec = BackgroundRecorder({str(path)!r})
        for i in range(500):
            rec.datagram("tx", b"NCSU-CM\x01\x01" + bytes(8), ("127.0.0.1", 1), i)
        rec.flush()
        os.kill(os.getpid(), signal.SIGKILL)
    """)
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, timeout=60)
    assert proc.returncode == -9
    deadline = time.monotonic() + 20
    while time.monotonic() < deadline:  # the writer finishes on its own, shortly after
        try:
            msgs, _ = read_all(path)
            break
        except Exception:  # noqa: BLE001 - not finished yet
            time.sleep(0.1)
    assert len(msgs["/mcp/tx"]) == 500


def test_close_is_idempotent_and_later_writes_are_dropped(tmp_path):
    path = tmp_path / "run.mcap"
    rec = McapRecorder(path)
    rec.datagram("tx", b"\x00", PEER, 1)
    rec.close()
    rec.close()
    rec.datagram("tx", b"\x01", PEER, 2)  # after close: ignored, the file stays valid
    msgs, _ = read_all(path)
    assert len(msgs["/mcp/tx"]) == 1 and rec.closed


def test_bad_arguments_are_refused(tmp_path):
    with pytest.raises(RecorderError, match="cannot write"):
        McapRecorder(tmp_path / "missing-dir" / "x.mcap")
    with McapRecorder(tmp_path / "x.mcap") as rec:
        with pytest.raises(ValueError, match="direction"):
            rec.datagram("sideways", b"", PEER, 1)
        with pytest.raises(ValueError, match="event"):
            rec.case_mark("X/y", "middle", 1)


def test_concurrent_writers(tmp_path):
    path = tmp_path / "run.mcap"
    rec = McapRecorder(path)
    data = encode(Message(1, 0, 1, Action.WP_OFF, None))

    def writer(direction: str) -> None:
        for i in range(500):
            rec.datagram(direction, data, PEER, i)

    threads = [threading.Thread(target=writer, args=(d,)) for d in ("tx", "rx", "tx", "rx")]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    rec.close()
    msgs, _ = read_all(path)
    assert len(msgs["/mcp/tx"]) == 1000 and len(msgs["/mcp/rx"]) == 1000
    assert rec.counts["/mcp/tx"] == 1000


def test_run_interrupted_by_an_exception_leaves_a_valid_file(tmp_path):
    """The process dies of an uncaught exception without calling close(): atexit does."""
    path = tmp_path / "crash.mcap"
    script = textwrap.dedent(f"""
        from mcp_conform.traceio.recorder import McapRecorder
        rec = McapRecorder({str(path)!r})
        rec.case_mark("ACK/test_z", "start", 1)
        rec.datagram("tx", b"NCSU-CM\\x01\\x01" + bytes(8), ("127.0.0.1", 1), 2)
        raise RuntimeError("the run was interrupted")
    """)
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 1 and "interrupted" in proc.stderr
    msgs, _ = read_all(path)
    assert len(msgs["/conformance/case"]) == 1 and len(msgs["/mcp/tx"]) == 1


def test_what_a_run_left_open_is_closed_at_exit_though_one_close_fails(tmp_path):
    """The recorders open are closed at exit by the one registry of what a run left open
    (traceio.files.ClosedAtExit, the live servers' too): one whose close fails does not keep
    the others' files from being finished."""
    path = tmp_path / "left.mcap"
    script = textwrap.dedent(f"""
        from mcp_conform.traceio import recorder
        class Broken:
            def close(self):
                raise OSError("disk gone")
        broken = Broken()
        recorder.OPEN.add(broken)
        rec = recorder.McapRecorder({str(path)!r})
        rec.datagram("tx", b"NCSU-CM\\x01\\x01" + bytes(8), ("127.0.0.1", 1), 2)
        later = Broken()
        recorder.OPEN.add(later)
        assert rec in recorder.OPEN
    """)
    proc = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 0, proc.stderr
    msgs, _ = read_all(path)
    assert len(msgs["/mcp/tx"]) == 1


def test_payload_summary():
    assert summarize_payload(None) is None
    assert summarize_payload(513) == 513
    assert summarize_payload(b"\xfd\x01") == {"mavlink_frame_len": 2, "hex": "fd01"}
    assert summarize_payload(ITEM)["command"] == 16
    many = summarize_payload(tuple(ITEM._replace(seq=i) for i in range(40)))
    assert many["count"] == 40 and len(many["items"]) < 40


def test_the_runner_tee_forwards_the_local_address_and_bursts(tmp_path):
    """``mcp-conform -v`` wraps the recorder (conformance.run_display.Tee): the session's socket
    address and the flood's burst still reach the file."""
    from mcp_conform.conformance.run_display import Tee

    path = tmp_path / "tee.mcap"
    rec = McapRecorder(path)
    tee = Tee(rec, None)
    tee.local = ("", 7889)
    tee.datagram("tx", b"x" * 17, PEER, 1)
    tee.burst("tx", [b"y" * 17], 3, PEER, 2, 3)
    rec.close()
    msgs, _ = read_all(path)
    assert msgs["/mcp/tx"][0][1]["local"] == "0.0.0.0:7889" and msgs["/mcp/burst"][0][1]["count"] == 3

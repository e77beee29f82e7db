"""captures.recorder: MCAP files read back with the mcap reader, CRCs validated."""

from __future__ import annotations

import base64
import json
import subprocess
import sys
import textwrap
import threading
from pathlib import Path

import pytest
from mcap.reader import make_reader

from captures.recorder import CHANNELS, McapRecorder, RecorderError, summarize_payload
from spec.codec import Action, Message, MissionItem, encode

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
        rec.case_mark("ACK/test_x", "end", 1_500, outcome="passed", rules=("MCP-ACK-1",))
    msgs, encodings = read_all(path)
    assert set(encodings) == set(CHANNELS)
    assert set(encodings.values()) == {"jsonschema"}
    assert {t: len(v) for t, v in msgs.items()} == {
        "/mcp/tx": 1, "/mcp/rx": 2, "/mavlink": 1, "/conformance/case": 2}
    with open(path, "rb") as f:
        summary = make_reader(f, validate_crcs=True).get_summary()
    assert summary is not None
    assert {s.name for s in summary.schemas.values()} == {"mcp.Datagram", "mcp.MavlinkFrame", "mcp.CaseMark"}
    for schema in summary.schemas.values():
        assert json.loads(schema.data)["type"] == "object"


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
        from captures.recorder import McapRecorder
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


def test_payload_summary():
    assert summarize_payload(None) is None
    assert summarize_payload(513) == 513
    assert summarize_payload(b"\xfd\x01") == {"mavlink_frame_len": 2, "hex": "fd01"}
    assert summarize_payload(ITEM)["command"] == 16
    many = summarize_payload(tuple(ITEM._replace(seq=i) for i in range(40)))
    assert many["count"] == 40 and len(many["items"]) < 40

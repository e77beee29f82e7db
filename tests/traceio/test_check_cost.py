"""What makes ``mcp-capture check`` of a million violations cheaper (issue 17), checked for
what it must not change: the same records read, the same judgement, the same JSON bytes.

No timing here (bench/bench_capture_tools.py prints the seconds and the peak RSS).
"""

from __future__ import annotations

import gc
import struct
import sys
import zlib
from pathlib import Path
from typing import Any

import lz4.frame
import pytest
import zstandard

from mcp_conform.judge.judging import NoJudge, Params, judge
from mcp_conform.spec.codec import Action, Message, encode
from mcp_conform.traceio.mcap_chunks import Message as ChunkMessage
from mcp_conform.traceio.mcap_chunks import chunk_records
from mcp_conform.traceio.reader import Datagram, open_capture
from mcp_conform.traceio.recorder import McapRecorder


def _capture(path: Path, n: int = 20) -> Path:
    with McapRecorder(path, local=("127.0.0.1", 7889)) as rec:
        for i in range(n):
            rec.datagram("rx", encode(Message(0, 1 + i % 3, i, Action.MISSION_READY, None)),
                         ("127.0.0.1", 41001 + i % 3), 1_800_000_000_000_000_000 + i * 1_000_000)
    return path


def _violating(path: Path, n: int) -> Path:
    """``n`` datagrams, each a violation (bench/bench_capture_tools.py's million capture)."""
    sys.path.insert(0, str(Path(__file__).resolve().parents[2] / "bench"))
    from bench_capture_tools import all_violating

    all_violating(path, n)
    return path


class _Spy(NoJudge):
    """Notes whether the cyclic collector was on as each datagram was judged."""

    def __init__(self, fail_at: int | None = None) -> None:
        self.enabled: list[bool] = []
        self.fail_at = fail_at

    def datagram(self, *args: Any, **kw: Any) -> list[Any]:
        self.enabled.append(gc.isenabled())
        if len(self.enabled) == self.fail_at:
            raise RuntimeError("judge failed")
        return []


@pytest.mark.parametrize("was", [True, False])
def test_the_collector_is_off_while_judging_and_as_it_was_after(tmp_path: Path, was: bool) -> None:
    """Judging keeps every violation and its evidence (millions of tuples): the collector's
    passes over them were a fifth of checking a million violations. Off while judging,
    as it was before once judging ends, and when judging fails too."""
    cap = _capture(tmp_path / "c.mcap")
    (gc.enable if was else gc.disable)()
    try:
        spy = _Spy()
        judge(cap, Params(), monitor=spy)
        assert spy.enabled == [False] * 20
        assert gc.isenabled() is was
        with pytest.raises(RuntimeError, match="judge failed"):
            judge(cap, Params(), monitor=_Spy(fail_at=3))
        assert gc.isenabled() is was
    finally:
        gc.enable()


# ---------------------------------------------------------------- MCAP chunks at C speed
def _record(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _message(channel: int, t: int, data: bytes) -> bytes:
    return _record(0x05, struct.pack("<HIQQ", channel, 7, t, t + 1) + data)


def _channel(cid: int, topic: bytes) -> bytes:
    return _record(0x04, struct.pack("<HH", cid, 0) + struct.pack("<I", len(topic)) + topic
                   + struct.pack("<I", 4) + b"json" + struct.pack("<I", 0))


def _chunk(data: bytes, compression: str = "", crc: int | None = None) -> Any:
    from mcap.records import Chunk

    packed = {"": data, "zstd": zstandard.compress(data), "lz4": lz4.frame.compress(data)}[compression]
    return Chunk(compression=compression, data=packed, message_end_time=0, message_start_time=0,
                 uncompressed_crc=zlib.crc32(data) if crc is None else crc, uncompressed_size=len(data))


ODD_CHUNKS = {
    "messages": _message(1, 10, b'{"a": 1}') + _message(2, 5, b"") + _message(1, 11, b"x" * 300),
    "a channel in it": _channel(1, b"/mcp/rx") + _message(1, 10, b"{}"),
    "an unknown record": _message(1, 10, b"{}") + _record(0x77, b"abc") + _message(1, 12, b"{}"),
    "a message of 21 bytes": _message(1, 10, b"{}") + _record(0x05, b"\x01" * 21),
    "a record longer than the chunk": _message(1, 10, b"{}") + struct.pack("<BQ", 0x05, 900) + b"\x00" * 40,
    "a cut record header": _message(1, 10, b"{}") + b"\x05\x10\x00",
    "a channel longer than it says": _message(1, 10, b"{}") + b"\x04" + struct.pack("<Q", 26)
    + _channel(2, b"/mcp/tx")[9:] + _message(2, 11, b"{}"),
    "a channel shorter than it says": b"\x04" + struct.pack("<Q", 30) + _channel(2, b"/mcp/tx")[9:]
    + b"\x00\x00\x00" + _message(2, 11, b"{}"),
    "empty": b"",
}


def _by_mcap(chunk: Any) -> list[Any]:
    from mcap.records import Message as McapMessage
    from mcap.stream_reader import breakup_chunk

    return [(r.channel_id, r.log_time, r.data) if type(r) is McapMessage else r
            for r in breakup_chunk(chunk, validate_crc=True)]


def _outcome(fn: Any, chunk: Any) -> Any:
    try:
        return [tuple(r) if type(r) is ChunkMessage else r for r in fn(chunk)]
    except Exception as exc:  # noqa: BLE001 - the same error, or the same records
        return (type(exc), str(exc))


@pytest.mark.parametrize("compression", ["", "zstd", "lz4"])
@pytest.mark.parametrize("name", list(ODD_CHUNKS))
def test_a_chunk_splits_as_mcap_splits_it(name: str, compression: str) -> None:
    """The same records (a message's channel, log time and bytes) or the same error as
    ``mcap``'s ``breakup_chunk``, odd chunks too; and a failed CRC fails alike."""
    data = ODD_CHUNKS[name]
    chunk = _chunk(data, compression)
    assert _outcome(chunk_records, chunk) == _outcome(_by_mcap, chunk)
    bad = _chunk(data, compression, crc=zlib.crc32(data) ^ 1)
    got = _outcome(chunk_records, bad)
    assert got == _outcome(_by_mcap, bad) and "crc validation failed" in got[1]


def test_reading_parses_no_message_field_by_field(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """Before: ``mcap`` read each message of a chunk (and each entry of the message index
    after it) through its Python stream, 8 bytes at a time: a tenth of checking a million
    datagrams. Now neither reader is called for a capture the recorder wrote, and what is
    read is what ``mcap``'s own reading gives."""
    from mcap.records import Message as McapMessage
    from mcap.records import MessageIndex
    from mcap.stream_reader import StreamReader

    cap = _capture(tmp_path / "c.mcap", 3000)  # several chunks and their indexes
    with open(cap, "rb") as f:
        want = [(r.channel_id, r.log_time, r.data) for r in StreamReader(f, validate_crcs=True).records
                if type(r) is McapMessage]
    before = [tuple(d) for d in open_capture(cap)]

    def refused(*args: Any, **kw: Any) -> None:
        raise AssertionError("parsed field by field")

    monkeypatch.setattr(McapMessage, "read", staticmethod(refused))
    monkeypatch.setattr(MessageIndex, "read", staticmethod(refused))
    got = [tuple(d) for d in open_capture(cap)]
    assert got == before and len(got) == len(want) == 3000
    assert [d[1] for d in got] == [t for _, t, _ in want]
    assert all(type(d) is Datagram for d in open_capture(cap))


@pytest.mark.parametrize("cut", [1, 5, 9, 20, 40])
def test_a_cut_message_index_reads_as_mcap_reads_it(tmp_path: Path, cut: int) -> None:
    """A file cut inside the message index after a chunk: the same reason and the same
    records as reading every index entry (the index parsed by ``mcap``) gives."""
    from mcap.records import MessageIndex

    cap = _capture(tmp_path / "c.mcap", 3000)
    raw = cap.read_bytes()
    at = raw.index(b"\x07", raw.index(b"\x06", 8) + 9)  # near the first chunk's end: find the index
    with open(cap, "rb") as f:
        from mcap.stream_reader import StreamReader
        for r in StreamReader(f, validate_crcs=True, emit_chunks=True).records:
            if type(r) is MessageIndex:
                at = f.tell() - 6 - 16 * len(r.records) - 9
                break
    short = tmp_path / "short.mcap"
    short.write_bytes(raw[:at + cut])
    mine = open_capture(short)
    got = [tuple(d) for d in mine]
    plain = open_capture(short)
    import mcp_conform.traceio.mcap_chunks as chunks

    with pytest.MonkeyPatch.context() as mp:  # mcap's own StreamReader, every entry parsed
        from mcap.stream_reader import StreamReader as Plain

        mp.setattr(chunks, "stream_reader", lambda f, limit: Plain(f, validate_crcs=True, record_size_limit=limit,
                                                                     emit_chunks=True))
        want = [tuple(d) for d in plain]
    assert got == want and mine.truncated == plain.truncated and mine.truncated


def test_what_judging_made_goes_to_the_oldest_generation_at_once(tmp_path: Path) -> None:
    """With the collector paused, every object judging made would sit in the youngest
    generation, and the collector's next three passes would walk them all (a million
    violations: two million tuples) on their way to the oldest. Moved there at once: the
    younger generations hold next to nothing after judging, and nothing stays frozen."""
    cap = _violating(tmp_path / "c.mcap", 5000)
    gc.collect()
    j = judge(cap, Params())
    assert len(j.violations) >= 1000 and gc.is_tracked(j.violations[0])  # made while judging
    assert len(gc.get_objects(generation=0)) + len(gc.get_objects(generation=1)) < 1000
    assert gc.get_freeze_count() == 0
    if gc.isenabled():
        gc.freeze()  # a process that froze its objects keeps them frozen
        try:
            judge(cap, Params())
            assert gc.get_freeze_count() > 0
        finally:
            gc.unfreeze()


def test_evidence_indexes_of_every_kind_of_evidence() -> None:
    """The monitor's (index, t_ns) pairs first, and every other kind as before."""
    from mcp_conform.traceio.reader import Datagram as D
    from mcp_conform.traceio.trace import evidence_indexes

    class V:
        evidence = ((3, 10), 4, D(5, 1, None, None, b""), {"index": 6}, (True, 1), ("x", 2), (), {"index": "7"})

    assert evidence_indexes(V()) == [3, 4, 5, 6, True]


def test_each_violation_line_is_json_dumps_of_its_document(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """``--json``'s violation lines, byte for byte ``json.dumps`` of what ``to_json`` lists
    (every rule of a noisy capture: evidence pairs, addresses, no MCP header), written with
    one encoder for the file: before, ``JSONEncoder().encode`` made one per violation."""
    import json

    import mcp_conform.captures.check as check_mod
    from mcp_conform.judge.judging import evidence_of
    from tests.captures.noisy import write_noisy

    j = judge(write_noisy(tmp_path / "n.mcap", 800), Params())
    evidence = evidence_of(j)
    made = []
    real = json.encoder.c_make_encoder
    monkeypatch.setattr(json.encoder, "c_make_encoder", lambda *a: made.append(a) or real(*a))
    out = tmp_path / "c.json"
    check_mod.write_json(str(out), j, evidence)
    lines = [x.rstrip(",") for x in out.read_text().splitlines() if x.startswith('    {"rule": ')]
    monkeypatch.undo()
    docs = check_mod.to_json(j, evidence)["violations"]
    assert len({d["rule"] for d in docs}) >= 3 and len(docs) == len(j.shown_violations) > 100
    assert any(e["t"] is not None and " → " in e["summary"] for d in docs for e in d["evidence"])
    assert [x[4:] for x in lines] == [json.dumps(d) for d in docs]
    assert len(made) <= 2  # the head's json.dumps(indent=2) makes none: the pure-Python one

    # odd violations, and evidence not at hand: still json.dumps of the document, byte for byte
    vs = j.violations[:6]
    j.violations = [vs[0]._replace(node=True), vs[1]._replace(evidence=("a \"quoted\" note", 3)),
                    vs[2]._replace(expected=None, actual='ünïcode "quotes" \\ \n\u2028'),
                    vs[3]._replace(level="should", evidence=()), vs[4]._replace(rule="MCP-NOT-A-RULE"),
                    vs[5]._replace(actual=12.5, expected=("tuple",)), *j.violations[6:]]
    some = dict(list(evidence.items())[::2])
    check_mod.write_json(str(out), j, some)
    lines = [x.rstrip(",") for x in out.read_text().splitlines() if x.startswith('    {"rule": ')]
    docs = check_mod.to_json(j, some)["violations"]
    assert any(e["t"] is None for d in docs for e in d["evidence"])
    assert [x[4:] for x in lines] == [json.dumps(d) for d in docs]

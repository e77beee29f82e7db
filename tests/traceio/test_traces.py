"""``traceio.traces``: what every protocol's trace reader shares, the protocol a parameter --
which run a capture's metadata names, whether its first records are a protocol's, the
one-line errors of a file that cannot be read or is empty."""

from __future__ import annotations

import pytest

from mcp_conform.traceio.reader import CaptureError, Datagram, MavlinkFrame, Metadata, StreamFrame
from mcp_conform.traceio.traces import (
    PEEK,
    claims,
    corrupt,
    frame_names,
    head_of,
    is_mcap_head,
    recorded,
    recorded_protocol,
)


def _meta(parameters: str | None) -> Metadata:
    return Metadata("mcp-conform", {} if parameters is None else {"parameters": parameters})


@pytest.mark.parametrize(("parameters", "protocol"), [
    ('{"protocol": "nsqd", "rto": 1}', "nsqd"), ('{"rto": 1}', None), ("not json", None),
    ('{"protocol": 7}', None), ('["protocol"]', None), (None, None)])
def test_the_protocol_a_runs_metadata_records(parameters, protocol):
    assert recorded_protocol(_meta(parameters)) == protocol


MINE, OTHERS = MavlinkFrame(0, 1, "tx", None, b"\xfd"), Datagram(0, 1, None, None, b"x")
STREAM = StreamFrame(0, 1, "rx", 1, None, None, b"")


def _says(meta: Metadata) -> bool | None:
    p = recorded_protocol(meta)
    return None if p is None else p == "mine"


@pytest.mark.parametrize(("records", "first", "claimed"), [
    ([MINE, OTHERS], False, False),  # another protocol's record among the first: not mine
    ([MINE, OTHERS], True, True),  # ... unless my first record decides at once
    ([OTHERS, MINE], True, False),
    ([_meta('{"protocol": "mine"}'), OTHERS], False, True),  # the run's record decides
    ([_meta('{"protocol": "theirs"}'), MINE], False, False),
    ([_meta('{"rto": 1}'), MINE], False, True),  # metadata that says nothing: the records
    ([STREAM], False, False),  # neither mine nor foreign: nothing of mine seen
    ([STREAM] * PEEK + [MINE], False, False),  # past the first PEEK records: not looked at
])
def test_a_capture_is_claimed_by_its_first_records(records, first, claimed):
    assert claims(iter(records), (MavlinkFrame,), (Datagram,), _says, first=first) is claimed


def test_a_file_that_cannot_be_read_or_is_empty_is_one_line(tmp_path):
    empty = tmp_path / "e.tlog"
    empty.write_bytes(b"")
    with pytest.raises(CaptureError, match=r"e\.tlog: empty file, not a trace of mine$"):
        head_of(empty, 8, "a trace of mine")
    with pytest.raises(CaptureError, match=r"gone: cannot read: "):
        head_of(tmp_path / "gone", 8, "a trace of mine")
    some = tmp_path / "s"
    some.write_bytes(b"\x89MCAP0\r\nrest")
    assert head_of(some, 8, "x") == (12, b"\x89MCAP0\r\n") and is_mcap_head(b"\x89MCAP0\r\n")
    assert is_mcap_head(b"\x89MC") and not is_mcap_head(b"\x89MX") and not is_mcap_head(b"\x00" * 9)
    assert str(corrupt("f.pcap", "pcap", "bad CRC")) == "f.pcap: pcap file corrupt, nothing could be read: bad CRC"


def test_the_role_a_runs_metadata_records():
    """``recorded``: what the run's metadata says (an MCP drone run's, a MAVLink vehicle run's
    role under test); nothing for a capture with no such key."""
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    assert recorded(root / "captures" / "golden" / "drone-suite.mcap", "role") == "drone"
    assert recorded(root / "captures" / "golden" / "drone-suite.mcap", "no such key") is None


def test_a_stream_protocols_frames_are_named_by_its_spec():
    """``frame_names``: a client's write is named only when it is one whole frame of an id the
    spec has; an item of the node's bytes is a frame's name, or why the deframer refused them."""
    from mcp_conform.spec import NSQD
    from mcp_conform.spec.nsqd_codec import Deframer, Frame, FramingError

    write, frame = frame_names(NSQD, lambda: Deframer(NSQD))
    update = NSQD.message("UPDATE")
    whole = (5 + 32).to_bytes(4, "big") + bytes([update.id]) + bytes(32)
    assert write(whole) == "UPDATE"
    assert write(whole[:-1]) is None and write(whole + whole) is None  # part of one, or two
    unknown = (5).to_bytes(4, "big") + bytes([0xEE])
    assert not NSQD.has_message(0xEE) and write(unknown) is None
    assert frame(Frame(update.id, bytes(32), whole)) == ("UPDATE", None)
    assert frame(Frame(0xEE, b"", unknown)) == (None, None)
    assert frame(FramingError(3, b"\0\0\0\3", "length 3 below 5")) == (None, "length 3 below 5")

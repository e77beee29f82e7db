"""The vehicle's stream decoder never raises and resynchronises after garbage."""

from __future__ import annotations

from hypothesis import given, settings
from hypothesis import strategies as st

from mcp_conform.vehicle import Decoder, Encoder, make_probe
from mcp_conform.vehicle.codec import frame_version
from mcp_conform.vehicle.probe import probe_token


@settings(max_examples=200, deadline=None)
@given(st.lists(st.binary(max_size=300), max_size=8))
def test_decoder_survives_any_bytes(chunks: list[bytes]) -> None:
    dec = Decoder()
    for chunk in chunks:
        msgs, bad, _ = dec.feed(chunk)
        assert bad >= 0 and isinstance(msgs, list)


@settings(max_examples=100, deadline=None)
@given(st.binary(max_size=200).map(lambda b: b.replace(b"\xfd", b"").replace(b"\xfe", b"")),
       st.integers(min_value=1, max_value=40))
def test_decoder_finds_a_frame_after_garbage_in_any_split(junk: bytes, split: int) -> None:
    data = junk + make_probe("x") + make_probe("y", version=1)
    dec = Decoder()
    got = []
    for i in range(0, len(data), split):
        got.extend(m.text for m in dec.feed(data[i:i + split])[0])
    assert got == ["MCPPROBE:x", "MCPPROBE:y"]
    assert dec.bad_bytes == len(junk)


def test_encoder_numbers_frames_and_speaks_v2() -> None:
    from pymavlink.dialects.v20 import ardupilotmega as mav

    enc = Encoder(1, 1)
    frames = [enc.encode(mav.MAVLink_heartbeat_message(2, 3, 0, 0, 0, 3)) for _ in range(3)]
    assert [frame_version(f) for f in frames] == [2, 2, 2]
    assert [f[4] for f in frames] == [0, 1, 2]  # v2 header: seq is byte 4
    assert [m.get_seq() for m in Decoder().feed(b"".join(frames))[0]] == [0, 1, 2]


def test_probe_token_parsing() -> None:
    assert probe_token("MCPPROBE:abc") == "abc"
    assert probe_token(b"MCPPROBE:abc\0\0") == "abc"
    assert probe_token("MCPPROBE:") is None
    assert probe_token("hello") is None
    assert probe_token(None) is None


def test_mavlink1_encoder_packs_every_reply_the_model_sends() -> None:
    from pymavlink.dialects.v20 import ardupilotmega as mav

    from mcp_conform.vehicle import Encoder, VehicleModel

    model = VehicleModel(now=0.0)
    msgs = [*model.snapshot(1.0), mav.MAVLink_statustext_message(2, b"PreArm: Need 3D Fix"),
            mav.MAVLink_mission_request_message(255, 0, 3, 0),
            mav.MAVLink_mission_ack_message(255, 0, 10, 0)]
    enc = Encoder(1, 1, version=1)
    for m in msgs:
        raw = enc.encode(m)
        assert raw[:1] == b"\xfe", m.get_type()
        got, bad, _ = Decoder().feed(raw)
        assert bad == 0 and got[0].get_type() == m.get_type()
    assert got[0].type == 10  # the MISSION_ACK's result survives MAVLink 1


def test_decoder_keeps_the_bytes_that_did_not_parse_once_each() -> None:
    """MCP-PAY-8: a frame altered on its way arrives as unparsed bytes, which are kept (with
    the arrival time of their first byte) to compare with the frame sent."""
    from mcp_conform.vehicle import make_probe

    frame = make_probe("kept")
    corrupt = bytearray(frame)
    corrupt[15] ^= 0x01  # a payload bit, the CRC unchanged
    unknown = bytearray(frame)
    unknown[7:10] = b"\xee\xee\x00"  # an unknown message id (no CRC check for those)
    dec = Decoder()
    msgs, bad, _ = dec.feed(bytes(corrupt) + frame, 1.0)
    assert [m.get_type() for m in msgs] == ["STATUSTEXT"] and bad == len(frame)
    (u,) = dec.take_unparsed()
    assert (u.t, u.raw, u.frame) == (1.0, bytes(corrupt), False) and "CRC" in u.reason
    assert dec.take_unparsed() == []
    msgs, bad, _ = dec.feed(bytes(unknown), 2.0)  # still handed on as a message, as before
    assert [m.get_type() for m in msgs] == ["UNKNOWN_61166"] and bad == 0
    (u,) = dec.take_unparsed()
    assert (u.raw, u.frame, u.reason) == (bytes(unknown), True, "unknown message id 61166")


def test_an_incomplete_frame_is_reported_once_when_nothing_follows() -> None:
    """A truncated frame waits in the parser for bytes that never come: reported after
    ``STALE`` s of quiet, once, and still completed by late bytes (valid traffic unchanged)."""
    from mcp_conform.vehicle import make_probe
    from mcp_conform.vehicle.codec import STALE

    frame = make_probe("cut")
    dec = Decoder()
    assert dec.feed(frame[:-3], 10.0)[:2] == ([], 0) and dec.take_unparsed() == []
    assert dec.holding() == len(frame) - 3
    assert dec.stale(10.0 + STALE / 2) == []
    (u,) = dec.stale(10.0 + STALE * 1.01)
    assert (u.t, u.raw) == (10.0, frame[:-3]) and u.reason.startswith("incomplete frame")
    assert dec.stale(20.0) == [] and dec.holding() == 0
    msgs, _, _ = dec.feed(frame[-3:], 21.0)  # the rest, late: the frame still parses
    assert [m.get_type() for m in msgs] == ["STATUSTEXT"] and dec.take_unparsed() == []
    dec.feed(frame[:-3], 30.0)
    dec.stale(31.0)
    msgs, _, _ = dec.feed(make_probe("next"), 32.0)  # not completed: dropped, not reported again,
    assert [m.get_type() for m in msgs] == ["STATUSTEXT"]  # and the next frame is not swallowed
    assert dec.take_unparsed() == [] and dec.holding() == 0

"""spec.codec: golden vectors, round trips, and decode's robustness (MCP-HDR-1/2, MCP-PAY-1..6, MCP-ROB-1..4).

The golden datagrams below were written by hand from the layouts (header ``!7s2B4H``, count
and ACK payload big-endian per D-2, mission items ``<fffffffHHBBBBB`` per MCP-PAY-4/E-1);
the float32 and MAVLink CRC bytes were worked out independently of the codec.
"""

from __future__ import annotations

import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from mcp_conform.spec.codec import (
    HEADER_SIZE,
    Action,
    DecodeError,
    LocalProtocolError,
    Message,
    MissionItem,
    build_datagram,
    decode,
    encode,
    peek_header,
    try_decode,
)
from mcp_conform.spec.strategies import MALFORMED_KINDS, datagrams, malformed_datagrams, messages
from tests.tiers import tiered_property

FAST = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])

PRE = "4E4353552D434D0101"  # "NCSU-CM", 0x01, 0x01 (MCP-HDR-1)

# Item A: x=35.5 (00 00 0E 42), y=-78.5 (00 00 9D C2), z=3.0 (00 00 40 40), seq 1,
# command 16 (NAV_WAYPOINT), target 1/0, frame 3, current 0, autocontinue 1.
ITEM_A = MissionItem(0.0, 0.0, 0.0, 0.0, 35.5, -78.5, 3.0, 1, 16, 1, 0, 3, 0, 1)
ITEM_A_HEX = ("00000000" "00000000" "00000000" "00000000" "00000E42" "00009DC2" "00004040"
              "0100" "1000" "01" "00" "03" "00" "01")
# Item B: param1=5.0 (00 00 A0 40), x=0.5 (00 00 00 3F), y=-1.0 (00 00 80 BF), z=2.0
# (00 00 00 40), seq 2, command 19 (LOITER_TIME), target 1/0, frame 3, current 1, autocontinue 1.
ITEM_B = MissionItem(5.0, 0.0, 0.0, 0.0, 0.5, -1.0, 2.0, 2, 19, 1, 0, 3, 1, 1)
ITEM_B_HEX = ("0000A040" "00000000" "00000000" "00000000" "0000003F" "000080BF" "00000040"
              "0200" "1300" "01" "00" "03" "01" "01")
# HEARTBEAT, MAVLink v1: FE len=09 seq=00 sys=FF comp=BE msgid=00, payload custom_mode=0
# type=6 autopilot=8 base_mode=0 status=4 version=3, X.25 CRC (crc_extra 50) = 0x2149, LE.
HEARTBEAT_V1_HEX = "FE0900FFBE00" "00000000" "06" "08" "00" "04" "03" "4921"

#            name, message, hex (dst src seq action | payload)
GOLDEN = [
    ("mission_ready_empty", Message(0, 1, 0x0102, Action.MISSION_READY, None),
     PRE + "0000" "0001" "0102" "0000"),
    ("mission_ready_id", Message(0, 7, 0x0103, Action.MISSION_READY, 7),
     PRE + "0000" "0007" "0103" "0000" + "0007"),
    ("start_mission", Message(1, 0, 0x0010, Action.START_MISSION, None),
     PRE + "0001" "0000" "0010" "0001"),
    ("end_mission", Message(2, 0, 0xFFFF, Action.END_MISSION, None),
     PRE + "0002" "0000" "FFFF" "0002"),
    ("wp_list_two", Message(0xFFFF, 0, 0x1234, Action.WP_LIST, (ITEM_A, ITEM_B)),
     PRE + "FFFF" "0000" "1234" "0003" + "0002" + ITEM_A_HEX + ITEM_B_HEX),
    ("wp_list_empty", Message(1, 0, 5, Action.WP_LIST, ()),
     PRE + "0001" "0000" "0005" "0003" + "0000"),
    ("wp_on", Message(1, 0, 7, Action.WP_ON, ITEM_A),
     PRE + "0001" "0000" "0007" "0004" + ITEM_A_HEX),
    ("wp_off", Message(1, 0, 8, Action.WP_OFF, None),
     PRE + "0001" "0000" "0008" "0005"),
    ("obstacles_list", Message(0x0102, 0, 9, Action.OBSTACLES_LIST, (ITEM_B,)),
     PRE + "0102" "0000" "0009" "0006" + "0001" + ITEM_B_HEX),
    ("ack", Message(0, 1, 0x0200, Action.ACK, 0x1234),
     PRE + "0000" "0001" "0200" "0007" + "1234"),
    ("mav_passthrough", Message(1, 0, 10, Action.MAV_PASSTHROUGH, bytes.fromhex(HEARTBEAT_V1_HEX)),
     PRE + "0001" "0000" "000A" "0008" + HEARTBEAT_V1_HEX),
]


def test_golden_vectors_cover_every_action_code() -> None:
    assert {int(m.action) for _, m, _ in GOLDEN} == set(range(9))


@pytest.mark.parametrize(("name", "msg", "hexstr"), GOLDEN, ids=[g[0] for g in GOLDEN])
def test_golden_encode(name: str, msg: Message, hexstr: str) -> None:
    assert encode(msg).hex().upper() == hexstr.upper()


@pytest.mark.parametrize(("name", "msg", "hexstr"), GOLDEN, ids=[g[0] for g in GOLDEN])
def test_golden_decode(name: str, msg: Message, hexstr: str) -> None:
    got = decode(bytes.fromhex(hexstr))
    assert got == msg
    assert type(got.action) is Action
    assert encode(got) == bytes.fromhex(hexstr)


def test_wp_list_benchmark_message_is_93_bytes() -> None:
    assert len(bytes.fromhex(GOLDEN[4][2])) == 93 == HEADER_SIZE + 2 + 2 * 37


def test_peek_header_reads_malformed_payloads() -> None:
    data = build_datagram(3, 0, 77, Action.WP_ON, b"\x01")
    assert peek_header(data) == (3, 0, 77, 4)
    assert peek_header(data[:HEADER_SIZE - 1]) is None
    assert peek_header(b"X" + data[1:]) is None


@pytest.mark.parametrize(("msg", "why"), [
    (Message(1, 0, 1, Action.ANY, None), "MCP-HDR-3"),
    (Message(1, 0, 1, Action.START_MISSION, b"x"), "no payload"),
    (Message(1, 0, 1, Action.ACK, 70000), "u16"),
    (Message(1, 0, 70000, Action.WP_OFF, None), "out of range"),
    (Message(1, 0, 1, Action.MAV_PASSTHROUGH, "frame"), "bytes"),
])
def test_encode_refuses_what_the_spec_forbids(msg: Message, why: str) -> None:
    with pytest.raises(LocalProtocolError, match=why):
        encode(msg)


# ---------------------------------------------------------------- properties
@tiered_property(150, 40, messages(), base=FAST)
def test_round_trip_message(msg: Message) -> None:
    data = encode(msg)
    assert decode(data) == msg
    assert encode(decode(data)) == data


@tiered_property(150, 40, datagrams(), base=FAST)
def test_round_trip_bytes(data: bytes) -> None:
    assert encode(decode(data)) == data


@FAST
@given(st.binary(max_size=300))
def test_decode_raises_only_decode_error(data: bytes) -> None:
    try:
        decode(data)
    except DecodeError as exc:
        assert exc.rule in set(MALFORMED_KINDS.values())
        assert "\n" not in str(exc)


@FAST
@given(st.binary(max_size=120).map(lambda b: bytes.fromhex(PRE) + b))
def test_decode_with_a_good_preamble_raises_only_decode_error(data: bytes) -> None:
    try:
        decode(data)
    except DecodeError as exc:
        assert exc.rule in set(MALFORMED_KINDS.values())


@FAST
@given(st.sampled_from(sorted(MALFORMED_KINDS)).flatmap(
    lambda k: st.tuples(st.just(k), malformed_datagrams(k))))
def test_every_malformed_kind_is_rejected_with_its_rule(case: tuple[str, bytes]) -> None:
    kind, data = case
    with pytest.raises(DecodeError) as info:
        decode(data)
    assert info.value.rule == MALFORMED_KINDS[kind]


def _expected_rule(action: int) -> str:
    return "MCP-PAY-6" if action == Action.MAV_PASSTHROUGH else "MCP-ROB-4"


@tiered_property(150, 40, messages(), base=FAST)
def test_every_proper_prefix_is_rejected(msg: Message) -> None:
    data = encode(msg)
    for n in range(len(data)):
        prefix = data[:n]
        if (n == HEADER_SIZE and msg.action == Action.MISSION_READY and msg.payload is not None):
            # D-3: a Mission_Ready cut after its header is the empty-payload form, still valid.
            assert decode(prefix) == msg._replace(payload=None)
            continue
        with pytest.raises(DecodeError) as info:
            decode(prefix)
        want = "MCP-ROB-1" if n < HEADER_SIZE else _expected_rule(msg.action)
        assert info.value.rule == want, (n, info.value)


@tiered_property(150, 40, messages(), st.binary(min_size=1, max_size=80), base=FAST)
def test_trailing_garbage_is_rejected(msg: Message, garbage: bytes) -> None:
    if msg.action == Action.MISSION_READY and msg.payload is None:
        assume(garbage != msg.src.to_bytes(2, "big"))  # that is the valid D-3 ID form
    with pytest.raises(DecodeError) as info:
        decode(encode(msg) + garbage)
    assert info.value.rule == _expected_rule(msg.action)


def test_decode_survives_the_largest_datagram() -> None:
    big = build_datagram(1, 0, 1, Action.WP_LIST, b"\xff" * (65507 - HEADER_SIZE))
    with pytest.raises(DecodeError) as info:
        decode(big)
    assert info.value.rule == "MCP-ROB-4"


def test_decode_rejects_non_bytes_with_decode_error() -> None:
    with pytest.raises(DecodeError):
        decode(None)  # type: ignore[arg-type]


def _decode_outcome(data: bytes) -> tuple[Message | None, tuple[str, str] | None]:
    try:
        return decode(data), None
    except DecodeError as exc:
        assert str(exc) == f"{exc.rule}: {exc.reason}"
        return None, (exc.rule, exc.reason)


@FAST
@given(st.one_of(datagrams(), st.binary(max_size=120),
                 st.sampled_from(sorted(MALFORMED_KINDS)).flatmap(malformed_datagrams)))
def test_try_decode_is_decode_without_the_raise(data: bytes) -> None:
    """The endpoint's hot path (try_decode) answers what decode does: the message, or the
    rule and reason decode's DecodeError carries; each read first, then again from the codec's
    last-datagram memory (the same object), then from an equal but new object."""
    first = try_decode(data)
    assert _decode_outcome(data) == first == try_decode(data)
    other = bytes(bytearray(data))
    assert _decode_outcome(other) == first
    assert try_decode(bytearray(data)) == first  # not remembered: not immutable
    assert (first[0] is None) != (first[1] is None)


def test_the_memory_of_malformed_datagrams_is_bounded() -> None:
    """try_decode remembers malformed datagrams (a flood repeats a few), at most _MEMO_MAX of
    at most _MEMO_BYTES each: a flood of distinct ones, or of big ones, holds no more."""
    from mcp_conform.spec import codec

    for i in range(3 * codec._MEMO_MAX):
        data = build_datagram(1, 0, i, 200)  # MCP-ROB-3, each different
        assert try_decode(data) == (None, ("MCP-ROB-3", "action code 200 is not 0-8"))
        assert 0 < len(codec._memo) <= codec._MEMO_MAX
    big = build_datagram(1, 0, 1, Action.WP_LIST, b"\x00\x09" + bytes(codec._MEMO_BYTES))
    assert try_decode(big)[1][0] == "MCP-ROB-4"  # type: ignore[index]
    assert big not in codec._memo


def test_action_and_mission_item_follow_the_spec() -> None:
    from mcp_conform.spec import SPEC

    assert [(a.name, int(a)) for a in Action] == [(a.name, a.code) for a in SPEC.actions]
    assert MissionItem._fields == tuple(f["name"] for f in SPEC.mission_item["fields"])


def test_passthrough_longer_than_any_frame_is_pay6_without_parsing_it_all():
    """A Mav_Passthrough payload longer than one MAVLink frame can be (v1 263, v2 280 bytes)
    is rejected as MCP-PAY-6 up front (the fuzzer sends them up to 65,507 bytes)."""
    from mcp_conform.spec.mavframe import heartbeat_frame

    for version in (1, 2):
        frame = heartbeat_frame(version)
        for tail in (frame * 30, bytes(65_000)):
            data = build_datagram(1, 0, 1, int(Action.MAV_PASSTHROUGH), frame + tail)
            with pytest.raises(DecodeError) as exc:
                decode(data)
            assert exc.value.rule == "MCP-PAY-6"


def test_a_frame_of_an_id_the_dialect_has_not_is_pay6():
    """MCP-PAY-6: "exactly one complete MAVLink v1 or v2 frame with a valid checksum under the
    ardupilotmega dialect". pymavlink hands a frame of an unknown id over unchecked (there is no
    CRC extra to check its checksum by): it is no valid frame, v1 or v2, so a node built on the
    dialect's C headers, which drops it, is not owed an ACK (mcp-fuzz --role manager found
    "MCP-ACK-1" on a C manager with such a frame, msgid 0x20FD, checksum 0x3412)."""
    for frame in (bytes([0xFD, 3, 0, 0, 5, 1, 1]) + (0x20FD).to_bytes(3, "little") + b"\x01\x02\x03\x12\x34",
                  bytes([0xFE, 3, 5, 1, 1, 3]) + b"\x01\x02\x03\x12\x34"):  # id 3: none in the dialect
        data = build_datagram(1, 0, 1, int(Action.MAV_PASSTHROUGH), frame)
        with pytest.raises(DecodeError) as exc:
            decode(data)
        assert exc.value.rule == "MCP-PAY-6" and "not in the ardupilotmega dialect" in str(exc.value), exc.value

"""spec/nsqd.yaml and what is derived from it: the one schema takes both specs, the loader
checks what the schema cannot, docs/nsqd.md is current, and the codec and the deframer
(issue 20): frames round-trip, bytes in any split give the same frames, a frame followed
by garbage still comes out whole, lengths out of bounds are framing errors naming
NSQD-FRM-4, malformed bodies are BodyErrors naming NSQD-MSG-7."""

from __future__ import annotations

import struct
from pathlib import Path

import pytest
import yaml
from hypothesis import given, settings
from hypothesis import strategies as st

from mcp_conform.spec import MAVLINK, NSQD, RULES, SPEC, SpecError, load, load_stream
from mcp_conform.spec.docs_nsqd import render
from mcp_conform.spec.nsqd_codec import (
    BodyError,
    Deframer,
    Frame,
    FramingError,
    decode_body,
    encode,
    gpx_problem,
    number_problem,
)
from mcp_conform.spec.nsqd_strategies import message_values, streams

ROOT = Path(__file__).resolve().parents[2]

UPDATE = dict(roll=1, pitch=2, yaw=3, thrust=4, lat=55, lon=10, alt=30, state=2)


def test_one_schema_takes_both_protocols_and_rules_do_not_collide():
    assert SPEC.protocol["transport"] == "udp" and NSQD.protocol["transport"] == "tcp"
    assert len(RULES) == len(SPEC.rules) + len(NSQD.rules) + len(MAVLINK.rules)
    assert all(r.startswith("NSQD-") for r in NSQD.rules_by_id)
    assert [m.id for m in NSQD.messages] == list(range(15))
    assert NSQD.framing.min_length == 5 and NSQD.framing.max_length == 8192


def test_loaders_refuse_the_other_kind_and_broken_specs(tmp_path):
    with pytest.raises(SpecError, match="stream protocol"):
        load(NSQD.path)
    with pytest.raises(SpecError, match="datagram protocol"):
        load_stream(SPEC.path)
    raw = yaml.safe_load(NSQD.path.read_text())
    raw["messages"][1]["effect"] = {"to": ["FLYING"]}
    bad = tmp_path / "bad.yaml"
    bad.write_text(yaml.safe_dump(raw))
    with pytest.raises(SpecError, match=r"messages\[1\].effect.to: unknown state 'FLYING'"):
        load_stream(bad)
    raw = yaml.safe_load(NSQD.path.read_text())
    raw["header"] = {}
    bad.write_text(yaml.safe_dump(raw))
    with pytest.raises(SpecError):
        load_stream(bad)


def test_committed_page_is_current_and_complete():
    page = (ROOT / "docs" / "nsqd.md").read_text(encoding="utf-8")
    assert page == render(NSQD), "docs/nsqd.md is stale: run `python -m mcp_conform.spec docs`"
    for rule in NSQD.rules:
        assert f"| {rule.id} " in page
    for m in NSQD.messages:
        assert f"`{m.name}`" in page
    for note in NSQD.errata + NSQD.decisions:
        assert f"**{note.id} {note.title}**" in page


def test_update_frame_layout_is_the_codes():
    f = encode(NSQD, "UPDATE", **UPDATE)
    assert len(f) == 37 and f[:5] == b"\x00\x00\x00\x25\x01"  # the length counts itself (E-1)
    assert struct.unpack(">7Ii", f[5:]) == (1, 2, 3, 4, 55, 10, 30, 2)


def _frames(data: bytes, cuts: list[int]) -> list[Frame | FramingError]:
    d, out, last = Deframer(NSQD), [], 0
    for c in sorted(set(cuts)) + [len(data)]:
        out += d.feed(data[last:c])
        last = c
    return out


STREAM = (encode(NSQD, "UPDATE", **UPDATE) + encode(NSQD, "ERROR", text="bad thing")
          + encode(NSQD, "SET_RPYTFF", roll="1.5", pitch="-2", yaw="0", thrust="40", flag=1, file_name="a.csv")
          + encode(NSQD, "TAKEOFF"))


def test_whole_byte_by_byte_and_trailing_garbage_give_the_same_frames():
    whole = _frames(STREAM, [])
    assert [f.msg_id for f in whole] == [1, 0, 7, 4]  # type: ignore[union-attr]
    assert _frames(STREAM, list(range(len(STREAM)))) == whole
    d = Deframer(NSQD)
    assert d.feed(STREAM + b"\x00\x00") == whole and d.pending == 2


@settings(max_examples=60, deadline=None)
@given(st.lists(st.integers(0, len(STREAM)), max_size=12))
def test_any_split_gives_the_same_frames(cuts):
    assert _frames(STREAM, cuts) == _frames(STREAM, [])


@pytest.mark.parametrize("length", [0, 1, 4, -1, -2**31, 8193, 2**31 - 1])
def test_length_out_of_bounds_is_a_framing_error_and_ends_the_stream(length):
    d = Deframer(NSQD)
    out = d.feed(struct.pack(">i", length) + b"\x04" + encode(NSQD, "TAKEOFF"))
    assert len(out) == 1 and isinstance(out[0], FramingError) and out[0].rule == "NSQD-FRM-4"
    assert d.feed(encode(NSQD, "TAKEOFF")) == []


@pytest.mark.parametrize("name,body,why", [
    ("SET_RPYTFF", struct.pack(">h", -1), "negative"),
    ("SET_RPYTFF", struct.pack(">h", 100) + b"1", "past the frame"),
    ("SET_HOVERHEIGHT", b"\x00\x00", "body ends"),
    ("SET_PID", b"".join(struct.pack(">h", 1) + b"1" for _ in range(3)) + struct.pack(">i", 3), "outside 0..2"),
    ("UPLOAD_FLIGHTPATH", struct.pack(">h", 5) + b"<gpx>", "not well-formed"),
])
def test_malformed_bodies_are_body_errors(name, body, why):
    with pytest.raises(BodyError, match=why) as info:
        decode_body(NSQD, NSQD.message(name).id, body)
    assert info.value.rule == "NSQD-MSG-7"


def test_text_checks():
    assert number_problem("1.5e3") is None and number_problem("-2") is None
    assert number_problem("abc") and number_problem("nan") and number_problem("1e999")
    assert gpx_problem('<gpx><trkseg><trkpt lat="1" lon="2"/></trkseg></gpx>') is None
    assert gpx_problem("<kml/>") and gpx_problem('<gpx><wpt lat="91" lon="0"/></gpx>')


@settings(max_examples=150, deadline=None)
@given(message_values())
def test_every_message_round_trips(nv):
    from mcp_conform.spec.nsqd_codec import Deframer as D

    name, values = nv
    (fr,) = D(NSQD).feed(encode(NSQD, name, **values))
    got = decode_body(NSQD, fr.msg_id, fr.body).as_dict()  # type: ignore[union-attr]
    want = {k: (bool(v) if isinstance(v, bool) else v) for k, v in values.items()}
    assert got == want


@settings(max_examples=80, deadline=None)
@given(streams())
def test_streams_cut_anywhere_give_their_frames(stream):
    data, cuts = stream
    assert _frames(data, cuts) == _frames(data, [])

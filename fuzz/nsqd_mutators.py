"""Cases for fuzzing a stream-protocol backend (``mcp-fuzz --protocol nsqd``), derived from
``spec/nsqd.yaml`` and drawn from a seeded ``random.Random`` (same seed, same cases).

A case is a list of :class:`Write`: bytes written on the connection as one ``send``, then
maybe a FIN or an RST. :func:`draw_case` builds one valid message from the messages table
(its fields typed as the spec says: decimal text, GPX paths, integer ranges) and applies one
mutation of a kind named in :data:`KINDS`: the length prefix lying (0, 1-4, negative, off
by one either way, over the bound), string lengths negative or past the frame, ids out of
range, bodies cut short or padded, numeric text that is not a number, GPX mutated in
structure and in size, a frame across many writes, many frames in one write, a frame cut by
FIN or by RST. ``valid`` says whether every frame of the case is one the spec says a
backend handles (only then is a close by the backend a finding).
"""

from __future__ import annotations

import random
import struct
from dataclasses import dataclass, field
from typing import Any

from mcp_conform.spec import NSQD
from mcp_conform.spec.nsqd import Field, MessageSpec, StreamSpec, int_range
from mcp_conform.spec.nsqd_codec import encode_body, frame
from mcp_conform.spec.nsqd_strategies import GPX_FORMS, gpx_document

__all__ = ["KINDS", "Case", "Write", "draw_case", "valid_values"]


@dataclass(frozen=True)
class Write:
    data: bytes
    end: str = ""  # "" | "fin" | "rst": how the connection ends after this write


@dataclass(frozen=True)
class Case:
    kind: str
    writes: tuple[Write, ...]
    valid: bool = False
    note: str = ""
    probe: bool = field(default=True)  # whether a probe command may follow on the same connection
    expect: tuple[int, ...] = ()  # a valid command's effect on the flight state (NSQD-MSG-3)
    or_error: bool = False  # ... or an ERROR when the autopilot may refuse (D-6)
    check: bool = False  # judge the effect after this case (the campaign samples which)
    msg: str = ""  # the message a one-message case carries (its name)

    @property
    def data(self) -> bytes:
        return b"".join(w.data for w in self.writes)


KINDS = ("valid", "length-lie", "string-length", "bad-id", "body-cut", "body-padded", "number-text",
         "gpx-structure", "gpx-size", "field-range", "split-writes", "batched", "fin-mid-frame",
         "rst-mid-frame", "random-bytes")

_NUMBERS_BAD = ["", "abc", "nan", "inf", "-inf", "1e999", "1.2.3", "0x10", " 1", "1 ", "--1", "+", ".",
                "9" * 400, "1e-99999", "\x00", "١٢", "1,5"]


def _gpx(rng: random.Random, points: int, form: tuple[str, str] | None = None) -> str:
    """A flight path of ``points`` random points in one of ``spec.nsqd_strategies.GPX_FORMS``
    (D-7: "at least one wpt, rtept or trkpt"; Nsqd's Matrice100::loadPathFromString reads
    ``trk > trkpt`` only, and every route it is sent is a null ``trk``)."""
    pts = [(round(rng.uniform(-89, 89), 5), round(rng.uniform(-179, 179), 5)) for _ in range(points)]
    return gpx_document(pts, form or rng.choice(GPX_FORMS))


def _gpx_broken(rng: random.Random) -> str:
    """A document D-7 does not call a flight path, or one at its edges: cut, nested deep, a
    coordinate that is no number or out of range, a point without lat, a track without points,
    an entity, an attribute flood, bytes."""
    doc = _gpx(rng, rng.randrange(1, 8))
    point = next(p for _, p in GPX_FORMS if f"<{p} " in doc)
    return rng.choice([
        doc[: rng.randrange(1, len(doc))],
        "<gpx>" + "<rte>" * rng.randrange(50, 1500) + "</gpx>",
        doc.replace('lat="', 'lat="x', 1),
        doc.replace(f"<{point}", f'<{point} lat="1e999"', 1),
        doc.replace(f"<{point} lat=", f"<{point} lax=", 1),
        '<gpx><wpt lat="' + "9" * rng.randrange(100, 3000) + '" lon="1"/></gpx>',
        '<gpx><trk></trk></gpx>',
        '<gpx><trk><trkpt lon="1"/></trk></gpx>',
        f'<gpx><trk><trkpt lat="{rng.choice(["abc", "", "1e999", "-"])}" lon="1"/></trk></gpx>',
        '<notgpx><trk><trkpt lat="1" lon="1"/></trk></notgpx>',
        '<?xml version="1.0"?><!DOCTYPE g [<!ENTITY a "aaaaaaaaaa">]><gpx><wpt lat="&a;" lon="1"/></gpx>',
        "<gpx " + "a=\"1\" " * rng.randrange(10, 900) + "/>",
        rng.randbytes(rng.randrange(1, 200)).decode("latin-1"),
    ])


def valid_values(spec: StreamSpec, msg: MessageSpec, rng: random.Random) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for f in msg.fields:
        t = spec.types[f.type]
        if "length" in t:
            if f.text == "number":
                out[f.name] = f"{rng.uniform(-500, 500):.{rng.randrange(0, 4)}f}"
            elif f.text == "gpx":
                out[f.name] = _gpx(rng, rng.randrange(1, 6))
            else:
                out[f.name] = "".join(rng.choice("abcdefghij_.0123") for _ in range(rng.randrange(0, 24)))
        else:
            lo, hi = int_range(t["struct"])
            lo = max(lo, f.min) if f.min is not None else lo
            hi = min(hi, f.max) if f.max is not None else hi
            out[f.name] = bool(rng.randrange(2)) if t["struct"] == ">?" else rng.randint(lo, hi)
    return out


def _client_messages(spec: StreamSpec) -> list[MessageSpec]:
    return [m for m in spec.messages if m.sent_by in ("client", "any") and not m.effect.unobserved]


def _string_fields(msg: MessageSpec, spec: StreamSpec) -> list[int]:
    return [i for i, f in enumerate(msg.fields) if "length" in spec.types[f.type]]


def _offsets(spec: StreamSpec, msg: MessageSpec, values: dict[str, Any]) -> list[int]:
    """Where each field starts in the body."""
    pos, out = 0, []
    for f in msg.fields:
        out.append(pos)
        pos += len(encode_body(spec, MessageSpec(0, "", "", (f,), msg.effect, ""), {f.name: values[f.name]}))
    return out


def draw_case(rng: random.Random, spec: StreamSpec = NSQD, kind: str | None = None) -> Case:
    kind = kind or rng.choice(KINDS)
    msgs = _client_messages(spec)
    msg = rng.choice(msgs)
    values = valid_values(spec, msg, rng)
    body = encode_body(spec, msg, values)
    whole = frame(spec, msg.id, body)
    fr = spec.framing
    f: Field | None  # the field a case aims at
    if kind == "valid":
        return Case(kind, (Write(whole),), valid=True, note=msg.name, expect=msg.effect.to, or_error=msg.effect.or_error,
                    msg=msg.name)
    if kind == "length-lie":
        n = len(whole)
        lie = rng.choice([0, 1, 2, 3, 4, -1, -n, -2**31, n - 1, n + 1, n + rng.randrange(2, 64),
                          fr.max_length, fr.max_length + 1, 2**31 - 1, rng.randrange(-2**31, 2**31)])
        return Case(kind, (Write(struct.pack(fr.prefix_struct, lie) + whole[fr.prefix_width:]),),
                    note=f"{msg.name} length {lie}", probe=False)
    if kind == "string-length":
        strs = _string_fields(msg, spec)
        if not strs:
            return draw_case(rng, spec, "body-cut")
        i = rng.choice(strs)
        off = _offsets(spec, msg, values)[i]
        n = rng.choice([-1, -2, -32768, len(body) + 1, 32767, rng.randrange(-32768, 32768)])
        mutated = body[:off] + struct.pack(">h", n) + body[off + 2:]
        return Case(kind, (Write(frame(spec, msg.id, mutated)),), note=f"{msg.name}.{msg.fields[i].name} length {n}")
    if kind == "bad-id":
        known = {m.id for m in spec.messages}
        bad = rng.choice([i for i in range(256) if i not in known])
        return Case(kind, (Write(frame(spec, bad, rng.randbytes(rng.randrange(0, 32)))),), note=f"id {bad}")
    if kind == "body-cut" and body:
        cut = rng.randrange(0, len(body))
        return Case(kind, (Write(frame(spec, msg.id, body[:cut])),), note=f"{msg.name} cut to {cut} of {len(body)}")
    if kind == "body-padded":
        return Case(kind, (Write(frame(spec, msg.id, body + rng.randbytes(rng.randrange(1, 64)))),),
                    valid=True, note=f"{msg.name} with trailing bytes")
    if kind == "number-text":
        numeric = [m for m in msgs if any(f.text == "number" for f in m.fields)]
        msg = rng.choice(numeric)
        values = valid_values(spec, msg, rng)
        f = rng.choice([f for f in msg.fields if f.text == "number"])
        values[f.name] = rng.choice(_NUMBERS_BAD)
        return Case(kind, (Write(frame(spec, msg.id, encode_body(spec, msg, values))),),
                    note=f"{msg.name}.{f.name} = {values[f.name][:20]!r}")
    if kind in ("gpx-structure", "gpx-size"):
        gmsg = next((m for m in msgs if any(f.text == "gpx" for f in m.fields)), msg)
        f = next(f for f in gmsg.fields if f.text == "gpx") if gmsg is not msg or any(f.text == "gpx" for f in msg.fields) else None
        if f is None:
            return draw_case(rng, spec, "valid")
        whole_path = False
        if kind == "gpx-size":
            room = fr.max_length - fr.header_size - 2
            size = rng.choice([room, room - 1, room + 1, rng.randrange(300, room)])
            doc = _gpx(rng, 400)
            text = doc[:size] if len(doc) >= size else doc + " " * (size - len(doc))
            whole_path = bool(rng.randrange(2))
            if whole_path:  # a whole path that fits: a frame the backend handles (NSQD-FRM-5)
                text = _gpx(rng, max(1, (min(size, room) - 80) // 52))
            note = f"GPX of {len(text)} bytes"
            if len(text.encode("utf-8", "surrogateescape")) > room:  # the frame is over the bound: closed (FRM-4)
                data = text.encode("utf-8", "surrogateescape")[:32767]
                return Case(kind, (Write(frame(spec, gmsg.id, struct.pack(">h", len(data)) + data)),),
                            note=note, probe=False)
        else:
            text = _gpx_broken(rng)
            note = f"GPX mutated ({len(text)} bytes)"
        data = text.encode("utf-8", "surrogateescape")[: 32767]
        body = struct.pack(">h", len(data)) + data
        if kind == "gpx-size" and whole_path:
            return Case(kind, (Write(frame(spec, gmsg.id, body)),), valid=True, note=note,
                        expect=gmsg.effect.to, or_error=gmsg.effect.or_error, msg=gmsg.name)
        return Case(kind, (Write(frame(spec, gmsg.id, body)),), note=note)
    if kind == "field-range":
        bounded = [(m, f) for m in msgs for f in m.fields if f.min is not None or f.max is not None]
        if not bounded:
            return draw_case(rng, spec, "valid")
        m, f = rng.choice(bounded)
        values = valid_values(spec, m, rng)
        values[f.name] = rng.choice([(f.min or 0) - 1, (f.max or 0) + 1, -2**31, 2**31 - 1])
        return Case(kind, (Write(frame(spec, m.id, encode_body(spec, m, values))),), note=f"{m.name}.{f.name} = {values[f.name]}")
    if kind == "split-writes":
        cuts = sorted(set(rng.sample(range(1, len(whole)), min(len(whole) - 1, rng.randrange(1, 8))))) if len(whole) > 1 else []
        parts, last = [], 0
        for c in [*cuts, len(whole)]:
            parts.append(Write(whole[last:c]))
            last = c
        return Case(kind, tuple(parts), valid=True, note=f"{msg.name} in {len(parts)} writes")
    if kind == "batched":
        frames = [frame(spec, (m := rng.choice(msgs)).id, encode_body(spec, m, valid_values(spec, m, rng)))
                  for _ in range(rng.randrange(2, 12))]
        return Case(kind, (Write(b"".join(frames)),), valid=True, note=f"{len(frames)} frames in one write")
    if kind in ("fin-mid-frame", "rst-mid-frame"):
        cut = rng.randrange(1, len(whole)) if len(whole) > 1 else 1
        return Case(kind, (Write(whole[:cut], end=kind[:3]),), note=f"{msg.name} cut at {cut} by {kind[:3].upper()}",
                    probe=False)
    data = rng.randbytes(rng.randrange(1, 64))
    return Case("random-bytes", (Write(data),), note=f"{len(data)} random bytes", probe=False)

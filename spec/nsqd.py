"""Load and check a stream protocol's spec (``spec/nsqd.yaml``): framing, field types, flight
states, messages and the rule catalogue.

Validated against the same ``spec.schema.json`` as ``mcp.yaml`` (its ``tcp`` branch), then
checked for what a schema cannot say: the prefix's struct has the declared width, the
smallest frame holds the prefix and the id, every field's type and every effect's state
exist, message ids and names are unique. The codec (``spec.nsqd_codec``), docs/nsqd.md and
the runner's Nsqd cases are derived from the :class:`StreamSpec` this returns.
"""

from __future__ import annotations

import struct
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

from mcp_conform.spec._load import SpecBase, SpecError, _fail, build_catalogue, read_validated

__all__ = ["NSQD_PATH", "Effect", "Field", "Framing", "MessageSpec", "StreamSpec", "int_range", "load_stream"]

NSQD_PATH = Path(__file__).with_name("nsqd.yaml")


@dataclass(frozen=True)
class Field:
    """One body field: its name, its type (a key of the spec's ``types``) and its checks."""

    name: str
    type: str
    text: str | None = None  # "number" | "gpx": what a string field's text must be (D-3, D-7)
    min: int | None = None
    max: int | None = None
    doc: str = ""


@dataclass(frozen=True)
class Effect:
    """What a handled message does to the flight state (NSQD-MSG-3)."""

    to: tuple[int, ...] = ()  # accepted state values, the handler's own first
    or_error: bool = False  # the autopilot may refuse; ERROR then (D-6)
    unobserved: bool = False  # left to the autopilot: not judged (D-5)

    @property
    def changes_state(self) -> bool:
        return bool(self.to)


@dataclass(frozen=True)
class MessageSpec:
    id: int
    name: str
    sent_by: str
    fields: tuple[Field, ...]
    effect: Effect
    doc: str


@dataclass(frozen=True)
class Framing:
    """The frame: a length prefix (``prefix_struct``, counting itself or not), an id, the body."""

    prefix_struct: str
    prefix_width: int
    counts_itself: bool
    id_struct: str
    min_length: int
    max_length: int

    @property
    def header_size(self) -> int:
        return self.prefix_width + struct.calcsize(self.id_struct)


@dataclass(frozen=True)
class StreamSpec(SpecBase):
    """The loaded, checked spec of a stream protocol: its framing, field types, flight states
    and messages."""

    DOCS: ClassVar[str] = "mcp_conform.spec.docs_nsqd"

    framing: Framing = field(repr=False, default=None)  # type: ignore[assignment]
    types: Mapping[str, Mapping[str, Any]] = field(repr=False, default_factory=dict)
    states: Mapping[str, int] = field(repr=False, default_factory=dict)
    messages: tuple[MessageSpec, ...] = ()

    def message(self, key: int | str) -> MessageSpec:
        """The message with this id or name (``KeyError`` if none)."""
        found: MessageSpec = super().message(key)
        return found

    def has_message(self, msg_id: int) -> bool:
        return any(m.id == msg_id for m in self.messages)

    def state_name(self, value: int) -> str:
        for name, v in self.states.items():
            if v == value:
                return name
        return f"state {value} (unknown)"


def int_range(struct_code: str) -> tuple[int, int]:
    """The values a fixed-size integer type of the spec carries (``>?`` a bool: 0..1)."""
    if struct_code.endswith("?"):
        return 0, 1
    bits = 8 * struct.calcsize(struct_code)
    if struct_code[-1].islower():  # b h i q: signed
        return -(2 ** (bits - 1)), 2 ** (bits - 1) - 1
    return 0, 2 ** bits - 1


def load_stream(path: str | Path | None = None) -> StreamSpec:
    """Load, validate and check a stream protocol's spec (default: the packaged ``nsqd.yaml``)."""
    raw, sha, src = read_validated(path if path is not None else NSQD_PATH)
    if raw["protocol"]["transport"] != "tcp":
        raise SpecError(f"{src}: protocol.transport: {raw['protocol']['transport']!r}: a datagram protocol (spec.load)")
    roles = tuple(raw["protocol"]["roles"])
    errata, decisions, params, rules, by_id = build_catalogue(raw, src, roles)

    fr = raw["framing"]
    width = struct.calcsize(fr["prefix"]["struct"])
    if width != fr["prefix"]["width"]:
        raise _fail("framing.prefix.width", f"{fr['prefix']['width']} but struct {fr['prefix']['struct']!r} packs {width} bytes", src)
    framing = Framing(prefix_struct=fr["prefix"]["struct"], prefix_width=width,
                      counts_itself=fr["prefix"]["counts_itself"], id_struct=fr["id"]["struct"],
                      min_length=fr["min_length"], max_length=fr["max_length"])
    if framing.counts_itself and framing.min_length < framing.header_size:
        raise _fail("framing.min_length", f"{framing.min_length} cannot hold the prefix and the id ({framing.header_size} bytes)", src)
    if framing.max_length < framing.min_length:
        raise _fail("framing.max_length", "below min_length", src)

    types = raw["types"]
    for name, t in types.items():
        if "length" in t and (t["length"] not in types or "struct" not in types[t["length"]]):
            raise _fail(f"types.{name}.length", f"names no fixed-size type: {t['length']!r}", src)
    states: dict[str, int] = {}
    for i, st in enumerate(raw["states"]):
        if st["name"] in states or st["value"] in states.values():
            raise _fail(f"states[{i}]", f"duplicate state {st['name']} = {st['value']}", src)
        states[st["name"]] = st["value"]

    messages: list[MessageSpec] = []
    for i, m in enumerate(raw["messages"]):
        where = f"messages[{i}]"
        if any(o.id == m["id"] or o.name == m["name"] for o in messages):
            raise _fail(where, f"duplicate message id or name {m['id']} {m['name']}", src)
        if m["sent_by"] not in (*roles, "any"):
            raise _fail(where + ".sent_by", f"{m['sent_by']!r} is not a role of the protocol", src)
        fields = []
        for j, f in enumerate(m["fields"]):
            if f["type"] not in types:
                raise _fail(f"{where}.fields[{j}].type", f"unknown type {f['type']!r}", src)
            if "text" in f and "length" not in types[f["type"]]:
                raise _fail(f"{where}.fields[{j}].text", "only a string field carries text", src)
            fields.append(Field(name=f["name"], type=f["type"], text=f.get("text"), min=f.get("min"),
                                max=f.get("max"), doc=f.get("doc", "")))
        eff = m["effect"]
        for s_name in eff.get("to", []):
            if s_name not in states:
                raise _fail(f"{where}.effect.to", f"unknown state {s_name!r}", src)
        effect = Effect(to=tuple(states[s] for s in eff.get("to", [])), or_error=eff.get("or_error", False),
                        unobserved=eff.get("unobserved", False))
        messages.append(MessageSpec(id=m["id"], name=m["name"], sent_by=m["sent_by"], fields=tuple(fields),
                                    effect=effect, doc=" ".join(m["doc"].split())))
    return StreamSpec(raw=raw, sha256=sha, path=src, rules=rules, errata=errata, decisions=decisions,
                      params=params, rules_by_id=by_id, framing=framing, types=types, states=states,
                      messages=tuple(messages))

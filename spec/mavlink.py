"""Load and check MAVLink's microservices spec (``spec/mavlink.yaml``): the heartbeat, command,
parameter and mission protocols, their messages by MAVLink name, and the rule catalogue.

The YAML names messages, fields, enums and enum entries; it types none of them. Their ids,
fields, types and values come from the pymavlink dialect the spec names (``dialect.module``,
``pymavlink.dialects.v20.ardupilotmega``): "Use the libraries made for the job (pymavlink's
dialect for every MAVLink constant and layout: nothing re-typed)". The file is validated
against the same ``spec.schema.json`` as ``mcp.yaml`` and ``nsqd.yaml`` (its ``mavlink``
branch), then checked for what a schema cannot say: every service is a rule group, every
message and enum a service lists and every ``refs`` name of a rule exists in the dialect,
every rule cites its source (a quoted passage, or the word "paraphrase") with a URL.
docs/mavlink.md is drawn from the :class:`MavlinkSpec` this returns (``spec.docs_mavlink``).
"""

from __future__ import annotations

import importlib
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import ModuleType
from typing import Any, ClassVar

from mcp_conform.spec._load import SpecBase, SpecError, _fail, build_catalogue, read_validated

__all__ = ["MAVLINK_PATH", "Citation", "FieldLayout", "MavlinkSpec", "MessageLayout", "ServiceMessage",
           "ServiceSpec", "deprecated_messages", "load_mavlink"]

MAVLINK_PATH = Path(__file__).with_name("mavlink.yaml")

_QUOTED = re.compile(r'"([^"]+)"')


@dataclass(frozen=True)
class FieldLayout:
    """One field of a MAVLink message as the dialect defines it."""

    name: str
    type: str  # the dialect's C type, with [n] for arrays: "uint8_t", "char[16]"
    enum: str | None = None


@dataclass(frozen=True)
class MessageLayout:
    """A MAVLink message as the dialect defines it: id, fields in declaration order, CRC_EXTRA."""

    name: str
    id: int
    fields: tuple[FieldLayout, ...]
    crc_extra: int

    def field(self, name: str) -> FieldLayout:
        for f in self.fields:
            if f.name == name:
                return f
        raise KeyError(f"{self.name}.{name}")


@dataclass(frozen=True)
class ServiceMessage:
    """A message a microservice uses: its MAVLink name, the role that sends it, its layout."""

    name: str
    sent_by: str
    layout: MessageLayout
    deprecated: bool = False
    doc: str = ""

    @property
    def id(self) -> int:
        return self.layout.id


@dataclass(frozen=True)
class ServiceSpec:
    """One microservice: its rule group, its page, its messages and enums."""

    group: str
    title: str
    url: str
    messages: tuple[ServiceMessage, ...]
    enums: tuple[str, ...]
    doc: str = ""


@dataclass(frozen=True)
class Citation:
    """Where a rule comes from: the page, the passages quoted from it, or a paraphrase."""

    url: str
    quotes: tuple[str, ...]
    paraphrase: bool


@dataclass(frozen=True)
class MavlinkSpec(SpecBase):
    """The loaded, checked spec of MAVLink's microservices, with the dialect's layouts of every
    message it names."""

    DOCS: ClassVar[str] = "mcp_conform.spec.docs_mavlink"

    dialect: ModuleType = field(repr=False, default=None)  # type: ignore[assignment]
    services: tuple[ServiceSpec, ...] = ()
    layouts: Mapping[str, MessageLayout] = field(repr=False, default_factory=dict)
    #: every enum of the dialect: its entries by name, with their values
    enums: Mapping[str, Mapping[str, int]] = field(repr=False, default_factory=dict)
    citations: Mapping[str, Citation] = field(repr=False, default_factory=dict)
    refs: Mapping[str, tuple[str, ...]] = field(repr=False, default_factory=dict)

    @property
    def messages(self) -> tuple[ServiceMessage, ...]:
        """Every message of every service, once (the first service that lists it)."""
        seen: dict[str, ServiceMessage] = {}
        for svc in self.services:
            for m in svc.messages:
                seen.setdefault(m.name, m)
        return tuple(seen.values())

    def message(self, key: int | str) -> ServiceMessage:
        """The message with this id or MAVLink name (``KeyError`` if no service uses it)."""
        found: ServiceMessage = super().message(key)
        return found

    def service(self, group: str) -> ServiceSpec:
        for svc in self.services:
            if svc.group == group:
                return svc
        raise KeyError(group)

    def layout(self, name: str) -> MessageLayout:
        """The dialect's layout of any message it defines (``KeyError`` if none)."""
        return self.layouts[name]

    def enum_value(self, entry: str) -> int:
        """The value of an enum entry by its name (``MAV_RESULT_UNSUPPORTED`` -> 3)."""
        for entries in self.enums.values():
            if entry in entries:
                return entries[entry]
        raise KeyError(entry)

    def resolve(self, name: str) -> str:
        """What a MAVLink name is in the dialect: ``message``, ``field``, ``enum`` or
        ``entry`` (``KeyError``: the dialect has no such name)."""
        head, _, member = name.partition(".")
        if head in self.layouts:
            if not member:
                return "message"
            self.layouts[head].field(member)
            return "field"
        if member:
            raise KeyError(name)
        if head in self.enums:
            return "enum"
        self.enum_value(head)
        return "entry"


def _layouts(dialect: ModuleType) -> dict[str, MessageLayout]:
    out: dict[str, MessageLayout] = {}
    for cls in dialect.mavlink_map.values():
        arrays = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
        fields = tuple(
            FieldLayout(name=n, type=t + (f"[{arrays[n]}]" if arrays.get(n) else ""),
                        enum=cls.fieldenums_by_name.get(n) or None)
            for n, t in zip(cls.fieldnames, cls.fieldtypes, strict=True))
        out[cls.msgname] = MessageLayout(name=cls.msgname, id=cls.id, fields=fields, crc_extra=cls.crc_extra)
    return out


def _enums(dialect: ModuleType) -> dict[str, dict[str, int]]:
    return {name: {e.name: value for value, e in entries.items() if not e.name.endswith("_ENUM_END")}
            for name, entries in dialect.enums.items()}


def _citation(rule: Mapping[str, Any], where: str, src: Path) -> Citation:
    source = rule["source"]
    quotes = tuple(q.strip() for q in _QUOTED.findall(source) if q.strip())
    paraphrase = "paraphrase" in source.lower()
    if not quotes and not paraphrase:
        raise _fail(where + ".source", f"{rule['id']}: quotes nothing (no \"...\") and says no \"paraphrase\"", src)
    return Citation(url=rule["url"], quotes=quotes, paraphrase=paraphrase)


def load_mavlink(path: str | Path | None = None) -> MavlinkSpec:
    """Load, validate and check a MAVLink microservices spec (default: the packaged ``mavlink.yaml``)."""
    raw, sha, src = read_validated(path if path is not None else MAVLINK_PATH)
    if raw["protocol"]["transport"] != "mavlink":
        raise SpecError(f"{src}: protocol.transport: {raw['protocol']['transport']!r}: not a MAVLink spec "
                        "(spec.load, spec.nsqd.load_stream)")
    roles = tuple(raw["protocol"]["roles"])
    errata, decisions, params, rules, by_id = build_catalogue(raw, src, roles)
    try:
        dialect = importlib.import_module(raw["dialect"]["module"])
    except ImportError as exc:
        raise _fail("dialect.module", f"cannot import {raw['dialect']['module']!r}: {exc}", src) from None
    layouts, enums = _layouts(dialect), _enums(dialect)

    services: list[ServiceSpec] = []
    for group, svc in raw["services"].items():
        where = f"services.{group}"
        if group not in raw["groups"]:
            raise _fail(where, f"{group!r} is not a rule group (groups)", src)
        msgs = []
        for i, m in enumerate(svc["messages"]):
            if m["name"] not in layouts:
                raise _fail(f"{where}.messages[{i}].name", f"{m['name']!r} is no message of {dialect.__name__}", src)
            if m["sent_by"] not in (*roles, "any"):
                raise _fail(f"{where}.messages[{i}].sent_by", f"{m['sent_by']!r} is not a role of the protocol", src)
            msgs.append(ServiceMessage(name=m["name"], sent_by=m["sent_by"], layout=layouts[m["name"]],
                                       deprecated=m.get("deprecated", False), doc=m.get("doc", "")))
        for i, e in enumerate(svc.get("enums", [])):
            if e not in enums:
                raise _fail(f"{where}.enums[{i}]", f"{e!r} is no enum of {dialect.__name__}", src)
        services.append(ServiceSpec(group=group, title=raw["groups"][group], url=svc["url"], messages=tuple(msgs),
                                    enums=tuple(svc.get("enums", [])), doc=svc.get("doc", "")))

    spec = MavlinkSpec(raw=raw, sha256=sha, path=src, rules=rules, errata=errata, decisions=decisions,
                       params=params, rules_by_id=by_id, dialect=dialect, services=tuple(services),
                       layouts=layouts, enums=enums)
    citations: dict[str, Citation] = {}
    refs: dict[str, tuple[str, ...]] = {}
    for i, r in enumerate(raw["rules"]):
        where = f"rules[{i}]"
        citations[r["id"]] = _citation(r, where, src)
        for name in r.get("refs", []):
            try:
                spec.resolve(name)
            except KeyError:
                raise _fail(where + ".refs", f"{r['id']}: {name!r} is no message, field, enum or entry "
                            f"of {dialect.__name__}", src) from None
        refs[r["id"]] = tuple(r.get("refs", []))
    object.__setattr__(spec, "citations", citations)
    object.__setattr__(spec, "refs", refs)
    return spec


def deprecated_messages(spec: MavlinkSpec) -> frozenset[str]:
    """The messages the dialect's XML marks ``<deprecated>``, read with pymavlink's own parser
    (``pymavlink.generator.mavparse``) from ``dialect.xml`` and the files it includes."""
    import contextlib
    import io

    from pymavlink.generator import mavparse

    folder = os.path.dirname(str(spec.dialect.__file__))
    todo, seen, out = [spec.raw["dialect"]["xml"]], set(), set()
    while todo:
        name = todo.pop()
        if name in seen:
            continue
        seen.add(name)
        with contextlib.redirect_stdout(io.StringIO()):  # mavparse prints its warnings
            xml = mavparse.MAVXML(os.path.join(folder, name), mavparse.PROTOCOL_2_0)
        out |= {m.name for m in xml.message if getattr(m, "deprecated", None)}
        todo += list(xml.include)
    return frozenset(out)

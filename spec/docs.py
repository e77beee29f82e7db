"""Generate the human-readable spec page, ``docs/spec.md``, from ``spec/mcp.yaml``.

The page is derived, never edited: header table (MCP-HDR-1/2), action codes with direction
and payload layout (MCP-HDR-3/5), payload layouts (MCP-PAY-1..6, D-2, D-3), the mission
item (MCP-PAY-4, E-1, E-2), parameters, errata and decisions, and the full rule table with
levels, roles, the decisions each rule rests on and how a black-box runner observes it per
role. ``python -m mcp_conform.spec docs`` writes it and ``python -m mcp_conform.spec docs --check`` fails when the
committed page is stale.

:func:`write`, :func:`check` and :func:`default_output` are the one entry point for every
protocol's page: each draws the page of the spec it is given with the module the spec names
(``SpecBase.DOCS``: this one for MCP, ``spec.docs_nsqd`` for Nsqd), whose ``render(spec)``,
``summary(spec)`` and ``DEFAULT_OUTPUT`` are its own.
"""

from __future__ import annotations

import importlib
import struct
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from mcp_conform.spec._load import ROLES, Spec, SpecBase

__all__ = ["DEFAULT_OUTPUT", "check", "default_output", "SummaryTable", "page", "render", "summary", "write"]

#: A table of ``python -m mcp_conform.spec``'s summary: its title, its columns, its rows.
SummaryTable = tuple[str, Sequence[str], Sequence[Sequence[str]]]

#: Where the page lives, relative to the repository root.
DEFAULT_OUTPUT = Path("docs") / "spec.md"


def page(spec: SpecBase) -> Any:
    """The module that draws ``spec``'s page (``render``, ``summary``, ``DEFAULT_OUTPUT``)."""
    return importlib.import_module(spec.DOCS)


def default_output(spec: SpecBase | None = None) -> Path:
    """The page of ``spec`` (default: MCP's, ``docs/spec.md``) in the source tree this
    package sits in, else in the working directory."""
    relative: Path = page(spec).DEFAULT_OUTPUT if spec is not None else DEFAULT_OUTPUT
    root = Path(__file__).resolve().parents[1]
    return root / relative if (root / "pyproject.toml").is_file() else relative


def _cell(value: Any) -> str:
    text = " ".join(str(value).split())
    return text.replace("|", "\\|") if text else "—"


def _table(head: Sequence[str], rows: Iterable[Sequence[Any]]) -> list[str]:
    out = ["| " + " | ".join(head) + " |", "|" + "|".join("---" for _ in head) + "|"]
    out += ["| " + " | ".join(_cell(c) for c in row) + " |" for row in rows]
    return out + [""]


def _layout_rows(layout: Mapping[str, Any]) -> list[tuple[Any, ...]]:
    """(offset, field, struct code, bytes, value or meaning) for a struct layout."""
    order = layout["struct"][0] if layout["struct"][0] in "@=<>!" else "@"
    rows, offset = [], 0
    for f in layout["fields"]:
        size = struct.calcsize(order + f["code"])
        if "const" in f:
            const = f["const"]
            meaning = f"constant {const!r}" if isinstance(const, str) else f"constant {const}"
            meaning += f" ({f['doc']})" if f.get("doc") else ""
        else:
            meaning = f.get("doc", "")
        rows.append((offset, f"`{f['name']}`", f"`{f['code']}`", size, meaning))
        offset += size
    return rows


def _payload_layout(spec: Spec, name: str) -> str:
    p = spec.payloads[name]
    kind = p["kind"]
    item = spec.mission_item["size"]
    if kind == "empty":
        return "none (17-byte datagram)"
    if kind == "optional_id":
        return f"empty, or drone ID `{p['struct']}`"
    if kind == "seq":
        return f"acknowledged seq `{p['struct']}`"
    if kind == "counted_items":
        return f"count `{p['count_struct']}` + count × {item}-byte mission item"
    if kind == "single_item":
        return f"one {item}-byte mission item"
    if kind == "mavlink_frame":
        return f"one MAVLink v1/v2 frame ({p.get('dialect', '')})"
    return kind


def _observe(rule: Any, role: str) -> str:
    obs = rule.observe.get(role)
    if obs is None:
        return "n/a"
    text = f"{obs.observable} ({obs.side})"
    return text + (f": {obs.reason}" if obs.reason else "")


def page_head(spec: Any) -> list[str]:
    """Every spec page's first lines: its title and the note that it is generated."""
    proto, name = spec.protocol, spec.path.name
    return [
        f"# {proto['name']} ({proto['short_name']}) — specification",
        "",
        f"<!-- Generated from spec/{name} by `python -m mcp_conform.spec docs`. Do not edit by hand:",
        f"     edit spec/{name} and regenerate; a test fails when this page is stale. -->",
        "",
    ]


def render(spec: Spec) -> str:
    """The whole page as Markdown, a pure function of the spec."""
    proto = spec.protocol
    hdr = spec.header
    item = spec.mission_item
    lines = [
        *page_head(spec),
        f"Source document: {proto['document']}, version {proto['document_version']} "
        f"({proto['document_date']}). Spec file format version {spec.raw['spec_version']}.",
        "",
        "## Protocol",
        "",
    ]
    ports = ", ".join(f"{role} {port}" for role, port in proto["ports"].items())
    lines += _table(("property", "value"), [
        ("transport", str(proto["transport"]).upper()),
        ("conventional ports", ports),
        ("manager ID", proto["manager_id"]),
        ("broadcast ID (D-1)", f"0x{proto['broadcast_id']:04X}"),
        ("local broadcast address", proto["broadcast_address"]),
        ("largest datagram", f"{proto['max_datagram']} bytes"),
    ])
    lines += [
        "## Header",
        "",
        f"{hdr['size']} bytes, struct `{hdr['struct']}` ({hdr['byte_order']} byte order); "
        f"preamble `{' '.join(spec.preamble.hex(' ').upper().split())}`.",
        "",
    ]
    lines += _table(("offset", "field", "code", "bytes", "value / meaning"), _layout_rows(hdr))
    lines += ["## Action codes", ""]
    lines += _table(
        ("code", "name", "sent by", "delivery", "payload", "meaning"),
        [(a.code, f"`{a.wire_name}`" + ("" if a.on_wire else " (never on the wire)"),
          a.sent_by, a.delivery, _payload_layout(spec, a.payload) if a.on_wire else "—", a.doc)
         for a in spec.actions])
    lines += ["## Payload layouts", ""]
    users: dict[str, list[str]] = {}
    for a in spec.actions:
        if a.on_wire:
            users.setdefault(a.payload, []).append(a.wire_name)
    lines += _table(
        ("layout", "kind", "struct", "used by", "description"),
        [(f"`{name}`", p["kind"], f"`{p.get('struct') or p.get('count_struct') or ''}`"
          if (p.get("struct") or p.get("count_struct")) else "—",
          ", ".join(users.get(name, [])), p.get("doc", ""))
         for name, p in spec.payloads.items()])
    lines += [
        "## Mission item",
        "",
        f"{item['size']} bytes, struct `{item['struct']}` (little-endian): the MAVLink v1 "
        f"{item['mavlink_message']} payload (message id {item['mavlink_msgid']}). Waypoint "
        f"files are `{item['waypoint_file']}`.",
        "",
    ]
    lines += _table(("offset", "field", "code", "bytes", "meaning"), _layout_rows(item))
    lines += catalogue_sections(spec, ROLES, "`mcp` (the node's MCP messages), `vehicle` (its MAVLink link), `none`")
    return "\n".join(lines).rstrip("\n") + "\n"


def catalogue_sections(spec: Any, roles: Sequence[str], observables: str) -> list[str]:
    """Parameters, errata and decisions, and the rule tables: the part of the page every
    protocol's spec has (``spec`` a ``Spec`` or a ``spec.nsqd.StreamSpec``)."""
    lines: list[str] = ["## Parameters", ""]
    lines += _table(("parameter", "default", "meaning"),
                    [(f"`{k}`", v["default"], v.get("doc", ""))
                     for k, v in spec.raw["parameters"].items()])
    lines += ["## Errata and decisions", ""]
    for note in spec.errata + spec.decisions:
        param = f" (parameter `{note.parameter}`)" if note.parameter else ""
        lines += [f"- **{note.id} {note.title}**{param}. {' '.join(note.text.split())}"]
    lines += [""]
    counts: dict[str, int] = {}
    for r in spec.rules:
        counts[r.level] = counts.get(r.level, 0) + 1
    summary = ", ".join(f"{n} {lvl}" for lvl, n in counts.items())
    lines += [
        "## Rules",
        "",
        f"{len(spec.rules)} rules ({summary}). Observability per role: {observables}; "
        "and the side of an exchange the rule "
        "binds. \"Depends on\" lists the errata and decisions a rule rests on, and the rules "
        "its observation relies on: when one of those failed first, the runner reports this "
        "rule's failure as its consequence.",
        "",
    ]
    for group, title in spec.groups.items():
        rules = [r for r in spec.rules if r.group == group]
        if not rules:
            continue
        lines += [f"### {group} — {title}", ""]
        lines += _table(
            ("ID", "level", "roles", "requirement", "depends on", *(f"observe ({r})" for r in roles)),
            [(f"{r.id}" + (f" ({r.status})" if r.status != "active" else ""), r.level,
              ", ".join(r.roles), r.text, ", ".join(r.depends_on),
              *(_observe(r, role) for role in roles))
             for r in rules])
    return lines


def summary(spec: Spec) -> list[SummaryTable]:
    """The tables ``python -m mcp_conform.spec`` prints of MCP's spec (title, columns, rows): the header
    and the action codes."""
    header = [(f["name"], f["code"], repr(f["const"]) if "const" in f else f.get("doc", ""))
              for f in spec.header["fields"]]
    actions = [(str(a.code), a.wire_name + ("" if a.on_wire else " (API only)"), a.sent_by, a.delivery, a.payload)
               for a in spec.actions]
    return [(f"Header: {spec.header['size']} bytes, struct {spec.header['struct']}",
             ("field", "code", "value / meaning"), header),
            ("Action codes", ("code", "name", "sent by", "delivery", "payload"), actions)]


def write(spec: SpecBase, path: str | Path | None = None) -> Path:
    """Write the page of ``spec``, whatever its protocol; returns its path."""
    out = Path(path) if path is not None else default_output(spec)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(page(spec).render(spec), encoding="utf-8")
    return out


def check(spec: SpecBase, path: str | Path | None = None) -> bool:
    """True when the page at ``path`` is exactly what the spec's ``render`` gives."""
    out = Path(path) if path is not None else default_output(spec)
    try:
        return out.read_text(encoding="utf-8") == page(spec).render(spec)
    except OSError:
        return False

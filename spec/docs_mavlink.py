"""Generate ``docs/mavlink.md`` from ``spec/mavlink.yaml``, as ``spec.docs`` does ``docs/spec.md``.

The page is derived, never edited: the protocol (links, roles, the pymavlink dialect), each
microservice with its page and its messages, whose ids and fields are the dialect's (nothing
re-typed: ``spec.mavlink`` reads them from pymavlink), the enums each service uses with their
entries, then the parameters, errata, decisions and rule tables shared with every spec
(``spec.docs.catalogue_sections``), and the source of every rule: its quote or paraphrase and
the URL it is read at. ``spec.docs.write`` and ``check`` draw it, the entry point of every
protocol's page.
"""

from __future__ import annotations

from pathlib import Path

from mcp_conform.spec.docs import SummaryTable, _table, catalogue_sections, page_head
from mcp_conform.spec.mavlink import MavlinkSpec, ServiceMessage, ServiceSpec

__all__ = ["DEFAULT_OUTPUT", "render", "summary"]

DEFAULT_OUTPUT = Path("docs") / "mavlink.md"

#: enums with more entries than this are summarised by their count on the page
_ENUM_LISTED = 20


def _fields(msg: ServiceMessage) -> str:
    return ", ".join(f"`{f.name}` {f.type}" + (f" ({f.enum})" if f.enum else "") for f in msg.layout.fields)


def _service(spec: MavlinkSpec, svc: ServiceSpec) -> list[str]:
    lines = [f"### {svc.group} — {svc.title}", "", f"{svc.doc} Page: <{svc.url}>.", ""]
    lines += _table(("id", "message", "sent by", "fields (from the dialect)", "meaning"),
                    [(m.id, f"`{m.name}`" + (" (deprecated)" if m.deprecated else ""), m.sent_by, _fields(m), m.doc)
                     for m in svc.messages])
    rows = []
    for name in svc.enums:
        entries = spec.enums[name]
        listed = (", ".join(f"{e} = {v}" for e, v in entries.items()) if len(entries) <= _ENUM_LISTED
                  else f"{len(entries)} entries")
        rows.append((f"`{name}`", listed))
    if rows:
        lines += _table(("enum", "entries"), rows)
    return lines


def render(spec: MavlinkSpec) -> str:
    """The whole page as Markdown, a pure function of the spec and its dialect."""
    proto, dialect = spec.protocol, spec.raw["dialect"]
    lines = [
        *page_head(spec),
        f"Source: {proto['document']}, as of {proto['document_version']}. Spec file format "
        f"version {spec.raw['spec_version']}. Every rule quotes its source with the page's URL, or "
        "says where it paraphrases; messages, fields and enums are named by their MAVLink names and "
        f"laid out by pymavlink's `{dialect['module']}` (`{dialect['xml']}`), never re-typed.",
        "",
        "## Protocol",
        "",
    ]
    lines += _table(("property", "value"), [
        ("links", ", ".join(proto["links"])),
        ("roles", ", ".join(spec.roles)),
        ("conventional ports", ", ".join(f"{r} {p}" for r, p in proto["ports"].items())),
        ("dialect", f"`{dialect['module']}` ({dialect['xml']}), wire versions "
                    + ", ".join(str(v) for v in dialect.get("wire_versions", []))),
    ])
    lines += ["## Microservices", ""]
    for svc in spec.services:
        lines += _service(spec, svc)
    lines += catalogue_sections(spec, spec.roles, "`mavlink` (the node's MAVLink frames on the runner's link), `none`")
    lines += ["## Sources", "", "Each rule's source: the passages quoted (or the paraphrase) and where they are read.", ""]
    lines += _table(("ID", "source", "URL"),
                    [(r.id, r.source, f"<{spec.citations[r.id].url}>") for r in spec.rules])
    return "\n".join(lines).rstrip("\n") + "\n"


def summary(spec: MavlinkSpec) -> list[SummaryTable]:
    """The table ``python -m mcp_conform.spec`` prints of MAVLink's spec: each service's messages."""
    return [(f"Messages (dialect {spec.raw['dialect']['module']})",
             ("service", "id", "name", "sent by"),
             [(svc.group, str(m.id), m.name + (" (deprecated)" if m.deprecated else ""), m.sent_by)
              for svc in spec.services for m in svc.messages])]

"""Generate ``docs/nsqd.md`` from ``spec/nsqd.yaml``, as ``spec.docs`` does ``docs/spec.md``.

The page is derived, never edited: the protocol and its transport, the framing (the length
prefix that counts itself: E-1, D-1), the field types ("floats" as the integers the wire
carries: E-2), the flight states, every message with its body layout and its effect on the
flight state (NSQD-MSG-3), then the parameters, errata, decisions and rule tables shared
with every spec (``spec.docs.catalogue_sections``). ``python -m mcp_conform.spec docs`` writes both
pages (``spec.docs.write`` and ``check``, the entry point of every protocol's page); ``--check``
fails when either is stale.
"""

from __future__ import annotations

from pathlib import Path

from mcp_conform.spec.docs import SummaryTable, _table, catalogue_sections, page_head
from mcp_conform.spec.nsqd import MessageSpec, StreamSpec

__all__ = ["DEFAULT_OUTPUT", "render", "summary"]

DEFAULT_OUTPUT = Path("docs") / "nsqd.md"


def _layout(spec: StreamSpec, msg: MessageSpec) -> str:
    fields = msg.fields
    if not fields:
        return "empty"
    parts = []
    for f in fields:
        extra = f", {f.text} text" if f.text else ""
        extra += f", {f.min}..{f.max}" if f.min is not None or f.max is not None else ""
        parts.append(f"`{f.name}` {f.type}{extra}")
    return "; ".join(parts)


def _effect(spec: StreamSpec, msg: MessageSpec) -> str:
    eff = msg.effect
    if eff.unobserved:
        return "not judged (D-5)"
    if not eff.to:
        return "none"
    text = " or ".join(spec.state_name(s) for s in eff.to)
    return text + (", or ERROR when refused (D-6)" if eff.or_error else "")


def render(spec: StreamSpec) -> str:
    """The whole page as Markdown, a pure function of the spec."""
    proto, fr = spec.protocol, spec.framing
    lines = [
        *page_head(spec),
        f"Source: {proto['document']}, as of {proto['document_version']}. Spec file format "
        f"version {spec.raw['spec_version']}. Where the blog post and the code differ, the code is "
        "the wire truth and the difference is an erratum.",
        "",
        "## Protocol",
        "",
    ]
    lines += _table(("property", "value"), [
        ("transport", str(proto["transport"]).upper()),
        ("roles", ", ".join(spec.roles)),
        ("conventional ports", ", ".join(f"{r} {p}" for r, p in proto["ports"].items())),
    ])
    lines += ["## Framing", ""]
    lines += _table(("part", "bytes", "struct", "meaning"), [
        ("length", fr.prefix_width, f"`{fr.prefix_struct}`",
         "the frame's size in bytes, " + ("this prefix included (E-1)" if fr.counts_itself else "after this prefix")),
        ("message id", fr.header_size - fr.prefix_width, f"`{fr.id_struct}`", "the messages table"),
        ("body", "length − " + str(fr.header_size), "—", "the message's fields in order"),
    ])
    lines += [f"A length below {fr.min_length} or above {fr.max_length} is a framing error (NSQD-FRM-4, D-1).", ""]
    lines += ["## Field types", ""]
    lines += _table(("type", "wire", "meaning"),
                    [(f"`{n}`", f"`{t['struct']}`" if "struct" in t else f"`{t['length']}` length + bytes", t["doc"])
                     for n, t in spec.types.items()])
    lines += ["## Flight states", ""]
    lines += _table(("value", "state"), [(v, n) for n, v in spec.states.items()])
    lines += ["## Messages", ""]
    lines += _table(("id", "name", "sent by", "body", "effect on the flight state", "meaning"),
                    [(m.id, f"`{m.name}`", m.sent_by, _layout(spec, m), _effect(spec, m), m.doc)
                     for m in spec.messages])
    lines += catalogue_sections(spec, spec.roles, "`stream` (the backend's frames on the runner's connections), `none`")
    return "\n".join(lines).rstrip("\n") + "\n"


def summary(spec: StreamSpec) -> list[SummaryTable]:
    """The table ``python -m mcp_conform.spec`` prints of a stream protocol's spec: its messages."""
    return [(f"Messages (frame: {spec.framing.prefix_struct} length counting itself, id, body)",
             ("id", "name", "sent by", "fields"),
             [(str(m.id), m.name, m.sent_by, ", ".join(f"{f.name}:{f.type}" for f in m.fields))
              for m in spec.messages])]

"""``python -m spec``: validate the spec and print its summary; ``python -m spec docs``.

    python -m spec [--spec PATH]                      validate, print header layout, action
                                                      codes and rule counts by group and level
    python -m spec [--spec PATH] docs [--check] [--output FILE]
                                                      write (or check) docs/spec.md and
                                                      docs/nsqd.md (one page with --spec)
    python -m spec --protocol nsqd [docs ...]         the Nsqd TCP protocol's spec

Exit 0 on success; 1 when ``docs --check`` finds the page stale; 2 with a one-line reason
when the spec is broken or the arguments are wrong.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from rich.console import Console
from rich.table import Table

from spec._load import LEVELS, Spec, SpecError, load, read_validated
from spec.profiles import PROFILES, add_protocol_option, pick
from spec.stream import StreamSpec, load_stream


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m spec",
                                description="Validate the MCP spec and print its summary.")
    p.add_argument("--spec", metavar="PATH", help="spec file to load (default: the packaged mcp.yaml and nsqd.yaml)")
    add_protocol_option(p, f"the packaged spec of this protocol only ({', '.join(PROFILES)})")
    sub = p.add_subparsers(dest="command")
    d = sub.add_parser("docs", help="write docs/spec.md from the spec (or --check it)")
    d.add_argument("--check", action="store_true", help="fail (exit 1) when the page is stale")
    d.add_argument("--output", metavar="FILE", help="page to write/check (default: docs/spec.md)")
    return p


def _load_any(path: str | None, protocol: str | None) -> list[Spec | StreamSpec]:
    """The specs asked for: a file (either kind, by its transport), one protocol, or both."""
    if path is not None:
        raw, _, _ = read_validated(path)
        return [load_stream(path) if raw["protocol"]["transport"] == "tcp" else load(path)]
    if protocol is not None:
        return [pick(protocol)[0].spec]
    return [load(), load_stream()]


def print_summary(spec: Spec | StreamSpec, console: Console) -> None:
    """Header layout, action codes (messages for a stream protocol) and rule counts by group
    and level, as rich tables."""
    proto = spec.protocol
    console.print(f"[bold]{proto['name']}[/bold] v{spec.version} — {spec.path} "
                  f"(sha256 {spec.sha256[:12]}…) [green]valid[/green]")
    if isinstance(spec, StreamSpec):
        msgs = Table(title=f"Messages (frame: {spec.framing.prefix_struct} length counting itself, id, body)")
        for col in ("id", "name", "sent by", "fields"):
            msgs.add_column(col)
        for m in spec.messages:
            msgs.add_row(str(m.id), m.name, m.sent_by, ", ".join(f"{f.name}:{f.type}" for f in m.fields))
        console.print(msgs)
        _rule_counts(spec, console)
        return
    hdr = Table(title=f"Header: {spec.header['size']} bytes, struct {spec.header['struct']}")
    for col in ("field", "code", "value / meaning"):
        hdr.add_column(col)
    for f in spec.header["fields"]:
        hdr.add_row(f["name"], f["code"], repr(f["const"]) if "const" in f else f.get("doc", ""))
    console.print(hdr)
    acts = Table(title="Action codes")
    for col in ("code", "name", "sent by", "delivery", "payload"):
        acts.add_column(col)
    for a in spec.actions:
        acts.add_row(str(a.code), a.wire_name + ("" if a.on_wire else " (API only)"),
                     a.sent_by, a.delivery, a.payload)
    console.print(acts)
    _rule_counts(spec, console)


def _rule_counts(spec: Spec | StreamSpec, console: Console) -> None:
    rules = Table(title=f"Rules: {len(spec.rules)}")
    rules.add_column("group")
    for level in LEVELS:
        rules.add_column(level, justify="right")
    rules.add_column("total", justify="right")
    for group, title in spec.groups.items():
        in_group = [r for r in spec.rules if r.group == group]
        rules.add_row(f"{group} ({title})", *(str(sum(r.level == lv for r in in_group)) for lv in LEVELS),
                      str(len(in_group)))
    rules.add_row("[bold]all[/bold]", *(str(sum(r.level == lv for r in spec.rules)) for lv in LEVELS),
                  str(len(spec.rules)))
    console.print(rules)


def main(argv: Sequence[str] | None = None) -> int:
    args = _parser().parse_args(argv)
    err = Console(stderr=True, highlight=False, soft_wrap=True)
    try:
        specs = _load_any(args.spec, args.protocol)
    except SpecError as exc:
        err.print(f"error: {exc}", markup=False)
        return 2
    if args.command == "docs":
        from spec import docs, docs_stream

        if args.output and len(specs) > 1:
            err.print("error: --output: give --protocol or --spec too (one page per spec)", markup=False)
            return 2
        stale = False
        for spec in specs:
            page = docs_stream if isinstance(spec, StreamSpec) else docs
            out = args.output
            if args.check:
                if page.check(spec, out):  # type: ignore[arg-type]
                    print(f"{out or page.default_output()} is current")
                else:
                    err.print(f"error: {out or page.default_output()} is stale: run `python -m spec docs`",
                              markup=False)
                    stale = True
            else:
                print(f"wrote {page.write(spec, out)}")  # type: ignore[arg-type]
        return 1 if stale else 0
    for spec in specs:
        print_summary(spec, Console())
    return 0


if __name__ == "__main__":
    sys.exit(main())

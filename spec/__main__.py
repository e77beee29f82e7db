"""``python -m spec``: validate the spec and print its summary; ``python -m spec docs``.

    python -m spec [--spec PATH]                      validate, print header layout, action
                                                      codes and rule counts by group and level
    python -m spec [--spec PATH] docs [--check] [--output FILE]
                                                      write (or check) docs/spec.md

Exit 0 on success; 1 when ``docs --check`` finds the page stale; 2 with a one-line reason
when the spec is broken or the arguments are wrong.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from rich.console import Console
from rich.table import Table

from spec._load import LEVELS, Spec, SpecError, load


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m spec",
                                description="Validate the MCP spec and print its summary.")
    p.add_argument("--spec", metavar="PATH", help="spec file to load (default: the packaged mcp.yaml)")
    sub = p.add_subparsers(dest="command")
    d = sub.add_parser("docs", help="write docs/spec.md from the spec (or --check it)")
    d.add_argument("--check", action="store_true", help="fail (exit 1) when the page is stale")
    d.add_argument("--output", metavar="FILE", help="page to write/check (default: docs/spec.md)")
    return p


def print_summary(spec: Spec, console: Console) -> None:
    """Header layout, action codes and rule counts by group and level, as rich tables."""
    proto = spec.protocol
    console.print(f"[bold]{proto['name']}[/bold] v{spec.version} — {spec.path} "
                  f"(sha256 {spec.sha256[:12]}…) [green]valid[/green]")
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
        spec = load(args.spec)
    except SpecError as exc:
        err.print(f"error: {exc}", markup=False)
        return 2
    if args.command == "docs":
        from spec import docs

        out = args.output
        if args.check:
            if docs.check(spec, out):
                print(f"{out or docs.default_output()} is current")
                return 0
            err.print(f"error: {out or docs.default_output()} is stale: run `python -m spec docs`",
                      markup=False)
            return 1
        print(f"wrote {docs.write(spec, out)}")
        return 0
    print_summary(spec, Console())
    return 0


if __name__ == "__main__":
    sys.exit(main())

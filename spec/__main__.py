"""``python -m mcp_conform.spec``: validate the spec and print its summary; ``python -m mcp_conform.spec docs``.

    python -m mcp_conform.spec [--spec PATH]                      validate, print header layout, action
                                                      codes and rule counts by group and level
    python -m mcp_conform.spec [--spec PATH] docs [--check] [--output FILE]
                                                      write (or check) docs/spec.md and
                                                      docs/nsqd.md (one page with --spec)
    python -m mcp_conform.spec --protocol nsqd [docs ...]         the Nsqd TCP protocol's spec

Exit 0 on success; 1 when ``docs --check`` finds the page stale; 2 with a one-line reason
when the spec is broken or the arguments are wrong.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from rich.console import Console
from rich.table import Table

from mcp_conform.spec._load import LEVELS, SpecBase, SpecError, read_validated
from mcp_conform.spec.profiles import PROFILES, add_protocol_option, pick, resolve


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m mcp_conform.spec",
                                description="Validate the MCP spec and print its summary.")
    p.add_argument("--spec", metavar="PATH", help="spec file to load (default: the packaged mcp.yaml and nsqd.yaml)")
    add_protocol_option(p, f"the packaged spec of this protocol only ({', '.join(PROFILES)})")
    sub = p.add_subparsers(dest="command")
    d = sub.add_parser("docs", help="write docs/spec.md from the spec (or --check it)")
    d.add_argument("--check", action="store_true", help="fail (exit 1) when the page is stale")
    d.add_argument("--output", metavar="FILE", help="page to write/check (default: docs/spec.md)")
    return p


def _load_any(path: str | None, protocol: str | None) -> list[SpecBase]:
    """The specs asked for: a file (loaded by the profile of its transport), one protocol's,
    or every protocol's."""
    if path is not None:
        raw, _, _ = read_validated(path)
        transport = raw["protocol"]["transport"]
        prof = next((p for p in PROFILES.values() if p.transport == transport), None)
        if prof is None:
            raise SpecError(f"{path}: protocol.transport: no protocol's spec is carried by {transport!r}")
        return [resolve(prof.loader)(path)]
    if protocol is not None:
        return [pick(protocol)[0].spec]
    return [p.spec for p in PROFILES.values()]


def print_summary(spec: SpecBase, console: Console) -> None:
    """The spec's own tables (``summary`` of its page's module: MCP's header and action codes,
    a stream protocol's messages), then its rule counts by group and level, as rich tables."""
    from mcp_conform.spec import docs

    console.print(f"[bold]{spec.name}[/bold] v{spec.version} — {spec.path} "
                  f"(sha256 {spec.sha256[:12]}…) [green]valid[/green]")
    for title, columns, rows in docs.page(spec).summary(spec):
        table = Table(title=title)
        for col in columns:
            table.add_column(col)
        for row in rows:
            table.add_row(*row)
        console.print(table)
    _rule_counts(spec, console)


def _rule_counts(spec: SpecBase, console: Console) -> None:
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
        from mcp_conform.spec import docs

        if args.output and len(specs) > 1:
            err.print("error: --output: give --protocol or --spec too (one page per spec)", markup=False)
            return 2
        stale = False
        for spec in specs:
            out = args.output
            if args.check:
                if docs.check(spec, out):
                    print(f"{out or docs.default_output(spec)} is current")
                else:
                    err.print(f"error: {out or docs.default_output(spec)} is stale: run `python -m mcp_conform.spec docs`",
                              markup=False)
                    stale = True
            else:
                print(f"wrote {docs.write(spec, out)}")
        return 1 if stale else 0
    for spec in specs:
        print_summary(spec, Console())
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The plumbing each stream or packet protocol writes outside its content (issue 39: "the lines
this protocol needed outside its own content modules (spec, monitor rules, cases, mutators and
oracles, reference nodes): target <= 300"), measured, not counted by hand.

A protocol's modules are the tracked ``.py`` files of the packages whose name holds its
profile's name (``spec.profiles.PROFILES``: ``mavlink``, ``nsqd``). Content, left out:

- ``spec/`` (its spec and what is derived from it: codec, strategies, scapy layer, spec page);
- ``judge/`` (its monitor rules);
- ``conformance/cases_<name>*/`` and ``fuzz/<name>_cases|mutators|oracles.py`` (cases,
  mutators and oracles);
- ``reference_impl/`` and ``vehicle/`` (its reference nodes: MAVLink's is the vehicle);
- ``captures/dissector_<name>.py`` (its Wireshark dissector, derived from the spec).

Everything else is plumbing: sessions, case contexts, capture tools and trace readers, the fuzz
target, campaign and triage. Code shared by the protocols (``harness.session_base``,
``fuzz.loop``, ``traceio.tcp``, ...) is not a protocol's; the last figure per protocol is the
code lines of shared modules (cases of other protocols aside) that still name it
(``mavlink``/``nsqd``, case aside): a check that
nothing protocol-bound moved into a shared module unnamed. A module is shared only when more
than one protocol uses it: one whose importers (every import statement of the packages, to a
fixed point) are all one protocol's is that protocol's plumbing, whatever its name, and the
figure "with them" adds it (session 28: ``harness/link_session.py`` and
``conformance/_link_case.py``, which MAVLink alone uses; ``captures/stream_tools.py``,
``conformance/_conn_case.py`` and ``traceio/tcp_pcap.py``, Nsqd's). This is by module: a
function of a module more than one protocol imports is not looked at (a class of
``fuzz.target_core`` or a path of ``captures.trace_tools`` only one protocol calls stays
shared here). "code": the lines that are neither blank, comments nor docstrings.

    python bench/plumbing_lines.py [--json] [--protocol NAME ...]
"""

from __future__ import annotations

import argparse
import ast
import io
import json
import re
import subprocess
import sys
import tokenize
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
PROTOCOLS = ("mavlink", "nsqd")
PACKAGES = ("captures", "conformance", "fuzz", "harness", "judge", "reference_impl", "reports", "sim",
            "soak", "spec", "traceio", "vehicle")
TARGET = 300


def content_kind(path: str, name: str) -> str | None:
    """Why a module of protocol ``name`` is content (None: it is plumbing)."""
    top, _, rest = path.partition("/")
    base = rest.rsplit("/", 1)[-1]
    if top == "spec":
        return "spec"
    if top == "judge":
        return "monitor rules"
    if top in ("reference_impl", "vehicle"):
        return "reference node"
    if top == "conformance" and rest.startswith(f"cases_{name}"):
        return "cases"
    if top == "fuzz" and base in (f"{name}_cases.py", f"{name}_mutators.py", f"{name}_oracles.py"):
        return "cases, mutators, oracles"
    if top == "captures" and base == f"dissector_{name}.py":
        return "dissector"
    return None


def tracked() -> list[str]:
    out = subprocess.run(["git", "ls-files", "-z", "--", *(f"{p}/*.py" for p in PACKAGES)], cwd=ROOT,
                         capture_output=True, check=True).stdout.decode()
    return sorted(p for p in out.split("\0") if p)


def measure(text: str) -> tuple[int, set[int]]:
    """(lines, the numbers of its code lines) of a module's source."""
    lines = text.count("\n") + (0 if text.endswith("\n") or not text else 1)
    docs: set[int] = set()
    for node in ast.walk(ast.parse(text)):
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            docs.update(range(node.lineno, (node.end_lineno or node.lineno) + 1))
    code: set[int] = set()
    skip = {tokenize.COMMENT, tokenize.NL, tokenize.NEWLINE, tokenize.INDENT, tokenize.DEDENT,
            tokenize.ENDMARKER, tokenize.ENCODING}
    for tok in tokenize.generate_tokens(io.StringIO(text).readline):
        if tok.type in skip or tok.start[0] in docs:
            continue
        code.update(range(tok.start[0], tok.end[0] + 1))
    return lines, code


def module_of(path: str) -> str:
    """``fuzz/loop.py`` -> ``mcp_conform.fuzz.loop`` (a package's ``__init__``: the package)."""
    dotted = path[:-3].replace("/", ".")
    return "mcp_conform." + (dotted[: -len(".__init__")] if dotted.endswith(".__init__") else dotted)


def imported_by(files: list[str]) -> dict[str, set[str]]:
    """Each module's importers among ``files`` (every import statement, at the top or inside a
    function; ``from pkg import mod`` counts for ``pkg.mod`` when that is a module)."""
    paths = {module_of(p): p for p in files}
    users: dict[str, set[str]] = {p: set() for p in files}
    for path in files:
        for node in ast.walk(ast.parse((ROOT / path).read_text())):
            names: list[str] = []
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names = [node.module] + [f"{node.module}.{a.name}" for a in node.names]
            for name in names:
                target = paths.get(name)
                if target is not None and target != path:
                    users[target].add(path)
    return users


def sole_users(files: list[str], owner: dict[str, str]) -> dict[str, str]:
    """The modules no protocol's name is in (``owner`` has them not) that one protocol alone
    uses: every importer is that protocol's, or a module this finds to be that protocol's alone
    (to a fixed point). Their code serves one protocol, however general its names."""
    users = imported_by(files)
    alone = dict(owner)
    changed = True
    while changed:
        changed = False
        for path, by in users.items():
            if path in alone or not by or "/cases" in path:
                continue
            whose = {alone.get(u) for u in by}
            if len(whose) == 1 and None not in whose:
                alone[path] = whose.pop()  # type: ignore[assignment]
                changed = True
    return {p: n for p, n in alone.items() if p not in owner}


def figures(names: tuple[str, ...]) -> dict[str, dict[str, Any]]:
    files = tracked()
    owned = {n: [p for p in files if n in p.rsplit("/", 1)[-1]] for n in PROTOCOLS}
    every_owned = {p for ps in owned.values() for p in ps}
    sole = sole_users(files, {p: n for n, ps in owned.items() for p in ps})
    result: dict[str, dict[str, Any]] = {}
    for name in names:
        plumbing: list[dict[str, Any]] = []
        content: list[dict[str, Any]] = []
        for path in owned[name]:
            lines, code = measure((ROOT / path).read_text())
            kind = content_kind(path, name)
            (content if kind else plumbing).append({"module": path, "lines": lines, "code": len(code), "kind": kind})
        word = re.compile(name, re.IGNORECASE)
        named: list[dict[str, Any]] = []
        for p in files:
            if p in every_owned or content_kind(p, name) is not None or "/cases" in p:
                continue
            text = (ROOT / p).read_text()
            at = measure(text)[1]
            named.append({"module": p, "lines": sum(1 for i, line in enumerate(text.splitlines(), 1)
                                                    if i in at and word.search(line))})
        only: list[dict[str, Any]] = []
        for p, whose in sorted(sole.items()):
            if whose == name:
                lines, code = measure((ROOT / p).read_text())
                only.append({"module": p, "lines": lines, "code": len(code), "kind": content_kind(p, name)})
        result[name] = {
            "plumbing": plumbing, "content": content,
            "lines": sum(m["lines"] for m in plumbing), "code": sum(m["code"] for m in plumbing),
            "content_lines": sum(m["lines"] for m in content),
            "shared_naming_it": [m for m in named if m["lines"]],
            "used_by_it_alone": only,
            "code_with_sole_use": sum(m["code"] for m in plumbing) + sum(m["code"] for m in only if not m["kind"]),
        }
    return result


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--json", action="store_true", help="the figures as JSON")
    ap.add_argument("--protocol", action="append", choices=PROTOCOLS, help="one protocol (repeatable)")
    ns = ap.parse_args(argv)
    res = figures(tuple(ns.protocol or PROTOCOLS))
    if ns.json:
        json.dump(res, sys.stdout, indent=1)
        print()
        return 0
    for name, r in res.items():
        print(f"{name}: plumbing {r['lines']} lines, {r['code']} of code (target <= {TARGET} lines); "
              f"content {r['content_lines']} lines left out")
        for m in r["plumbing"]:
            print(f"  {m['lines']:5d} {m['code']:5d}  {m['module']}")
        shared = r["shared_naming_it"]
        print(f"  shared modules naming {name}: {len(shared)} ({sum(m['lines'] for m in shared)} lines "
              f"of code that name it)")
        only = [m for m in r["used_by_it_alone"] if not m["kind"]]
        print(f"  modules without its name that {name} alone uses (its plumbing too): {len(only)} "
              f"({sum(m['code'] for m in only)} lines of code); with them: {r['code_with_sole_use']} of code")
        for m in only:
            print(f"  {m['lines']:5d} {m['code']:5d}  {m['module']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""The report's and the capture check's JSON Schemas are read from the installed package: they
were read from top-level ``conformance`` and ``captures`` packages, which only a checkout's
working directory has (an installed wheel has ``mcp_conform.conformance`` and
``mcp_conform.captures``): ``validate_json`` raised "No module named 'conformance'" anywhere else."""

from __future__ import annotations

import os
import subprocess
import sys


def test_the_schema_is_read_from_the_installed_package(tmp_path):
    """From a directory where no top-level ``conformance`` or ``captures`` package is
    importable, as with an installed wheel: both schemas load."""
    code = ("from mcp_conform.conformance.report import load_schema as a\n"
            "from mcp_conform.captures.check import load_schema as b\n"
            "print(a()['title'] and 'ok', b() and 'ok')")
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, capture_output=True, text=True, timeout=120,
                         env={k: v for k, v in os.environ.items() if k != "PYTHONPATH"})
    assert out.returncode == 0 and out.stdout.split() == ["ok", "ok"], out.stdout + out.stderr


def _walk(node, path=()):
    if isinstance(node, dict):
        yield path, node
        for k, v in node.items():
            yield from _walk(v, (*path, k))
    elif isinstance(node, list):
        for i, v in enumerate(node):
            yield from _walk(v, (*path, i))


def test_the_schema_admits_every_protocols_rule_ids_roles_and_name():
    """The schema's rule-ID patterns and its role and protocol enums are written by hand; every
    protocol plugged in (``spec.profiles.PROFILES``) must fit them, or its reports would not
    validate (MAVLink's and Nsqd's did not, until session 28). A protocol added with a new
    prefix or role fails here first."""
    import re

    from mcp_conform.conformance.report import load_schema
    from mcp_conform.spec.profiles import PROFILES

    schema = load_schema()
    rule_patterns = {n["pattern"] for _, n in _walk(schema) if "pattern" in n and "-[A-Z]+-" in n["pattern"]}
    assert rule_patterns, "no rule-ID pattern found in the schema"
    role_enum = set(schema["properties"]["role"]["enum"])
    protocol_enums = [set(n["enum"]) for p, n in _walk(schema) if p[-1:] == ("protocol",) and "enum" in n]
    assert protocol_enums
    for profile in PROFILES.values():
        for rule in profile.spec.rules_by_id:
            bad = [pat for pat in rule_patterns if not re.match(pat, rule)]
            assert not bad, f"{profile.name}: {rule} does not match {bad}"
        assert set(profile.role_names) <= role_enum, (profile.name, profile.role_names)
        short = profile.spec.protocol["short_name"]
        assert all(short in e for e in protocol_enums), (profile.name, short)


def test_the_capture_checks_schema_admits_every_protocols_rule_ids():
    """``mcp-capture check --json``'s schema: its rule-ID patterns fit every protocol's rules."""
    import re

    from mcp_conform.captures.check import load_schema
    from mcp_conform.spec.profiles import PROFILES

    patterns = {n["pattern"] for _, n in _walk(load_schema()) if "pattern" in n and "-[A-Z]+-" in n["pattern"]}
    assert patterns
    for profile in PROFILES.values():
        for rule in profile.spec.rules_by_id:
            assert all(re.match(pat, rule) for pat in patterns), (profile.name, rule, patterns)

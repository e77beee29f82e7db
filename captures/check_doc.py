"""The one document ``mcp-capture check --json`` writes, whatever the protocol
(``check.schema.json``, beside this module), from the common verdict interface of the monitors
(``judge.verdicts.Verdicts``): the schema version and the protocol, the tool and the spec, the
file, the parameters, the nodes, the violations, the rules' verdicts, what the protocol adds
(MCP: its sessions; MAVLink: its frames, Nsqd: its connections and gaps, and how many times each
rule was broken), the summary and the verdict.

A protocol's check gives its file, parameters and nodes; a violation its monitor found is
listed by :func:`violation_json` (MCP's streamed by ``captures.check``, in the same shape).
"""

from __future__ import annotations

import json
from importlib import resources
from typing import Any

from mcp_conform.judge.verdicts import Found, Verdicts

__all__ = ["SCHEMA_VERSION", "document", "load_schema", "summary_json", "validate_json", "violation_json"]

SCHEMA_VERSION = "1.5"  # 1.1: parameters.from_capture; 1.2: segments (merged xdist captures); 1.3: the
# challenge and waypoints recorded by a manager-role run (challenge_source "recorded"); 1.4:
# parameters.rto_declared (the run declared its rto the nodes' own: judge.params.Params.adopt);
# 1.5: one document for every protocol (protocol, verdict; MAVLink's and Nsqd's rules, nodes,
# violations and their own sections)


def document(v: Verdicts, spec: Any, file: dict[str, Any], parameters: dict[str, Any], nodes: list[Any],
             violations: list[Any], own: dict[str, Any] | None = None) -> dict[str, Any]:
    """The document (see the module docstring); ``own``: the protocol's sections, after the rules."""
    from mcp_conform.spec.about import tool_version

    return {
        "schema_version": SCHEMA_VERSION,
        "protocol": v.protocol,
        "tool": {"name": "mcp-capture", "version": tool_version()},
        "spec": {"version": spec.version, "sha256": spec.sha256},
        "file": file,
        "parameters": parameters,
        "nodes": nodes,
        "violations": violations,
        "rules": v.rules,
        **(own or {}),
        "summary": summary_json(v),
        "verdict": v.verdict,
    }


def summary_json(v: Verdicts) -> dict[str, Any]:
    return {"violations": v.total, "must": v.levels["MUST"], "should": v.levels["SHOULD"], "info": v.levels["INFO"],
            "failing": v.failing, "verdicts": v.verdict_counts(), "exit_code": v.exit_code}


def violation_json(f: Found, spec: Any, first_ns: int | None) -> dict[str, Any]:
    """A violation of a monitor that gives its evidence as lines (MAVLink's, Nsqd's)."""
    r = spec.rule(f.rule)
    zero = first_ns or 0
    return {"rule": f.rule, "level": r.level, "node": f.node, "t": round((f.t_ns - zero) / 1e9, 9), "t_ns": f.t_ns,
            "text": r.text, "expected": f.expected, "actual": f.actual,
            "evidence": [{"index": None, "t": None, "summary": e} for e in f.evidence], "frames": list(f.frames),
            **dict(f.more)}


def load_schema() -> dict[str, Any]:
    return json.loads(resources.files("mcp_conform.captures").joinpath("check.schema.json").read_text())


def validate_json(doc: dict[str, Any]) -> None:
    """Raises ``jsonschema.ValidationError`` when ``doc`` does not follow the schema."""
    import jsonschema

    jsonschema.validate(doc, load_schema())

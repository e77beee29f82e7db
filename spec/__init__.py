"""The CentMesh MCP spec and everything derived from it.

``spec.SPEC`` is the loaded, checked ``mcp.yaml``; ``spec.codec`` the wire codec built from
it; ``spec.mission`` mission items and waypoint files through pymavlink. ``spec`` imports no
other package of this project.
"""

from spec._load import (
    LEVELS,
    ROLES,
    ActionSpec,
    Note,
    Observation,
    Rule,
    Spec,
    SpecError,
    load,
)

SPEC: Spec = load()

__all__ = [
    "LEVELS",
    "ROLES",
    "SPEC",
    "ActionSpec",
    "Note",
    "Observation",
    "Rule",
    "Spec",
    "SpecError",
    "load",
]

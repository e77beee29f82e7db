"""The CentMesh MCP spec and everything derived from it.

``spec.SPEC`` is the loaded, checked ``mcp.yaml``, ``spec.NSQD`` the Nsqd TCP protocol's
``nsqd.yaml`` (``spec.nsqd``, ``spec.nsqd_codec``), both read through one interface
(``spec.SpecBase``), and ``spec.MAVLINK`` MAVLink's microservices (``mavlink.yaml``);
``spec.RULES`` every rule of the three; ``spec.codec`` the wire codec built from it;
``spec.mission`` mission items and waypoint files through pymavlink; ``spec.profiles`` each
protocol declared once (its spec, codec, framing, and the modules of the floors above that
serve it, by name). ``spec`` imports no other package of this project.
"""

from mcp_conform.spec._load import (
    LEVELS,
    ROLES,
    ActionSpec,
    Note,
    Observation,
    Rule,
    Spec,
    SpecBase,
    SpecError,
    load,
)

SPEC: Spec = load()

from mcp_conform.spec.nsqd import StreamSpec, load_stream  # noqa: E402  (after _load, which it builds on)

#: The Nsqd TCP drone protocol's spec (``nsqd.yaml``): the second protocol (``--protocol nsqd``).
NSQD: StreamSpec = load_stream()

from mcp_conform.spec.mavlink import MavlinkSpec, load_mavlink  # noqa: E402

#: MAVLink's microservices (``mavlink.yaml``, layouts from pymavlink's dialect): the third
#: protocol (``--protocol mavlink``).
MAVLINK: MavlinkSpec = load_mavlink()

#: Every rule of every protocol by ID (the IDs carry the protocol's prefix: MCP-, NSQD-, MAV-), for
#: reports that name a rule whatever protocol the run spoke.
RULES: dict[str, Rule] = {**SPEC.rules_by_id, **NSQD.rules_by_id, **MAVLINK.rules_by_id}

__all__ = [
    "LEVELS",
    "ROLES",
    "MAVLINK",
    "NSQD",
    "RULES",
    "SPEC",
    "ActionSpec",
    "Note",
    "Observation",
    "Rule",
    "Spec",
    "SpecBase",
    "SpecError",
    "StreamSpec",
    "load",
    "load_stream",
]

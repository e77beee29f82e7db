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

import threading  # noqa: E402
from typing import TYPE_CHECKING, Any  # noqa: E402

from mcp_conform.spec.mavlink import MavlinkSpec, load_mavlink  # noqa: E402
from mcp_conform.spec.nsqd import StreamSpec, load_stream  # noqa: E402  (after _load, which it builds on)

if TYPE_CHECKING:
    #: The Nsqd TCP drone protocol's spec (``nsqd.yaml``): the second protocol (``--protocol nsqd``).
    NSQD: StreamSpec
    #: MAVLink's microservices (``mavlink.yaml``, layouts from pymavlink's dialect): the third
    #: protocol (``--protocol mavlink``).
    MAVLINK: MavlinkSpec
    #: Every rule of every protocol by ID (the IDs carry the protocol's prefix: MCP-, NSQD-, MAV-),
    #: for reports that name a rule whatever protocol the run spoke.
    RULES: dict[str, Rule]

#: how each of the other protocols' specs is loaded, on first use (PEP 562): a process that
#: speaks MCP alone -- every node a run spawns, ``mcp-node`` -- never reads them, and MAVLink's
#: brings pymavlink's ardupilotmega dialect, 26 of the 59 ms ``import mcp_conform.spec`` took
_LAZY = {"NSQD": load_stream, "MAVLINK": load_mavlink}


_LOADING = threading.RLock()  # two threads' first use: one load, one object


def __getattr__(name: str) -> Any:
    if name not in _LAZY and name != "RULES":
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    with _LOADING:
        if name in globals():
            return globals()[name]
        if name == "RULES":
            value: Any = {**SPEC.rules_by_id, **__getattr__("NSQD").rules_by_id, **__getattr__("MAVLINK").rules_by_id}
        else:
            value = _LAZY[name]()
        globals()[name] = value  # loaded once: the next lookup finds it without this function
        return value


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
    "MavlinkSpec",
    "StreamSpec",
    "load",
    "load_stream",
]

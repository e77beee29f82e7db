"""Each protocol declared once: its profile, per role (docs/design.md, "A protocol is a plug-in").

A profile names everything the tools need to speak, judge, fuzz and read one protocol: its
spec and framing (``datagram`` or ``stream``: a stream protocol's capture channels are named
after it, ``traceio.channels.stream_topics``), transport, monitor, dissector and capture tools
(its reader, checker and recogniser), fuzz campaign, mutators and oracles, reference node, and per role (the role of the node under test)
the runner's session and case context, the case package and the reference node. Things
that live on a higher floor are named by import path (``"package.module:attribute"``), and
resolved lazily, with :func:`resolve`, by the floor that uses them: ``spec`` imports none
of them, and a name here is only a string until a tool asks for it.

Every tool's ``--protocol`` and ``--role`` go through :func:`pick`, the one place where a
protocol name or a role name turns into behaviour. A new protocol adds its profile here.
"""

from __future__ import annotations

import argparse
import importlib
from dataclasses import dataclass
from typing import Any

import mcp_conform.spec as _spec
from mcp_conform.spec import SPEC, SpecBase

__all__ = ["DEFAULT_PROTOCOL", "PIECES", "PROFILES", "ProfileError", "Profile", "RoleProfile",
           "add_protocol_option", "having", "pick", "pick_having", "profile_of_role", "resolve", "ROLE_NAMES"]

DEFAULT_PROTOCOL = "mcp"


class ProfileError(ValueError):
    """An unknown protocol, or a role the protocol's nodes do not take: one line for a person."""


@dataclass(frozen=True)
class RoleProfile:
    """The node under test in one role: what the runner drives it with and judges it by."""

    name: str
    #: the runner's session over the whole run (``harness``) and its case context (``conformance``)
    session: str
    context: str
    #: the package of the role's conformance cases
    cases: str
    #: the fuzz target of the role (``fuzz``), None: fuzzed by the protocol's own campaign
    fuzz_target: str | None
    #: RunConfig fields only this role reads, reported in the JSON report's parameters
    parameters: tuple[str, ...] = ()
    #: ``--impair``: the runner's socket edge can be a bad link for this role
    impairable: bool = False
    #: ``--parallel``: the role's cases are shared out across node instances
    shardable: bool = False
    #: the role the runner (a replay, a reference node's default address) plays against it
    peer: str | None = None
    #: the node's protocol ID when the spec fixes it for the role (MCP's manager: 0), else None
    fixed_id: int | None = None
    #: the runner's schedule runs the role's batchable cases together (``conformance.schedule``);
    #: False: one after another
    scheduled: bool = False
    #: ``mcp-fuzz`` fuzzes a node in this role (by its fuzz target or the protocol's own
    #: campaign); False: ``--role`` names it in a one-line usage error
    fuzzed: bool = True
    #: ``mcp-conform --mavlink`` means something in this role (the drone's simulated vehicle, a
    #: MAVLink link's transport); False: a one-line usage error, not an option ignored
    mavlink: bool = True


@dataclass(frozen=True)
class Profile:
    """One protocol: its spec and everything derived from it, by the floor that owns it."""

    name: str
    #: the name in ``spec`` of its loaded spec (``SPEC``, ``NSQD``, ``MAVLINK``): :attr:`spec`,
    #: loaded on first use (a process that speaks one protocol reads no other's spec)
    spec_name: str
    #: how the wire carries messages: ``datagram`` (one message a datagram), ``stream``
    #: (frames deframed from a byte stream, recorded on the protocol's stream channels) or
    #: ``packet`` (self-delimiting packets over either, as MAVLink's, recorded as its own)
    framing: str
    transport: str  # udp, tcp; mavlink: either, as the node's address says
    #: None below: the protocol has no such piece yet (:func:`resolve` says so in one line)
    #: the run's trace monitor of a datagram protocol (``harness.session_base.DatagramSessionBase``)
    monitor: str | None
    dissector: str | None  # its Wireshark Lua dissector: ``generate()`` and ``FILENAME``
    #: whether a capture file holds this protocol's traffic (None: the default's captures)
    capture_detect: str | None
    #: ``mcp-capture check|show|diff|export|replay`` of its captures (``captures.cli.CaptureTools``)
    capture_tools: str | None
    mutators: str | None
    oracles: str | None
    #: ``mcp-fuzz``'s campaign of this protocol (``fuzz.config.FuzzCampaign``): its loop over
    #: the protocol's targets, engines, oracles and triage, and its ``--replay``
    fuzz_campaign: str | None
    #: the reference node's command line (``mcp-node --protocol NAME ROLE``; the runner's
    #: embedded default: ``harness.session_base.reference_command``)
    reference_cli: str
    roles: tuple[RoleProfile, ...]
    #: the loader of a spec file of this protocol (``python -m mcp_conform.spec --spec PATH``)
    loader: str

    @property
    def spec(self) -> SpecBase:
        """Its spec, loaded (``spec.SPEC``, ``spec.NSQD``, ``spec.MAVLINK``)."""
        return getattr(_spec, self.spec_name)  # type: ignore[no-any-return]

    @property
    def default_role(self) -> RoleProfile:
        return self.roles[0]

    @property
    def role_names(self) -> tuple[str, ...]:
        return tuple(r.name for r in self.roles)

    def role(self, name: str | None) -> RoleProfile:
        """The role ``name`` (None: the protocol's default); ProfileError when its nodes do
        not take it."""
        if name is None:
            return self.default_role
        for r in self.roles:
            if r.name == name:
                return r
        raise ProfileError(f"{name!r} is not a role of --protocol {self.name} ({', '.join(self.role_names)})")

    def role_of_id(self, node_id: int | None) -> RoleProfile:
        """The role of the node with this protocol ID: the role whose ID the spec fixes to it
        (MCP's manager, 0), else (an unknown ID too) the first role with no fixed ID (MCP's
        drones)."""
        for r in self.roles:
            if r.fixed_id is not None and r.fixed_id == node_id:
                return r
        return next(r for r in self.roles if r.fixed_id is None)


MCP = Profile(
    name="mcp", spec_name="SPEC", framing="datagram", transport="udp",
    monitor="mcp_conform.judge.run_monitor:RunMonitor", dissector="mcp_conform.captures.dissector",
    capture_detect=None, capture_tools="mcp_conform.captures.mcp",
    mutators="mcp_conform.fuzz.mutators", oracles="mcp_conform.fuzz.oracles", fuzz_campaign="mcp_conform.fuzz.campaign:DatagramCampaign",
    reference_cli="mcp_conform.reference_impl.cli",
    roles=(
        RoleProfile("drone", session="mcp_conform.harness.drone_session:Session", context="mcp_conform.conformance.drone_case:CaseContext",
                    cases="mcp_conform.conformance.cases", fuzz_target="mcp_conform.fuzz.drone_target:FuzzTarget",
                    impairable=True, shardable=True, scheduled=True,
                    peer="manager"),
        RoleProfile("manager", session="mcp_conform.harness.manager_session:ManagerSession",
                    context="mcp_conform.conformance.manager_case:ManagerCaseContext",
                    cases="mcp_conform.conformance.cases_manager", fuzz_target="mcp_conform.fuzz.manager_target:ManagerFuzzTarget",
                    parameters=("drones", "challenge", "waypoints"),
                    peer="drone", fixed_id=int(SPEC.protocol["manager_id"]), mavlink=False),
    ),
    loader="mcp_conform.spec._load:load",
)

NSQD_PROFILE = Profile(
    name="nsqd", spec_name="NSQD", framing="stream", transport="tcp",
    monitor="mcp_conform.judge.nsqd_monitor:StreamMonitor", dissector="mcp_conform.captures.dissector_nsqd",
    capture_detect="mcp_conform.captures.nsqd:is_capture", capture_tools="mcp_conform.captures.nsqd",
    mutators="mcp_conform.fuzz.nsqd_mutators", oracles="mcp_conform.fuzz.nsqd_oracles",
    fuzz_campaign="mcp_conform.fuzz.nsqd_campaign:StreamCampaign", reference_cli="mcp_conform.reference_impl.nsqd_cli",
    roles=(
        RoleProfile("backend", session="mcp_conform.harness.nsqd_session:StreamSession",
                    context="mcp_conform.conformance.nsqd_case:StreamCaseContext", cases="mcp_conform.conformance.cases_nsqd",
                    fuzz_target=None,
                    peer="client", mavlink=False),
    ),
    loader="mcp_conform.spec.nsqd:load_stream",
)

#: MAVLink's microservices (issue 39): frames through pymavlink over TCP or UDP, as SITL is
#: reached; the node under test is an autopilot (the runner its ground station) or a ground
#: station (the runner its vehicle). The reference vehicle is ``mcp-vehicle``, the reference
#: ground station ``reference_impl.mavlink_gcs``.
MAVLINK_PROFILE = Profile(
    name="mavlink", spec_name="MAVLINK", framing="packet", transport="mavlink",
    monitor="mcp_conform.judge.mavlink_monitor:MavlinkMonitor", dissector="mcp_conform.captures.dissector_mavlink",
    capture_detect="mcp_conform.captures.mavlink:is_capture", capture_tools="mcp_conform.captures.mavlink",
    mutators=None, oracles=None, fuzz_campaign="mcp_conform.fuzz.mavlink_campaign:MavlinkCampaign",
    reference_cli="mcp_conform.reference_impl.mavlink_gcs",
    roles=(RoleProfile("vehicle", session="mcp_conform.harness.mavlink_session:MavlinkSession",
                       context="mcp_conform.conformance.mavlink_case:MavlinkCaseContext",
                       cases="mcp_conform.conformance.cases_mavlink",
                       fuzz_target="mcp_conform.fuzz.mavlink_vehicle:MavTarget",
                       peer="gcs"),
           # the runner is the vehicle, a ground station is judged (its reference:
           # ``mcp-node --protocol mavlink gcs {mavlink}``; ``mcp-node --protocol mavlink``
           # otherwise runs mcp-vehicle, as before)
           RoleProfile("gcs", session="mcp_conform.harness.mavlink_gcs_session:MavlinkGcsSession",
                       context="mcp_conform.conformance.mavlink_gcs_case:MavlinkGcsCaseContext",
                       cases="mcp_conform.conformance.cases_mavlink_gcs", fuzz_target=None,
                       peer="vehicle", fuzzed=False, parameters=("mavlink1",))),
    loader="mcp_conform.spec.mavlink:load_mavlink",
)

#: Every protocol by its ``--protocol`` name; the first is the default.
PROFILES: dict[str, Profile] = {p.name: p for p in (MCP, NSQD_PROFILE, MAVLINK_PROFILE)}
#: Every role of every protocol (a role name belongs to one protocol).
ROLE_NAMES: tuple[str, ...] = tuple(r.name for p in PROFILES.values() for r in p.roles)


def profile_of_role(role: str) -> Profile:
    """The protocol whose nodes take ``role``; ProfileError when none does."""
    for p in PROFILES.values():
        if role in p.role_names:
            return p
    raise ProfileError(f"{role!r} is not one of "
                       + ", ".join(f"{r} ({p.name})" for p in PROFILES.values() for r in p.role_names))


def pick(protocol: str | None = None, role: str | None = None) -> tuple[Profile, RoleProfile]:
    """The profile and role a tool's ``--protocol`` and ``--role`` name (no protocol: the
    default, mcp; no role: the protocol's first). ProfileError (one line) when they name
    nothing, or nothing together."""
    prof = PROFILES.get(DEFAULT_PROTOCOL if protocol is None else protocol)
    if prof is None:
        raise ProfileError(f"{protocol!r} is not one of {', '.join(PROFILES)}")
    return prof, prof.role(role)


#: what each piece a tool may need is called in a person's words (:func:`add_protocol_option`)
PIECES = {"capture_tools": "capture tools", "dissector": "Wireshark dissector",
          "fuzz_campaign": "fuzz campaign", "monitor": "trace monitor"}


def having(piece: str | None) -> tuple[str, ...]:
    """The protocols whose profile has ``piece`` (None: every protocol)."""
    return tuple(name for name, p in PROFILES.items() if piece is None or getattr(p, piece) is not None)


def pick_having(protocol: str | None, piece: str | None) -> Profile:
    """:func:`pick`'s profile, which must have ``piece``; ProfileError (one line) naming the
    protocols that do."""
    prof = pick(protocol)[0]
    if piece is not None and getattr(prof, piece) is None:
        raise ProfileError(f"{prof.name!r} has no {PIECES.get(piece, piece)} yet "
                           f"(protocols with one: {', '.join(having(piece))})")
    return prof


class _ProtocolOption(argparse.Action):
    """``--protocol NAME`` checked by :func:`pick_having`: an unknown name, or a protocol
    without the piece the tool needs, is the same one line in every tool (``PROG: error:
    --protocol: 'x' is not one of mcp, nsqd, mavlink``)."""

    def __init__(self, *args: Any, needs: str | None = None, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.needs = needs

    def __call__(self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any,
                 option_string: str | None = None) -> None:
        try:
            pick_having(values, self.needs)
        except ProfileError as exc:
            parser.error(f"{option_string}: {exc}")
        setattr(namespace, self.dest, values)


def add_protocol_option(parser: Any, help: str, default: str | None = None, needs: str | None = None) -> None:
    """``--protocol`` as every tool takes it: one of :data:`PROFILES` that has the profile
    field ``needs`` (the piece the tool works with: ``capture_tools``, ``dissector``,
    ``fuzz_campaign``), checked by :func:`pick_having`."""
    parser.add_argument("--protocol", action=_ProtocolOption, default=default, metavar="|".join(having(needs)),
                        help=help, needs=needs)


def resolve(path: str | None) -> Any:
    """``"package.module"`` -> the module, ``"package.module:name"`` -> its attribute: a
    profile's name of a thing on a higher floor, imported by the floor that asks for it.
    None (a piece the protocol does not have yet): ProfileError."""
    if path is None:
        raise ProfileError("this protocol has no such piece yet (spec.profiles: the tool should ask "
                           "pick_having first)")
    module, _, attr = path.partition(":")
    mod = importlib.import_module(module)
    return getattr(mod, attr) if attr else mod

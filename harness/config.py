"""The runner's parameters (docs/design.md, "The runner's contract"), shared by CLI and plugin."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from typing import Any

from mcp_conform.spec import SPEC
from mcp_conform.spec.profiles import DEFAULT_PROTOCOL, Profile, RoleProfile, pick

#: the embedded reference node's retransmission timeout, which the runner starts it with
#: (``harness.session_base``) and so declares (``RunConfig.rto_declared``)
EMBEDDED_RTO = 0.2
DEFAULT_SEED = 20140307  # the description's date: every run sends the same bytes by default
#: the role of a run that names none: the default protocol's first (``spec.profiles.pick``)
DEFAULT_ROLE = pick()[1].name


def parse_hostport(text: str, what: str, default_host: str = "127.0.0.1") -> tuple[str, int]:
    """'HOST:PORT' or ':PORT' or 'PORT' -> (host, port); ValueError names ``what``."""
    host, sep, port_s = text.rpartition(":")
    if not sep:
        host, port_s = "", text
    try:
        port = int(port_s)
    except ValueError:
        raise ValueError(f"{what}: {text!r} is not HOST:PORT") from None
    if not 0 <= port <= 65535:
        raise ValueError(f"{what}: port {port} is out of range 0-65535")
    return (host or default_host), port


@dataclass
class RunConfig:
    """Everything a run needs to know; defaults are the description's (spec) values."""

    #: the protocol the node speaks (``spec.profiles``: every tool's ``--protocol``)
    protocol: str = DEFAULT_PROTOCOL
    role: str = DEFAULT_ROLE
    target: tuple[str, int] | None = None
    listen: tuple[str, int] | None = None  # None: all addresses, the role's convention port
    target_id: int | None = None
    spawn: str | None = None
    mavlink: bool = False
    #: How the node reaches the vehicle: tcp, udp/udpin (the node listens), udpout.
    mavlink_transport: str = "tcp"
    #: ``--mavlink1`` (--role gcs): the runner's vehicle speaks MAVLink 1 from the start
    mavlink1: bool = False
    embedded: bool = False  # no --target and no --spawn: the reference node
    strict: bool = False
    rto: float = float(SPEC.params["timeout_s"])
    ack_window: float = float(SPEC.params["ack_window_s"])
    broadcast_id: int = int(SPEC.protocol["broadcast_id"])
    timeout: float = float(SPEC.params["run_timeout_s"])
    seed: int = DEFAULT_SEED
    capture: str | None = None
    json_path: str | None = None
    junit_path: str | None = None
    case_timeout: float | None = None  # None: derived from rto and ack_window
    # --role manager: the drones the runner plays, the challenge, the waypoint file handed over
    drones: tuple[int, ...] = (1, 2, 3)
    challenge: int = 1
    waypoints: str | None = None
    #: ``--impair SPEC``: the runner's socket edge is a bad link (``harness.impair_link``)
    impair: Any = None  # harness.impair.ImpairSpec
    extra: dict[str, Any] = field(default_factory=dict)

    def profile(self) -> tuple[Profile, RoleProfile]:
        """The protocol's profile and the role's, as ``spec.profiles.pick`` names them."""
        return pick(self.protocol, self.role)

    @property
    def mode(self) -> str:
        return "embedded" if self.embedded else ("spawn" if self.spawn else "attach")

    @property
    def rto_declared(self) -> bool:
        """--rto is the node's own retransmission timeout, not only assumed: the embedded MCP
        reference node, which the runner starts with it (``EMBEDDED_RTO``). The
        run's monitor and the capture's parameters say so (``Monitor(rto_declared=)``)."""
        return self.embedded and self.protocol == "mcp" and self.rto == EMBEDDED_RTO

    def per_case_limit(self) -> float:
        """A bound on one case's wall time, generous against the node's own timeouts: a case
        may await several commands, each across up to 5 copies one --rto apart, from a node
        that is deaf while busy (D-6), plus its observation windows."""
        if self.case_timeout is not None:
            return self.case_timeout
        return max(60.0, 30 * self.rto + 10 * self.ack_window)

    def parameters(self) -> dict[str, Any]:
        """The parameters block of the JSON report."""
        d = asdict(self)
        out = {k: d[k] for k in ("protocol", "role", "target_id", "spawn", "mavlink", "strict", "rto",
                                 "ack_window", "broadcast_id", "timeout", "seed")}
        out["mode"] = self.mode
        if self.rto_declared:
            out["rto_declared"] = True
        for name in self.profile()[1].parameters:  # the role's own (--role manager: its drones)
            value = d[name]
            out[name] = list(value) if isinstance(value, tuple) else value
        if self.impair is not None:
            out["impair"] = self.impair.text()
        out["listen"] = f"{self.listen[0]}:{self.listen[1]}" if self.listen else None
        return out

"""The runner's options: parsed and checked into a ``RunConfig`` (``make_config``), from the
command line, the ini file or the environment (``option_values``); shared by the pytest
plugin and ``mcp-conform``. Every error is a ``ConfigError`` whose message names the option.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path
from typing import Any

import pytest

from mcp_conform.conformance.option_names import _FLAGS, _KEYS, _TRUE, env_name
from mcp_conform.harness.config import DEFAULT_SEED, RunConfig, parse_hostport
from mcp_conform.spec.profiles import PROFILES, ProfileError, pick

__all__ = ["DEFAULT_STARTUP_TIMEOUT", "ConfigError", "apply_embedded_defaults", "make_config", "matches_select", "mavlink_value",
           "option_values", "unmatched"]

#: How long the runner waits for the node's first datagram (``--startup-timeout``): a silent
#: target is a one-line setup error (exit 2) after this, not after the whole run's --timeout.
DEFAULT_STARTUP_TIMEOUT = 60.0


class ConfigError(ValueError):
    """A bad option value; the message names the option."""


# ---------------------------------------------------------------------- configuration
def _float(value: Any, name: str, minimum: float = 0.0) -> float:
    try:
        f = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name}: {value!r} is not a number of seconds") from None
    if not f > minimum or f != f or f == float("inf"):
        raise ConfigError(f"{name}: {value!r} must be a positive number of seconds")
    return f


def _int(value: Any, name: str, lo: int, hi: int) -> int:
    try:
        i = int(str(value), 0)
    except ValueError:
        raise ConfigError(f"{name}: {value!r} is not an integer") from None
    if not lo <= i <= hi:
        raise ConfigError(f"{name}: {i} is out of range {lo}-{hi}")
    return i


def make_config(values: Mapping[str, Any], opt: Callable[[str], str] = lambda n: "--mcp-" + n.replace("_", "-")) -> RunConfig:
    """A checked ``RunConfig`` from option values (keys: target, listen, target_id, protocol, role,
    spawn, mavlink, strict, rto, ack_window, broadcast_id, timeout, startup_timeout, seed,
    capture, json, junit, impair); ``opt(name)`` spells an option in error messages."""
    cfg = RunConfig()
    v = {k: x for k, x in values.items() if x is not None}
    try:  # the one place a protocol and a role turn into a profile (spec.profiles)
        prof, role_prof = pick(v.get("protocol"), v.get("role"))
    except ProfileError as exc:
        what = opt("protocol") if "protocol" in v and v["protocol"] not in PROFILES else opt("role")
        raise ConfigError(f"{what}: {exc}") from None
    cfg.protocol, cfg.role = prof.name, role_prof.name
    role = cfg.role
    try:
        if "target" in v:
            cfg.target = parse_hostport(str(v["target"]), opt("target"))
        if "listen" in v:
            cfg.listen = parse_hostport(str(v["listen"]), opt("listen"), default_host="")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if "target_id" in v:
        cfg.target_id = _int(v["target_id"], opt("target_id"), 0, 0xFFFF)
    if "spawn" in v:
        if not str(v["spawn"]).strip():
            raise ConfigError(f"{opt('spawn')}: the command is empty")
        cfg.spawn = str(v["spawn"])
    mavlink = v.get("mavlink", False)
    cfg.mavlink = bool(mavlink)
    if isinstance(mavlink, str):
        from mcp_conform.vehicle import TRANSPORTS

        if mavlink not in TRANSPORTS:
            raise ConfigError(f"{opt('mavlink')}: {mavlink!r} is not one of {', '.join(TRANSPORTS)}")
        cfg.mavlink_transport = mavlink
    if cfg.mavlink and not role_prof.mavlink:  # as --mavlink1: one line, not an option ignored
        where = " or ".join(f"--protocol {p.name} --role {r.name}" for p in PROFILES.values() for r in p.roles
                            if r.mavlink)
        raise ConfigError(f"{opt('mavlink')}: the runner starts or chooses a MAVLink link only with {where}, "
                          f"not with --protocol {cfg.protocol} --role {role}")
    _mavlink1_option(cfg, v, opt)
    cfg.strict = bool(v.get("strict", False))
    if "rto" in v:
        cfg.rto = _float(v["rto"], opt("rto"))
    if "ack_window" in v:
        cfg.ack_window = _float(v["ack_window"], opt("ack_window"))
    if "broadcast_id" in v:
        cfg.broadcast_id = _int(v["broadcast_id"], opt("broadcast_id"), 0, 0xFFFF)
    if "timeout" in v:
        cfg.timeout = _float(v["timeout"], opt("timeout"))
    if "case_timeout" in v:
        cfg.case_timeout = _float(v["case_timeout"], opt("case_timeout"))
    cfg.extra["startup_timeout"] = (_float(v["startup_timeout"], opt("startup_timeout"))
                                    if "startup_timeout" in v else DEFAULT_STARTUP_TIMEOUT)
    cfg.seed = _int(v["seed"], opt("seed"), 0, 2**63 - 1) if "seed" in v else DEFAULT_SEED
    cfg.capture = v.get("capture")
    cfg.json_path = v.get("json")
    cfg.junit_path = v.get("junit")
    cfg.embedded = cfg.target is None and cfg.spawn is None
    _manager_options(cfg, v, opt)
    if "impair" in v:
        from mcp_conform.harness.impair import ImpairmentError, parse_impairment

        try:
            cfg.impair = parse_impairment(str(v["impair"]))
        except ImpairmentError as exc:
            raise ConfigError(str(exc).replace("--impair", opt("impair"), 1)) from None
        if not role_prof.impairable:
            raise ConfigError(f"{opt('impair')}: the {role} role is not run through a bad link yet "
                              "(the drone role is)")
    cfg.extra["explicit"] = sorted(k for k in v if k in _KEYS and k not in ("mavlink", "mavlink1", "strict"))
    return cfg


def _mavlink1_option(cfg: RunConfig, v: Mapping[str, Any], opt: Callable[[str], str]) -> None:
    """--mavlink1: the node the runner plays speaks MAVLink 1 from the start, so only in a role
    whose parameters have it (``spec.profiles``: the gcs role, the runner the vehicle);
    elsewhere a one-line error naming the roles that take it."""
    on = v.get("mavlink1", False)
    cfg.mavlink1 = on.strip().lower() in _TRUE if isinstance(on, str) else bool(on)
    if cfg.mavlink1 and "mavlink1" not in cfg.profile()[1].parameters:
        where = " or ".join(f"--protocol {p.name} --role {r.name}" for p in PROFILES.values() for r in p.roles
                            if "mavlink1" in r.parameters)
        raise ConfigError(f"{opt('mavlink1')}: the runner speaks MAVLink 1 only as the vehicle of {where}, "
                          f"not with --protocol {cfg.protocol} --role {cfg.role}")


def _manager_options(cfg: RunConfig, v: Mapping[str, Any], opt: Callable[[str], str]) -> None:
    """--drones, --challenge, --waypoints (the manager role's)."""
    if "drones" in v:
        try:
            ids = tuple(int(x, 0) for x in str(v["drones"]).split(",") if x.strip())
        except ValueError:
            raise ConfigError(f"{opt('drones')}: {v['drones']!r} is not a comma-separated list of IDs") from None
        bad = [i for i in ids if not 0 < i < cfg.broadcast_id or i > 0xFFFF]
        if not ids or bad or len(set(ids)) != len(ids):
            raise ConfigError(f"{opt('drones')}: {v['drones']!r}: drone IDs are distinct, 1..{cfg.broadcast_id - 1}")
        cfg.drones = ids
    if "challenge" in v:
        cfg.challenge = _int(v["challenge"], opt("challenge"), 1, 3)
    if "waypoints" in v:
        path = Path(str(v["waypoints"]))
        if not path.is_file():
            raise ConfigError(f"{opt('waypoints')}: {str(path)!r} is not a file")
        cfg.waypoints = str(path)


def apply_embedded_defaults(cfg: RunConfig) -> None:
    """The embedded default runs the reference node with short timeouts: assume them too
    (unless --rto / --ack-window were given)."""
    if not cfg.embedded:
        return
    from mcp_conform.harness.session_base import EMBEDDED_ACK_WINDOW, EMBEDDED_RTO

    explicit = cfg.extra.get("explicit", ())
    if "rto" not in explicit:
        cfg.rto = EMBEDDED_RTO
    if "ack_window" not in explicit:
        cfg.ack_window = EMBEDDED_ACK_WINDOW


def matches_select(prefixes: list[str], cid: str, rule_ids: tuple[str, ...]) -> bool:
    """A case is selected when a prefix starts its case ID or one of its rule IDs
    (case-insensitive; ``MCP-ACK-1`` does not select ``MCP-ACK-10``)."""
    if not prefixes:
        return True
    names = [cid.upper(), *(r.upper() for r in rule_ids)]
    for p in (x.strip().upper() for x in prefixes):
        for name in names:
            if name == p or (name.startswith(p) and p and not (p[-1].isdigit() and name[len(p)].isdigit())):
                return True
    return False


def unmatched(prefixes: list[str], cases: Iterable[tuple[str, tuple[str, ...]]]) -> list[str]:
    """The prefixes (``--exclude``'s) that match no case (case ID, rule IDs) at all."""
    cases = list(cases)
    return [p for p in prefixes if not any(matches_select([p], cid, ids) for cid, ids in cases)]


def mavlink_value(text: str) -> Any:
    """``--mcp-mavlink`` from the ini file or the environment: a transport (tcp, udp,
    udpin, udpout), a yes (tcp) or a no (off)."""
    word = text.strip().lower()
    if word in _TRUE:
        return "tcp"
    return False if word in ("", "0", "false", "no", "off") else word


def option_values(config: pytest.Config) -> dict[str, Any]:
    """Each option from, in order of precedence, the command line, the ini file
    (``mcp_target = ...`` under ``[pytest]``/``[tool.pytest.ini_options]``) and the
    environment (``MCP_CONFORM_TARGET``), as pytest plugins conventionally offer them."""
    out: dict[str, Any] = {}
    for key in _KEYS:
        value = config.getoption("mcp_" + key)
        if value in (None, False):
            ini = config.getini("mcp_" + key)
            value = ini if ini not in ("", None, False, []) else None
        if value in (None, False):
            env = os.environ.get(env_name(key))
            if env is not None and env != "":
                value = env.strip().lower() in ("1", "true", "yes", "on") if key in _FLAGS else env
        if key in _FLAGS and isinstance(value, str):
            value = value.strip().lower() in _TRUE
        elif key == "mavlink" and isinstance(value, str):
            value = mavlink_value(value)
        out[key] = value
    return out



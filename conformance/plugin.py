"""The mcp-conform pytest plugin's entry point (``pytest11``: ``mcp_conform``).

Installed for every pytest run in the environment, this module costs next to nothing: it
declares the ``--mcp-*`` options and ini keys and imports nothing heavier than pytest. The
runner itself (``conformance._plugin_run``: fixtures ``mcp_config``, ``mcp_session``,
``node``; the MUST / SHOULD / INFO outcome mapping; time limits; the reports) is loaded and
registered only when a run asks for it:

- an ``--mcp-*`` option is given, an ``mcp_*`` ini key is set, or an ``MCP_CONFORM_*``
  environment variable (the options' other spellings, see ``conformance.options``);
- or a test module imports ``conformance.marks`` (every case does, through ``rules(...)``),
  so ``pytest --pyargs conformance.cases`` and a user's own cases work with no option.

``mcp-conform`` is a thin front end that runs ``conformance.cases`` through it;
``pytest --mcp-target HOST:PORT`` runs the same suite, and users write their own cases::

    from mcp_conform.conformance.marks import rules

    @rules("MCP-ACK-1")
    def test_my_command_is_acked(node):
        node.expect_acked([("WP_Off", node.command(Action.WP_OFF))])

The session under test is made by the ``pytest_mcp_make_session`` hook (firstresult), so a
conftest can substitute its own: a ``harness.node.NodeUnderTest`` (stand it on
``harness.node.NodeBase``; anything else is a one-line setup error naming what it lacks).
"""

from __future__ import annotations

import os
from typing import TYPE_CHECKING, Any

import pytest

from mcp_conform.conformance.option_names import _FLAGS, _KEYS, env_name

if TYPE_CHECKING:
    from mcp_conform.harness.config import RunConfig

__all__ = ["activate", "env_name"]  # and, loaded on first use: ConfigError, make_config,
# matches_select (conformance.options), McpState, STATE_KEY (conformance._plugin_run)

RUN_PLUGIN = "mcp_conform.conformance._plugin_run"
_CONFIG: dict[str, pytest.Config] = {}


class _HookSpecs:
    @pytest.hookspec(firstresult=True)
    def pytest_mcp_make_session(self, cfg: RunConfig, recorder: Any, config: pytest.Config) -> Any:
        """Return the session for the run (see ``harness.drone_session.Session``)."""



# ---------------------------------------------------------------------- options


def pytest_addoption(parser: pytest.Parser) -> None:
    g = parser.getgroup("mcp-conform", "MCP conformance (mcp-conform)")
    g.addoption("--mcp-target", metavar="HOST:PORT", help="the node's unicast address (attach mode)")
    g.addoption("--mcp-listen", metavar="HOST:PORT", help="where the runner receives (default: all addresses, the role's port)")
    g.addoption("--mcp-target-id", metavar="N", help="the node's MCP ID (default: from its Mission_Ready, else 1)")
    g.addoption("--mcp-protocol", metavar="mcp|nsqd", help="the protocol the node speaks (default mcp)")
    g.addoption("--mcp-role", metavar="drone|manager|backend",
                help="the role of the node under test (default: the protocol's first, drone for mcp)")
    g.addoption("--mcp-spawn", metavar="CMD", help="start the node under test with CMD ({target_port} ... placeholders)")
    g.addoption("--mcp-mavlink", nargs="?", const="tcp", default=None, metavar="tcp|udp|udpin|udpout",
                help="start the simulated vehicle and pass {mavlink} (a pymavlink URL of that transport; default tcp)")
    g.addoption("--mcp-mavlink1", action="store_true", help="--role gcs: the runner's vehicle speaks MAVLink 1 from the start")
    g.addoption("--mcp-strict", action="store_true", help="a failed SHOULD is a failure")
    g.addoption("--mcp-select", metavar="PREFIX", action="append", default=[], help="run cases whose rule ID or case ID starts with PREFIX (repeatable)")
    g.addoption("--mcp-json", metavar="FILE", help="write the JSON report")
    g.addoption("--mcp-junit", metavar="FILE", help="write a JUnit XML report")
    g.addoption("--mcp-capture", metavar="FILE.mcap", help="record the run to an MCAP file")
    g.addoption("--mcp-live", metavar="[HOST:]PORT", help="serve the run live to Foxglove over its WebSocket protocol "
                "(the capture's channels; loopback unless HOST is given; port 0: a free one)")
    g.addoption("--mcp-html", metavar="FILE", help="write a self-contained HTML report (failed cases with their sequence charts)")
    g.addoption("--mcp-rto", metavar="S", help="the node's retransmission timeout as assumed (default 5)")
    g.addoption("--mcp-ack-window", metavar="S", help="how long 'no reply' is watched (default 2)")
    g.addoption("--mcp-broadcast-id", metavar="N", help="the broadcast MCP ID (default 0xFFFF)")
    g.addoption("--mcp-timeout", metavar="S", help="deadline for the whole run (default 600)")
    g.addoption("--mcp-startup-timeout", metavar="S", help="how long to wait for the node's first datagram, and for a spawned node's Mission_Ready (default 60)")
    g.addoption("--mcp-case-timeout", metavar="S", help="time limit of one case (default: from --mcp-rto and --mcp-ack-window); pytest-timeout's --timeout applies too where it is shorter")
    g.addoption("--mcp-seed", metavar="N", help="seed of the malformed corpus")
    g.addoption("--mcp-exclude", metavar="PREFIX", action="append", default=[], help="leave out cases whose rule ID or case ID starts with PREFIX (repeatable)")
    g.addoption("--mcp-baseline", metavar="FILE", help="expected failures (YAML or JSON): listed failures are xfailed, listed passes xpassed")
    g.addoption("--mcp-write-baseline", metavar="FILE", help="write this run's failures as a baseline")
    g.addoption("--mcp-junit-family", metavar="xunit2|xunit1", default="xunit2", help="xunit2 (default): valid against the Jenkins junit-10 schema; xunit1: also properties in each testcase")
    g.addoption("--mcp-drones", metavar="1,2,3", help="--role manager: the drone IDs the runner plays")
    g.addoption("--mcp-challenge", metavar="1|2|3", help="--role manager: the challenge the manager runs")
    g.addoption("--mcp-waypoints", metavar="FILE", help="--role manager: the QGC WPL 110 file the manager is handed")
    g.addoption("--mcp-impair", metavar="SPEC", help="the runner's link to the node is a bad one, reproducible by seed: "
                "loss=0.1,dup=0.05,reorder=0.1,delay=0-50ms,corrupt=0.01,seed=7 (a case the impairment "
                "spoiled is repeated, never failed)")
    g.addoption("--mcp-verbose-traffic", action="store_true", help="print every datagram sent and received, live, to stderr")
    g.addoption("--mcp-serial", action="store_true", help="run every case alone, one after another "
                "(the default schedule overlaps what only waits)")
    g.addoption("--mcp-list", action="store_true", help="list the cases with their rule IDs; run nothing")
    g.addoption("--mcp-frontend", action="store_true", help="(used by mcp-conform) speak as mcp-conform")
    g.addoption("--mcp-shard", metavar="K/N", help="(used by mcp-conform --parallel) run instance K's share "
                "of the plan shared out across N node instances (conformance.schedule.shard_plan)")
    g.addoption("--mcp-shard-events", metavar="FILE", help="(used by mcp-conform --parallel) append the plan, "
                "each case's record and the run's notes to FILE, one JSON object a line")
    for key in _KEYS:
        parser.addini("mcp_" + key, f"default for --mcp-{key.replace('_', '-')} (environment: {env_name(key)})",
                      type="bool" if key in _FLAGS else "string", default=False if key in _FLAGS else None)  # type: ignore[maybe-unrecognized-str-typeform]  # mypy 2.4: pytest's Literal, not a type


def pytest_addhooks(pluginmanager: pytest.PytestPluginManager) -> None:
    pluginmanager.add_hookspecs(_HookSpecs)



def _default_role() -> str:
    """The default role's name (``spec.profiles``), imported only when a run names a role."""
    from mcp_conform.harness.config import DEFAULT_ROLE

    return DEFAULT_ROLE


def _wanted(config: pytest.Config) -> bool:
    """Did this run ask for the runner (an option, an ini key, an environment variable)?"""
    for key, value in vars(config.option).items():
        if key.startswith("mcp_") and value not in (None, False, [], "xunit2") \
                and not (key == "mcp_role" and value == _default_role()):
            return True
    for key in _KEYS:
        try:
            if config.getini("mcp_" + key) not in ("", None, False, []):
                return True
        except ValueError:
            pass
    return any(k.startswith("MCP_CONFORM_") and v for k, v in os.environ.items())


def activate(config: pytest.Config | None = None) -> None:
    """Load and register the runner for this pytest run (idempotent). Called at configure
    time when the run asks for it, and by ``conformance.marks`` when a module of cases is
    imported, before its items are built (so the fixtures are there for them)."""
    config = config or _CONFIG.get("config")
    if config is None or config.pluginmanager.has_plugin(RUN_PLUGIN):
        return
    import importlib

    config.pluginmanager.register(importlib.import_module(RUN_PLUGIN), RUN_PLUGIN)


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line("markers", "mcp_rules(*ids): the MCP rule IDs a conformance case verifies")
    config.addinivalue_line("markers", "mcp_phase(phase): startup, main, late or end")
    _CONFIG["config"] = config
    if _wanted(config):
        activate(config)


def pytest_unconfigure(config: pytest.Config) -> None:
    if _CONFIG.get("config") is config:
        _CONFIG.pop("config", None)


def __getattr__(name: str) -> Any:
    """The runner's public names, loaded on first use (``from conformance.plugin import ...``)."""
    if name in ("ConfigError", "make_config", "matches_select", "apply_embedded_defaults", "option_values"):
        from mcp_conform.conformance import options

        return getattr(options, name)
    if name in ("McpState", "STATE_KEY"):
        import importlib

        return getattr(importlib.import_module(RUN_PLUGIN), name)
    raise AttributeError(name)

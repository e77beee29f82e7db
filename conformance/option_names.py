"""The runner's option names and their other spellings, shared by the plugin's entry point
(``conformance.plugin``: ``--mcp-*`` options and ``mcp_*`` ini keys) and the option parser
(``conformance.options``: ``MCP_CONFORM_*`` environment variables). Imports nothing, so the
plugin stays inert in pytest runs that do not ask for the runner."""

from __future__ import annotations

__all__ = ["env_name"]

_KEYS = ("target", "listen", "target_id", "protocol", "role", "spawn", "mavlink", "strict", "rto", "ack_window",
         "broadcast_id", "timeout", "seed", "capture", "json", "junit", "case_timeout",
         "drones", "challenge", "waypoints", "startup_timeout", "impair", "mavlink1")
_FLAGS = ("strict", "mavlink1")
_TRUE = ("1", "true", "yes", "on")


def env_name(key: str) -> str:
    """The environment variable that sets option ``key`` (``MCP_CONFORM_TARGET``, ...)."""
    return "MCP_CONFORM_" + key.upper()

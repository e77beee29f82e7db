"""The node under fuzz of the campaign's role, started, or a ``SetupError`` with its
resources released: the target its role profile names (``spec.profiles``, ``fuzz_target``:
the drone's ``fuzz.drone_target``, the manager's ``fuzz.manager_target``), so the targets never
import each other and no role is named here."""

from __future__ import annotations

from mcp_conform.fuzz.config import FuzzConfig, target_class
from mcp_conform.fuzz.target_base import TargetBase
from mcp_conform.harness.errors import SetupError

__all__ = ["start_target"]


def start_target(cfg: FuzzConfig) -> TargetBase:
    """A started target, or SetupError (its resources released)."""
    t: TargetBase = target_class(cfg.protocol, cfg.role)(cfg)
    try:
        t.start()
    except SetupError:
        t.close()
        raise
    except OSError as exc:
        t.close()
        raise SetupError(str(exc)) from None
    return t

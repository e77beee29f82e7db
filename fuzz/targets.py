"""The node under fuzz of the campaign's role: the drone target (``fuzz.target``) or the
manager target (``fuzz.manager_target``), started, or a ``SetupError`` with its resources
released. The one place that picks a role's target, so the two never import each other."""

from __future__ import annotations

from fuzz.config import FuzzConfig
from fuzz.manager_target import ManagerFuzzTarget
from fuzz.target import FuzzTarget
from fuzz.target_base import TargetBase
from harness.errors import SetupError

__all__ = ["start_target"]


def start_target(cfg: FuzzConfig) -> TargetBase:
    """A started target, or SetupError (its resources released)."""
    t: TargetBase
    if cfg.role == "manager":
        t = ManagerFuzzTarget(cfg)
    else:
        t = FuzzTarget(cfg)
    try:
        t.start()
    except SetupError:
        t.close()
        raise
    except OSError as exc:
        t.close()
        raise SetupError(str(exc)) from None
    return t

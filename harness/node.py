"""What the runner needs of a node under test, whatever its protocol and role.

:class:`NodeUnderTest` names it (a ``typing.Protocol``): the run's parameters, the case
context it hands each case, its start, its cases' begin and end, its liveness and its
close, and the run's observations the runner reports when the node has them (the trace
monitor, the liveness watch, a timing note, an unreadable header, the startup's own words).
:class:`NodeBase` gives every member its "nothing to say" value, so a session says only
what it has: the datagram sessions (``harness.session_base.DatagramSessionBase``), the stream
session (``harness.nsqd_session``, on ``SessionBase``) and a session a conftest substitutes through the
``pytest_mcp_make_session`` hook all stand on it. The runner checks the contract once,
where the session is made (:func:`check_node`), and reads the members plainly after that.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, runtime_checkable

from mcp_conform.harness.config import RunConfig
from mcp_conform.harness.errors import SetupError

__all__ = ["NodeBase", "NodeUnderTest", "check_node"]


@runtime_checkable
class NodeUnderTest(Protocol):
    """The node under test as the runner (``conformance``) drives it over a whole run."""

    cfg: RunConfig
    recorder: Any
    #: the runner's case context, ``make_context(session, case_id, rules)``
    make_context: Callable[..., Any] | None
    #: the node's address as the reports print it
    target_desc: str
    #: why the node was lost (None: it was not); the next case is then an error
    lost: str | None
    #: the node must be restarted before the next case (spawn mode)
    needs_restart: bool
    #: the run's trace monitor (``judge.run_monitor``: ``finish``, ``to_json``), None: none
    monitor: Any
    #: the liveness watch (``harness.liveness``: ``lost``, ``loss_after``), None: none
    liveness: Any
    #: the runner's datagram socket (``harness.driver.TargetDriver``), None: not a datagram node
    driver: Any
    #: the node's retransmission period disagrees with --rto: the sentence saying so
    timing: str | None
    #: (rule, why): the node's datagrams cannot be read; only raw-byte cases run
    unreadable: tuple[str, str] | None
    #: (line, status): what the terminal says while the node starts (None: the runner's default)
    startup_note: tuple[str, str] | None
    #: what the node's first datagram is (the runner's wait for it); None: no such wait
    first_awaited: str | None

    def start(self) -> None: ...

    def alive(self) -> bool: ...

    def begin_case(self, case_id: str, rules: tuple[str, ...]) -> Any: ...

    def end_case(self, ctx: Any, outcome: str) -> None: ...

    def close(self) -> None: ...

    def not_judged(self, rules: tuple[str, ...]) -> str | None: ...

    def startup_unanswered(self, why: str) -> Exception: ...

    def startup_timed_out(self, timeout: float) -> Exception: ...


class NodeBase:
    """Every :class:`NodeUnderTest` member the runner may read, at "nothing to say"."""

    cfg: RunConfig
    recorder: Any = None
    make_context: Callable[..., Any] | None = None
    target_desc: str = ""
    lost: str | None = None
    needs_restart: bool = False
    monitor: Any = None
    liveness: Any = None
    driver: Any = None
    timing: str | None = None
    unreadable: tuple[str, str] | None = None
    startup_note: tuple[str, str] | None = None
    first_awaited: str | None = None

    def alive(self) -> bool:
        return True

    def not_judged(self, rules: tuple[str, ...]) -> str | None:
        """Why a case of ``rules`` cannot be judged on this node (None: it can)."""
        return None

    def startup_unanswered(self, why: str) -> Exception:
        """The error for a node that sent nothing within --startup-timeout (``why``)."""
        return SetupError(why)

    def startup_timed_out(self, timeout: float) -> Exception:
        """The error for a startup the run's --timeout cut short."""
        return SetupError(f"target never answered within the run's --timeout of {timeout:g} s")


def _members() -> list[str]:
    names = list(NodeUnderTest.__annotations__)
    return names + [n for n, v in vars(NodeUnderTest).items() if callable(v) and not n.startswith("_")]


def check_node(session: Any) -> Any:
    """``session`` if it is a :class:`NodeUnderTest`, else a one-line SetupError naming what
    it lacks (a session substituted through ``pytest_mcp_make_session`` stands on
    :class:`NodeBase` and adds what its node does)."""
    if isinstance(session, NodeUnderTest):
        return session
    missing = [m for m in _members() if not hasattr(session, m)]
    raise SetupError(f"the session {type(session).__name__} is not a node under test "
                     f"(harness.node.NodeUnderTest): it lacks {', '.join(missing)}; "
                     "stand it on harness.node.NodeBase")

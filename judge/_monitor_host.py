"""What the trace monitor's rule mixins use of the class that hosts them, for the type checker.

:class:`judge.monitor.Monitor` is one judge built from four mixins (``SenderRules`` over
``RetransmissionRules``, ``ReceiverRules``, ``VehicleRules``): each mixin's methods read the
state ``Monitor.__init__`` sets up and call helpers that ``Monitor`` or a sibling mixin
defines. :class:`MonitorHost` declares those attributes and helpers once; each mixin names it
as its base only while type checking (``if TYPE_CHECKING``; at run time the base is
``object``, so the classes and their method order are unchanged). The types are the ones
``Monitor.__init__`` annotates; a helper's signature here is checked against its definition
(``Monitor`` inherits both), and an abstract one that no class defines would make
``Monitor()`` an error. A plain class rather than a ``typing.Protocol``: mypy (2.4) cannot
determine the type of a protocol's attribute that an explicit subclass assigns
(``inferred_challenge``, ``_packed_waypoints``: error ``has-type``).
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Iterable
from typing import Any

from mcp_conform.judge._monitor_base import _Exchange, _Node, _Timers

__all__ = ["MonitorHost"]


class MonitorHost:
    """The state and helpers of ``Monitor`` that its rule mixins share (see the module)."""

    # the run's assumptions (Monitor's arguments)
    rto_ns: int
    lone_rto_ns: int
    lone_due_ns: int
    rto_declared: bool
    window_ns: int
    broadcast_id: int
    drones: tuple[int, ...] | None
    challenge: int | None
    waypoints: tuple[Any, ...] | None
    horizon_ns: int
    inferred_challenge: int | None
    # derived once
    _rtx_delay: int
    _ack_horizon: int
    _packed_waypoints: list[bytes] | None
    _waypoint_set: frozenset[bytes]
    _insane: dict[bytes, str]
    # per datagram and per node
    _rd: int | None
    _nodes: dict[int, _Node]
    _tester_ids: set[int]
    _on_real: dict[int, list[Any]]
    _timers: _Timers
    # messages and ACKs by key (Monitor.__init__ says which)
    _ex: dict[int, Any]
    _by_seq: dict[int, Any]
    _ack_seq: dict[int, Any]
    _to_seq: dict[int, Any]
    _malformed_seen: set[tuple[int, int, int, int]]
    _malformed_lists: set[tuple[int, int]]
    _acked_addrs: dict[tuple[int, int], set[Any]]
    _acks_to: set[int]
    _stray_acks: dict[tuple[int, int], tuple[int, int, int]]
    _reacks: dict[tuple[int, int], tuple[int, int]]
    _answered_to: dict[tuple[int, int], int]
    _waiting_copy: dict[tuple[int, int], Any]
    _ambiguous: dict[int, tuple[Any, list[tuple[Any, int, int, int]]]]
    _doubtful: set[int]
    _last_to: dict[int, int]
    _latest_to: dict[int, Any]
    _unmatched_acks: dict[tuple[int, int], tuple[int, int]]
    _carried: bytearray
    _nothing: dict[int, tuple[int, int, int, int]]
    party: int | None
    complete: bool
    _bcast_srcs: set[int]
    _unicast_dsts: set[int]
    _rob_dsts: dict[str, set[int]]
    _latency: dict[int, list[Any]]
    # passthrough frames (MCP-PAY-6..8)
    _pt: dict[Any, list[Any]]
    _pt_to: dict[int, list[Any]]
    _node_delivers: set[int]

    # Monitor's helpers
    @abstractmethod
    def _node(self, node_id: int) -> _Node: ...

    @abstractmethod
    def _emit(self, rule: str, node: int, t_ns: int, expected: str, actual: str,
              evidence: Iterable[tuple[int, int]]) -> None: ...

    @abstractmethod
    def _observe(self, node: int, rule: str) -> None: ...

    @abstractmethod
    def _complete_for(self, *ids: int) -> bool: ...

    @abstractmethod
    def _rtx_expire(self, now: int, ex: Any) -> None: ...

    # one mixin's helpers that another calls
    @abstractmethod
    def _judge_spacing(self, ex: _Exchange, copies: list[tuple[int, int]], t: int) -> None: ...

    @abstractmethod
    def _wrong_ack_deadline(self, now: int, ex: _Exchange, wrong: tuple[int, int]) -> None: ...

    @abstractmethod
    def _seq_number_taken(self, node: _Node, seq: int, t: int) -> None: ...

    @abstractmethod
    def _copy_received(self, ex: _Exchange, i: int, t: int) -> None: ...

    @abstractmethod
    def _check_ready_fix(self, node: _Node, i: int, t: int) -> None: ...

    @abstractmethod
    def _track_passthrough(self, ex: _Exchange) -> None: ...

    @abstractmethod
    def _passthrough_acked(self, ex: _Exchange, node: _Node, t: int) -> None: ...

    @abstractmethod
    def _end_acked(self, ex: _Exchange, node: _Node, t: int) -> None: ...

"""``MissionMessageHandlerBase``: the application's message handlers, as the description has them.

"There are default handlers for each and every message that do 'nothing'. In other words,
if the application developers do not write any message handlers, no action will be taken
whenever a MCP message is received." An application subclasses this class and overrides
the ``handle_*_message`` methods "by their exact names".

Each handler receives ``buffer``, the decoded payload typed by the codec (``None`` for an
empty payload, a ``tuple`` of ``MissionItem`` for WP_List / Obstacles_List, one
``MissionItem`` for WP_On, the frame ``bytes`` for Mav_Passthrough, the drone's ID or
``None`` for Mission_Ready). A handler that declares a second parameter also receives the
whole :class:`~spec.codec.Message` as ``msg`` (to know its ``src``, for instance).

:func:`dispatch` finds and calls the handler for a delivered message; :class:`~reference_impl.api.Mcp`
calls it from its handler thread, in delivery order.
"""

from __future__ import annotations

import inspect
from collections.abc import Callable
from typing import Any

from mcp_conform.spec.codec import Action, Message, Payload

__all__ = ["HANDLER_NAMES", "MissionMessageHandlerBase", "dispatch"]

#: The handler method of each action code, by the description's exact names.
HANDLER_NAMES: dict[Action, str] = {
    Action.MISSION_READY: "handle_mission_ready_message",
    Action.START_MISSION: "handle_start_mission_message",
    Action.END_MISSION: "handle_end_mission_message",
    Action.WP_LIST: "handle_wp_list_message",
    Action.WP_ON: "handle_wp_on_message",
    Action.WP_OFF: "handle_wp_off_message",
    Action.OBSTACLES_LIST: "handle_obstacle_list_message",
    Action.ACK: "handle_ack_message",
    Action.MAV_PASSTHROUGH: "handle_mav_passthrough_message",
}


class MissionMessageHandlerBase:
    """Default handlers that do nothing; ``mavutil_obj`` is the autopilot link, or None.

    "mavutil_obj ... should allow None as well as we would not need one for the process
    running on the Laptop" (the Mission Manager).
    """

    def __init__(self, mavutil_obj: Any = None) -> None:
        self.mavutil_obj = mavutil_obj

    def handle_mission_ready_message(self, buffer: Payload = None, msg: Message | None = None) -> None:
        """A drone is ready (Mission_Ready; ``buffer`` is its ID or None, D-3)."""

    def handle_start_mission_message(self, buffer: Payload = None, msg: Message | None = None) -> None:
        """Start_Mission: the drone may arm now (MCP-BLK-4)."""

    def handle_end_mission_message(self, buffer: Payload = None, msg: Message | None = None) -> None:
        """End_Mission: finish pending actions, then RTL (MCP-BLK-7)."""

    def handle_wp_list_message(self, buffer: Payload = None, msg: Message | None = None) -> None:
        """WP_List: ``buffer`` is a tuple of MissionItem."""

    def handle_wp_on_message(self, buffer: Payload = None, msg: Message | None = None) -> None:
        """WP_On: ``buffer`` is one MissionItem, now active."""

    def handle_wp_off_message(self, buffer: Payload = None, msg: Message | None = None) -> None:
        """WP_Off: the most recently active waypoint is now inactive."""

    def handle_obstacle_list_message(self, buffer: Payload = None, msg: Message | None = None) -> None:
        """Obstacles_List: ``buffer`` is a tuple of MissionItem to avoid."""

    def handle_mav_passthrough_message(self, buffer: Payload = None, msg: Message | None = None) -> None:
        """Mav_Passthrough: ``buffer`` is one MAVLink frame (bytes), MCP-PAY-6/8."""

    def handle_ack_message(self, buffer: Payload = None, msg: Message | None = None) -> None:
        """ACKs are consumed by the protocol and never delivered; kept "for the sake of completion"."""


def dispatch(handler: Any, msg: Message, _cache: dict[Any, int] | None = None) -> bool:
    """Call ``handler``'s method for ``msg.action`` with ``(buffer[, msg])``.

    Returns False when ``handler`` has no such method (nothing is called). Handlers written
    like the description's, with no parameter at all (``handle_start_mission_message()``),
    are called with none. Exceptions propagate to the caller.
    """
    name = HANDLER_NAMES.get(Action(msg.action))
    fn = getattr(handler, name, None) if name else None
    if fn is None:
        return False
    key = (type(handler), name)
    cache = _cache if _cache is not None else {}
    arity = cache.get(key)
    if arity is None:
        arity = _arity(fn)
        cache[key] = arity
    if arity == 3:
        fn(msg.payload, msg=msg)
    elif arity == 2:
        fn(msg.payload, msg)
    elif arity == 1:
        fn(msg.payload)
    else:
        fn()
    return True


def _arity(fn: Callable[..., Any]) -> int:
    """How to call ``fn``: 2 = (buffer, msg), 3 = (buffer, msg=msg), 1 = (buffer), 0 = ()."""
    try:
        params = list(inspect.signature(fn).parameters.values())
    except (TypeError, ValueError):  # builtins without a signature: the description's shape
        return 1
    positional = [p for p in params if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    if len(positional) >= 2 or any(p.kind is p.VAR_POSITIONAL for p in params):
        return 2
    if any(p.name == "msg" and p.kind is p.KEYWORD_ONLY for p in params) or any(
            p.kind is p.VAR_KEYWORD for p in params):
        return 3 if positional else 0
    return 1 if positional else 0

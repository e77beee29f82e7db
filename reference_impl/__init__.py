"""The reference MCP implementation: sans-I/O endpoint, UDP transport, blocking API.

``from reference_impl import Mcp, MissionMessageHandlerBase, McpException, Action`` gives the
description's API (:mod:`reference_impl.api`); :class:`Endpoint` is the sans-I/O protocol
core (:mod:`reference_impl.endpoint`) and the event types are its output
(:mod:`reference_impl.events`).
"""

from mcp_conform.reference_impl._transitions import State
from mcp_conform.reference_impl.api import Mcp, McpException
from mcp_conform.reference_impl.endpoint import Endpoint
from mcp_conform.reference_impl.events import (
    AckReceived,
    AckSent,
    DeliveryConfirmed,
    DeliveryFailed,
    DuplicateDiscarded,
    Event,
    Malformed,
    MessageDelivered,
    Retransmitted,
    Unexpected,
)
from mcp_conform.reference_impl.handler import MissionMessageHandlerBase
from mcp_conform.spec.codec import Action, LocalProtocolError, Message, MissionItem

__all__ = [
    "AckReceived",
    "AckSent",
    "Action",
    "DeliveryConfirmed",
    "DeliveryFailed",
    "DuplicateDiscarded",
    "Endpoint",
    "Event",
    "LocalProtocolError",
    "Malformed",
    "Mcp",
    "McpException",
    "Message",
    "MessageDelivered",
    "MissionItem",
    "MissionMessageHandlerBase",
    "Retransmitted",
    "State",
    "Unexpected",
]

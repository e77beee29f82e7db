"""A Foxglove WebSocket client for the tests of ``--live`` (issue 24 item 2), on
``websocket-client``: what Foxglove does when it opens ``ws://HOST:PORT`` — read the
server's ``serverInfo`` and ``advertise``, subscribe to every channel as it is advertised,
and take the binary ``messageData`` frames (opcode 1: subscription id u32, log time u64,
payload) apart.

The protocol's subprotocol was ``foxglove.websocket.v1``; the ``foxglove-sdk`` server we
serve with (0.30) names it ``foxglove.sdk.v1`` and refuses a client offering only the old
name (HTTP 400), so the client offers both, as Foxglove's app does.
"""

from __future__ import annotations

import json
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import websocket

SUBPROTOCOLS = ["foxglove.sdk.v1", "foxglove.websocket.v1"]
MESSAGE_DATA = 0x01
_HEAD = struct.Struct("<BIQ")


@dataclass
class Received:
    topic: str
    log_time: int
    data: bytes
    running: bool  # what ``running()`` said when the message arrived

    def json(self) -> Any:
        return json.loads(self.data)


@dataclass
class Session:
    subprotocol: str | None = None
    server_info: dict[str, Any] = field(default_factory=dict)
    channels: dict[int, dict[str, Any]] = field(default_factory=dict)  # channel id -> advertised
    messages: list[Received] = field(default_factory=list)
    statuses: list[dict[str, Any]] = field(default_factory=list)
    closed: bool = False  # the server closed the connection (not our timeout)

    def topics(self) -> set[str]:
        return {c["topic"] for c in self.channels.values()}

    def on(self, topic: str) -> list[Received]:
        return [m for m in self.messages if m.topic == topic]


def connect(url: str, timeout: float = 60.0, alive: Callable[[], bool] = lambda: True) -> websocket.WebSocket:
    """Connect as soon as the server listens (within ``timeout``, while ``alive()``)."""
    deadline = time.monotonic() + timeout
    while True:
        try:
            return websocket.create_connection(url, subprotocols=SUBPROTOCOLS, timeout=10)
        except (OSError, websocket.WebSocketException):
            if time.monotonic() > deadline or not alive():
                raise
            time.sleep(0.02)


def watch(ws: websocket.WebSocket, running: Callable[[], bool], until: float = 240.0,
          then: Callable[[Session], None] | None = None) -> Session:
    """Read until the server closes the connection (or ``until`` seconds pass), subscribing
    to each channel once, as it is advertised; ``then(session)`` after each message."""
    s = Session(subprotocol=ws.getsubprotocol())
    subscription: dict[int, str] = {}  # subscription id -> topic
    deadline = time.monotonic() + until
    while time.monotonic() < deadline:
        try:
            frame = ws.recv()
        except websocket.WebSocketTimeoutException:
            continue
        except (websocket.WebSocketConnectionClosedException, ConnectionError, OSError):
            s.closed = True
            break
        if not frame:  # a close frame
            s.closed = True
            break
        if isinstance(frame, bytes):
            op, sub, t = _HEAD.unpack_from(frame)
            if op == MESSAGE_DATA:
                s.messages.append(Received(subscription[sub], t, frame[_HEAD.size:], running()))
                if then is not None:
                    then(s)
            continue
        doc = json.loads(frame)
        if doc.get("op") == "serverInfo":
            s.server_info = doc
        elif doc.get("op") == "advertise":
            new = [c for c in doc["channels"] if c["id"] not in s.channels]
            for c in new:
                s.channels[c["id"]] = c
                subscription[c["id"]] = c["topic"]  # one subscription per channel, its id the channel's
            if new:
                ws.send(json.dumps({"op": "subscribe",
                                    "subscriptions": [{"id": c["id"], "channelId": c["id"]} for c in new]}))
        elif doc.get("op") == "status":
            s.statuses.append(doc)
    ws.close()
    return s

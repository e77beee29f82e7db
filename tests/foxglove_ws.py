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
import signal
import socket
import struct
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import websocket

from tests.capturing import free_port

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


def listening(port: int, host: str = "127.0.0.1") -> bool:
    """Whether anything accepts a connection on (host, port)."""
    with socket.socket() as s:
        return s.connect_ex((host, port)) == 0


@dataclass
class Watched:
    port: int
    seen: Session
    returncode: int
    out: str
    err: str  # empty where stderr went to ``out``


def watch_tool(argv: list[str], *, cwd: Path, env: dict[str, str], stderr_to_out: bool = False,
               until: float = 240.0, wait: float = 60.0, running: Callable[[], bool] = lambda: True,
               interrupt_when: Callable[[Session], bool] | None = None) -> Watched:
    """Run ``argv --live 127.0.0.1:PORT`` (a free port) and watch it as Foxglove does until the
    server closes the connection (or ``until`` s); ``running()`` and the process still going
    is what each message's ``running`` says. ``interrupt_when(session)``: SIGINT the tool, as
    a user's Ctrl-C, once it holds. The process is killed if it outlives ``wait`` s after."""
    port = free_port(socket.SOCK_STREAM)
    proc = subprocess.Popen([*argv, "--live", f"127.0.0.1:{port}"], cwd=cwd, env=env, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT if stderr_to_out else subprocess.PIPE)

    def then(s: Session) -> None:
        if interrupt_when is not None and proc.poll() is None and interrupt_when(s):
            proc.send_signal(signal.SIGINT)

    try:
        ws = connect(f"ws://127.0.0.1:{port}", alive=lambda: proc.poll() is None)
        seen = watch(ws, running=lambda: proc.poll() is None and running(), until=until, then=then)
        out, err = proc.communicate(timeout=wait)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    return Watched(port, seen, proc.returncode, out, err or "")


class Watcher(threading.Thread):
    """A client of an in-process server (``url``) watching from a thread: :func:`watch` for
    ``until`` s, ``then(session)`` after each message; :meth:`session` when it is done."""

    def __init__(self, url: str, until: float = 30.0, then: Callable[[Session], Any] | None = None) -> None:
        super().__init__(daemon=True)
        self.ws = connect(url, timeout=5)
        self.until, self.then = until, then
        self._session: Session | None = None

    def run(self) -> None:
        self._session = watch(self.ws, running=lambda: True, until=self.until, then=self.then)

    def session(self, timeout: float = 30.0) -> Session:
        self.join(timeout)
        assert self._session is not None, "the client was still watching"
        return self._session

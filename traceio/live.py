"""A run watched while it happens: its capture's channels served over the Foxglove WebSocket
protocol (issue 24 item 2; ``--live [HOST:]PORT`` on ``mcp-conform``, ``mcp-fuzz``,
``mcp-node`` and ``mcp-soak``).

Nothing here makes a message. The recorder (:class:`traceio.recorder.McapRecorder`) turns
each event of a run (a datagram, a MAVLink frame, a case mark, a log line) into the JSON
bodies of its channels once, and hands every body it writes to its ``live`` feed as well
(a recorder without a file, ``McapRecorder(None, live=...)``, when the run writes no
capture): the live stream and the capture are the same messages, with the same schemas
(``traceio.channels.CHANNELS`` and the ``foxglove-sdk`` schemas of :mod:`traceio.fox`), the
same topics and the same log times. So Foxglove shows a live run with the layout of
``examples/foxglove-layout.json`` as it shows the capture afterwards (the package ships that
file as :data:`LAYOUT_PATH`, which the banner names: an installed wheel has no examples/).

:class:`LiveServer` is ``foxglove-sdk``'s WebSocket server (``foxglove.start_server``) with a
context of its own, so nothing else logged in the process reaches it, and the channels
advertised from the start (a client connecting before the first datagram sees every topic).
A :class:`LiveFeed` is what one recorder writes to; a server holding several nodes' views
(``mcp-soak``: the manager and each drone) gives each its own feed (``segment``), whose
topics carry the view's name in front (``/drone1/mcp/rx``): one topic, one channel. The
channels are made before the server starts listening (a channel made while a client is
connected may be lost to it: ``foxglove-sdk`` 0.30 advertises it before it can be
subscribed to).

The server listens on loopback unless told otherwise, on the port asked (0: a free one, see
:attr:`LiveServer.url`), and :meth:`LiveServer.stop` (idempotent; also at interpreter exit)
closes it: nothing is left listening when a run ends, however it ends, and a client that
stopped reading does not hold the end of the run (``STOP_S``).
"""

from __future__ import annotations

import errno
import json
import socket
import threading
import time
import warnings
from pathlib import Path
from typing import Any

from mcp_conform.traceio.channels import CHANNELS, STREAM_CHANNELS, foxglove_channels
from mcp_conform.traceio.files import ClosedAtExit

__all__ = ["DEFAULT_HOST", "LAYOUT_PATH", "LiveError", "LiveFeed", "LiveServer", "parse_live"]

#: Foxglove's layout for these channels as the package ships it (package data; the same
#: file as examples/foxglove-layout.json, both built by ``traceio.fox.layout_json``)
LAYOUT_PATH = Path(__file__).resolve().with_name("foxglove-layout.json")

#: the servers running, stopped at interpreter exit: a run that ends without stopping its
#: server leaves nothing listening
_SERVERS = ClosedAtExit("stop")

DEFAULT_HOST = "127.0.0.1"
#: How long :meth:`LiveServer.stop` lets a subscribed client's queue drain before it closes the
#: server (which drops what is still queued: a run's last verdict would not reach Foxglove).
LINGER_S = 0.3
#: Messages queued for one client before the oldest are dropped (the SDK's default is 1024; a
#: whole run is a few thousand small messages, and a viewer should see every one).
BACKLOG = 65536
#: How long :meth:`LiveServer.stop` waits for the server to close its clients' connections.
#: foxglove-sdk's ``stop()`` stops listening at once, then waits for every client to take
#: what is queued for it: a client that stopped reading (a laptop gone to sleep) would hold
#: the run's end for ever. After this long the wait is left to a daemon thread.
STOP_S = 2.0


class LiveError(Exception):
    """The live server cannot be started (one line, names the option)."""


def parse_live(text: str, option: str = "--live") -> tuple[str, int]:
    """``[HOST:]PORT`` as (host, port): loopback without a host, port 0 a free port; a
    ``LiveError`` naming ``option`` otherwise."""
    value = str(text).strip()
    host, sep, port_text = value.rpartition(":")
    if not sep:
        host = DEFAULT_HOST
    elif not host:
        raise LiveError(f"{option}: {text!r}: no host before ':' (give [HOST:]PORT)")
    if host.startswith("[") and host.endswith("]"):
        raise LiveError(f"{option}: {text!r}: IPv6 addresses are not served (give an IPv4 address or a name)")
    if ":" in host:
        raise LiveError(f"{option}: {text!r}: give [HOST:]PORT")
    try:
        port = int(port_text, 10)
    except ValueError:
        raise LiveError(f"{option}: {text!r}: port {port_text!r} is not a number (give [HOST:]PORT)") from None
    if not 0 <= port <= 65535:
        raise LiveError(f"{option}: {text!r}: port {port} is out of range (0-65535; 0: a free port)")
    return host, port


def _schemas() -> dict[str, tuple[str, dict[str, Any]]]:
    """Every channel a capture may have: topic -> (schema name, JSON schema); a stream
    protocol's (``/nsqd/*``) too, which a capture registers at its first frame."""
    return {**CHANNELS, **foxglove_channels(), **STREAM_CHANNELS}


class LiveFeed:
    """What one recorder writes to (its ``live``): ``publish(topic, data, t_ns)`` with the JSON
    bytes the capture holds. ``segment``: the view's name, put in front of its topics."""

    def __init__(self, server: LiveServer, segment: str | None) -> None:
        self._server = server
        self.segment = segment

    def topic(self, topic: str) -> str:
        return topic if self.segment is None else f"/{self.segment}{topic}"

    def publish(self, topic: str, data: bytes, t_ns: int) -> None:
        self._server.publish(self.topic(topic), data, t_ns)


class LiveServer:
    """foxglove-sdk's WebSocket server of one run (see the module's description)."""

    def __init__(self, host: str = DEFAULT_HOST, port: int = 0, *, name: str = "mcp-conform",
                 option: str = "--live", feeds: dict[str | None, tuple[str, ...] | None] | None = None) -> None:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", DeprecationWarning)
                import foxglove
        except ImportError:
            raise LiveError(f"{option}: foxglove-sdk is not installed "
                            "(pip install 'centmesh-mcp-conform[viewers]')") from None
        self._foxglove = foxglove
        self.host = host
        self._lock = threading.Lock()
        self._channels: dict[str, Any] = {}
        self._feeds: dict[str | None, LiveFeed] = {}
        self._stopped = False
        self.abandoned = False
        self.published = 0
        self._context = foxglove.Context()
        # every channel made before the server starts: a channel made while a client is
        # connected is advertised to it before the server knows it, and the client's subscribe
        # can come in between ("unknown channel", nothing served on it: foxglove-sdk 0.30)
        for segment, topics in (feeds if feeds is not None else {None: None}).items():
            self.feed(segment, topics)
        try:
            self._server = foxglove.start_server(name=name, host=host, port=port, context=self._context,
                                                 message_backlog_size=BACKLOG)
        except (RuntimeError, OSError, ValueError, OverflowError) as exc:
            why = str(exc).removeprefix("FoxgloveError: ")
            raise LiveError(f"{option} {host}:{port}: cannot serve: {why}") from None
        self.port = int(self._server.port)
        _SERVERS.add(self)

    @property
    def url(self) -> str:
        """``ws://HOST:PORT``: what Foxglove opens (Open connection, Foxglove WebSocket)."""
        return f"ws://{self.host}:{self.port}"

    @property
    def stopped(self) -> bool:
        return self._stopped

    def subscribed(self) -> int:
        """How many channels a client is subscribed to now."""
        with self._lock:
            return sum(_has_sinks(c) for c in self._channels.values())

    def feed(self, segment: str | None = None, topics: tuple[str, ...] | None = None) -> LiveFeed:
        """The feed of one view (one per ``segment``), its channels made now: every channel of
        a capture, or only ``topics`` (a campaign's own ``/log``). Give the feeds to the
        constructor (``feeds``) where they are known: made before the server starts, they are
        served to a client from its first moment (see there)."""
        with self._lock:
            feed = self._feeds.get(segment)
            if feed is None:
                feed = self._feeds[segment] = LiveFeed(self, segment)
            for topic, (name, schema) in _schemas().items():
                if topics is None or topic in topics:
                    self._channel(feed.topic(topic), name, schema, segment)
            return feed

    def _channel(self, topic: str, name: str, schema: dict[str, Any], segment: str | None) -> Any:
        """The channel of ``topic`` (made once; the caller holds the lock)."""
        channel = self._channels.get(topic)
        if channel is None and not self._stopped:
            fg = self._foxglove
            metadata = {"segment": segment} if segment is not None else None
            channel = self._channels[topic] = fg.Channel(
                topic, schema=fg.Schema(name=name, encoding="jsonschema", data=json.dumps(schema).encode()),
                message_encoding="json", context=self._context, metadata=metadata)
        return channel

    def publish(self, topic: str, data: bytes, t_ns: int) -> None:
        """One message on ``topic``."""
        with self._lock:
            if self._stopped:
                return
            channel = self._channels.get(topic)
            if channel is None:
                return  # not a channel of this server's feeds
            channel.log(data, log_time=int(t_ns))
            self.published += 1

    def stop(self) -> None:
        """Close the server (idempotent): clients are disconnected, the port is free. With a
        client subscribed, the messages queued for it get ``LINGER_S`` to go out first."""
        with self._lock:
            if self._stopped:
                return
            self._stopped = True
            channels, self._channels = list(self._channels.values()), {}
        if any(_has_sinks(c) for c in channels):
            time.sleep(LINGER_S)
        closing = threading.Thread(target=self._close, args=(channels,), name="live-stop", daemon=True)
        closing.start()
        closing.join(STOP_S)
        #: a client that does not read held the close past STOP_S (nothing listens any more)
        self.abandoned = closing.is_alive()
        _SERVERS.discard(self)

    def _close(self, channels: list[Any]) -> None:
        try:
            self._server.stop()
            _wait_unbound(self.host, self.port)
        finally:
            for channel in channels:
                try:
                    channel.close()
                except Exception:  # noqa: BLE001 - the server is gone; nothing more to close
                    pass

    def __enter__(self) -> LiveServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _wait_unbound(host: str, port: int, timeout: float = 1.0) -> None:
    """Until nothing listens on (host, port): foxglove-sdk's ``stop()`` returns a moment
    (about a millisecond) before its listening socket is closed, and a connection made in
    that moment is accepted. Probed by binding the address (no connection is made)."""
    deadline = time.monotonic() + timeout
    while True:
        with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
            s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                s.bind((host, port))
                return
            except OSError as exc:
                if exc.errno != errno.EADDRINUSE or time.monotonic() > deadline:
                    return  # not ours to probe (a name, another interface), or given up
        time.sleep(0.001)


def _has_sinks(channel: Any) -> bool:
    try:
        return bool(channel.has_sinks())
    except Exception:  # noqa: BLE001 - a closed channel has none
        return False
